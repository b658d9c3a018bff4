#!/usr/bin/env bash
# `make bundle`: everything an air-gapped x86-64 node needs to run FetchBench-MS, made on a
# machine with internet, in git-ignored folders of this checkout (docs/offline-install.md):
#   .whl/   the locked wheels for the node's Python (scripts/offline/bundle.py; by default
#           --python-version 3.12, without ray, imageio-ffmpeg, opencv-python and mplib, which
#           evaluation and training never import, and --slim: without the data files FetchBench
#           never reads, with pybullet's blob meshes as a data-only wheel);
#   .gl/    the Vulkan / EGL loader packages (Debian amd64) a bare node may lack
#           (`ldconfig -p | grep -c libvulkan` prints 0), unpacked on the node with
#           `for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig`.
# Downloads only; re-running downloads nothing twice. Arguments go to bundle.py (e.g.
# `--python-version 3.11`, `--split-mib 500`).
#
#   bash scripts/offline/kit.sh [BUNDLE_ARGS...]      # or: make bundle BUNDLE_ARGS="..."
set -euo pipefail
cd "$(dirname "$0")/../.."
say() { echo "[offline-kit] $*"; }
case "${1:-}" in -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;; esac

say "wheels (.whl/)"
python3 scripts/offline/bundle.py --skip ray --skip imageio-ffmpeg --skip opencv-python --skip mplib --slim "$@"

GL_PACKAGES="libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2"
have=0
for p in $GL_PACKAGES; do ls .gl/${p}_*.deb >/dev/null 2>&1 && have=$((have + 1)); done
if [ "$have" -eq "$(echo $GL_PACKAGES | wc -w)" ]; then
  say "Vulkan/EGL loaders already in .gl/ ($have packages)"
else
  say "Vulkan/EGL loaders (.gl/: $GL_PACKAGES)"
  lists=$(mktemp -d)
  # (-oAPT::Sandbox::User=root: the download folder is ours, not the _apt user's)
  o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=$lists -oAPT::Sandbox::User=root"
  mkdir -p .gl "$lists/partial"
  apt-get $o update -qq
  (cd .gl && apt-get $o download $GL_PACKAGES)
  rm -rf "$lists"
fi
say "done: copy this checkout with .whl/ and .gl/ to the node (docs/offline-install.md)"
