#!/usr/bin/env bash
# The GPU machine's kit, in git-ignored folders of this checkout (docs/offline-install.md):
#   .whl/1..n  the locked wheels for its Python 3.12, in transfers that fit a call beside the
#              working tree (scripts/offline/bundle.py; the packages FetchBench's jobs there never
#              import are left out, and --slim drops the data files it never reads);
#   .gl/       the Vulkan / EGL loader packages a fresh machine lacks (ldconfig -p | grep -c
#              libvulkan is 0 there), unpacked with `for f in .gl/*.deb; do dpkg -x $f /; done;
#              ldconfig` in the call that starts a rendering job (the device tool's README recipe).
# Both are downloads only (from the package index and Debian's archive for amd64); re-running
# downloads nothing twice. Files outside git are lost when a session is cut off: this
# remakes them in one command. Extra arguments go to offline_bundle.py.
set -euo pipefail
cd "$(dirname "$0")/../.."
say() { echo "[device-kit] $*"; }

say "wheels for the GPU machine (.whl/)"
python3 scripts/offline/bundle.py --skip ray --skip imageio-ffmpeg --skip opencv-python --skip mplib --slim "$@"

GL_PACKAGES="libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2"
have=0
for p in $GL_PACKAGES; do ls .gl/${p}_*.deb >/dev/null 2>&1 && have=$((have + 1)); done
if [ "$have" -eq "$(echo $GL_PACKAGES | wc -w)" ]; then
  say "Vulkan/EGL loaders already in .gl/ ($have packages)"
else
  say "Vulkan/EGL loaders for the GPU machine (.gl/: $GL_PACKAGES)"
  lists=$(mktemp -d)
  # (-oAPT::Sandbox::User=root: the download folder is ours, not the _apt user's)
  o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=$lists -oAPT::Sandbox::User=root"
  mkdir -p .gl "$lists/partial"
  apt-get $o update -qq
  (cd .gl && apt-get $o download $GL_PACKAGES)
  rm -rf "$lists"
fi
say "done: carry .whl/1 .. .whl/N one a call, and .gl with the call that starts a rendering job"
