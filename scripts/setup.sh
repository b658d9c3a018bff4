#!/usr/bin/env bash
# One idempotent set-up for `make demo` and `make test`: a virtual environment with the
# package installed in editable mode, and a software Vulkan renderer (Mesa lavapipe >= 24.3)
# when SAPIEN finds no Vulkan device. Every step first checks whether it is already done,
# says what it does, and is skipped when there is nothing to do.
#
# Environment: FETCHBENCH_VENV (default .venv), PYTHON (default python3, >= 3.10),
# FETCHBENCH_TORCH_INDEX (where torch's CPU build comes from when it is reachable;
# default https://download.pytorch.org/whl/cpu; set it empty to use the package index only).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${FETCHBENCH_VENV:-.venv}
PY=${PYTHON:-python3}
TORCH_INDEX=${FETCHBENCH_TORCH_INDEX-https://download.pytorch.org/whl/cpu}
say() { echo "[setup] $*"; }
SUDO=""; [ "$(id -u)" != "0" ] && SUDO=sudo
apt_install() {
  if [ -n "$SUDO" ] && ! command -v sudo >/dev/null; then
    say "not root and no sudo: install $* by hand"; exit 1
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >/dev/null
}

# 1. Virtual environment (Debian/Ubuntu ship venv support as a separate package).
if [ ! -x "$VENV/bin/python" ]; then
  if ! command -v "$PY" >/dev/null; then
    say "installing python3"; apt_install python3
  fi
  if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 10))'; then
    say "$PY is $("$PY" -V 2>&1); FetchBench-MS needs Python >= 3.10 (set PYTHON=...)"; exit 1
  fi
  if ! "$PY" -c 'import ensurepip, venv' 2>/dev/null; then
    say "installing python3-venv"; apt_install python3-venv
  fi
  say "creating virtual environment $VENV"
  "$PY" -m venv "$VENV"
fi

# 2. Packages: exactly the versions of requirements.lock (every transitive dependency, as
#    tested; `make lock` regenerates it from pyproject.toml's ranges), then this package
#    editable without dependencies. torch first, and its CPU build where the PyTorch CPU
#    index is reachable, so that nothing pulls the CUDA wheels (several GB); the lock's
#    torch==2.13.0 then matches it. Re-installed only when pyproject.toml or the lock
#    changes (code changes need no re-install).
stamp="$VENV/.fetchbench-installed"
want=$(cat pyproject.toml requirements.lock | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    extra=()
    if [ -n "$TORCH_INDEX" ] && "$VENV/bin/python" -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1] + '/torch/', timeout=5)" "$TORCH_INDEX" 2>/dev/null; then
      extra=(--extra-index-url "$TORCH_INDEX")
    fi
    say "installing torch==2.13.0 (CPU build)${extra:+ from $TORCH_INDEX}"
    "$VENV/bin/pip" install -q "torch==2.13.0" "${extra[@]}"
  fi
  say "installing the locked dependencies (requirements.lock, $(grep -vc '^#' requirements.lock) packages)"
  "$VENV/bin/pip" install -q -r requirements.lock
  say "installing fetchbench_ms (editable, dependencies from the lock)"
  "$VENV/bin/pip" install -q --no-deps -e .
  echo "$want" > "$stamp"
else
  say "virtual environment $VENV is up to date (requirements.lock)"
fi

# 3. Software Vulkan renderer. SAPIEN renders on CPU only with lavapipe >= 24.3; Debian 12's
#    own Mesa (22.3) is too old, its bookworm-backports suite has 25.0.
#    The check renders a picture (~10 s: shader compilation), so its success is remembered
#    together with what it depends on (installed packages, Vulkan drivers) and redone only
#    when one of those changes.
vk_stamp="$VENV/.fetchbench-vulkan-ok"
vulkan_key() {
  echo "$want $(ls /usr/share/vulkan/icd.d/ /etc/vulkan/icd.d/ 2>/dev/null | tr '\n' ' ') $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)"
}
if [ -f "$vk_stamp" ] && [ "$(cat "$vk_stamp")" = "$(vulkan_key)" ]; then
  say "a Vulkan device works for SAPIEN (checked before, drivers unchanged)"
elif "$VENV/bin/python" -m fetchbench_ms.utils.vulkan_check >/dev/null 2>&1; then
  say "a Vulkan device works for SAPIEN"
  vulkan_key > "$vk_stamp"
else
  . /etc/os-release
  if [ "${VERSION_CODENAME:-}" = "bookworm" ]; then
    if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
      say "adding Debian bookworm-backports (for Mesa 25 lavapipe)"
      echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee /etc/apt/sources.list.d/fetchbench-backports.list >/dev/null
    fi
    say "installing mesa-vulkan-drivers from bookworm-backports"
    apt_install -t bookworm-backports mesa-vulkan-drivers libvulkan1
  else
    say "installing mesa-vulkan-drivers (needs Mesa >= 24.3)"
    apt_install mesa-vulkan-drivers libvulkan1
  fi
  if "$VENV/bin/python" -m fetchbench_ms.utils.vulkan_check; then
    say "software Vulkan renderer works"
    vulkan_key > "$vk_stamp"
  else
    say "SAPIEN still finds no usable Vulkan device"; exit 1
  fi
fi
