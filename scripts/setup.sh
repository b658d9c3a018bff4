#!/usr/bin/env bash
# One idempotent set-up for `make demo` and `make test`: a virtual environment with the
# package installed in editable mode, and a software Vulkan renderer (Mesa lavapipe >= 24.3)
# when SAPIEN finds no Vulkan device. Every step first checks whether it is already done,
# says what it does, and is skipped when there is nothing to do.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${FETCHBENCH_VENV:-.venv}
PY=${PYTHON:-python3}
say() { echo "[setup] $*"; }

# 1. Virtual environment.
if [ ! -x "$VENV/bin/python" ]; then
  say "creating virtual environment $VENV"
  "$PY" -m venv "$VENV"
fi

# 2. Packages. torch first and pinned to the CPU build, so that nothing that depends on it
#    pulls the CUDA wheels (several GB). Re-installed only when pyproject.toml changes.
stamp="$VENV/.fetchbench-installed"
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    say "installing torch==2.13.0 (CPU build)"
    "$VENV/bin/pip" install -q "torch==2.13.0"
  fi
  say "installing fetchbench_ms and its dependencies (editable)"
  "$VENV/bin/pip" install -q -e ".[dev]"
  echo "$want" > "$stamp"
else
  say "virtual environment $VENV is up to date"
fi

# 3. Software Vulkan renderer. SAPIEN renders on CPU only with lavapipe >= 24.3; Debian 12's
#    own Mesa (22.3) is too old, its bookworm-backports suite has 25.0.
if "$VENV/bin/python" -m fetchbench_ms.utils.vulkan_check >/dev/null 2>&1; then
  say "a Vulkan device works for SAPIEN"
else
  if [ "$(id -u)" != "0" ] && ! command -v sudo >/dev/null; then
    say "no working Vulkan device and not root: install mesa-vulkan-drivers >= 24.3 by hand"; exit 1
  fi
  SUDO=""; [ "$(id -u)" != "0" ] && SUDO=sudo
  . /etc/os-release
  if [ "${VERSION_CODENAME:-}" = "bookworm" ]; then
    if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
      say "adding Debian bookworm-backports (for Mesa 25 lavapipe)"
      echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee /etc/apt/sources.list.d/fetchbench-backports.list >/dev/null
    fi
    say "installing mesa-vulkan-drivers from bookworm-backports"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1 >/dev/null
  else
    say "installing mesa-vulkan-drivers (needs Mesa >= 24.3)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
  fi
  if "$VENV/bin/python" -m fetchbench_ms.utils.vulkan_check; then
    say "software Vulkan renderer works"
  else
    say "SAPIEN still finds no usable Vulkan device"; exit 1
  fi
fi
