#!/usr/bin/env bash
# One idempotent set-up for `make demo` and `make test`: a virtual environment with the
# package installed in editable mode, and a software Vulkan renderer (Mesa lavapipe >= 24.3)
# when SAPIEN finds no Vulkan device. Every step first checks whether it is already done,
# says what it does, and is skipped when there is nothing to do.
#
# Environment: FETCHBENCH_VENV (default .venv), PYTHON (default python3, >= 3.10; the lock is
# tested on the version its header names), FETCHBENCH_TORCH_INDEX (where torch's CPU build
# comes from when it is reachable; default https://download.pytorch.org/whl/cpu; set it
# empty to use the package index only), FETCHBENCH_UNLOCKED=1 (see step 2).
set -euo pipefail
case "${1:-}" in -h|--help) sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;; esac
cd "$(dirname "$0")/.."
VENV=${FETCHBENCH_VENV:-.venv}
PY=${PYTHON:-python3}
say() { echo "[setup] $*"; }
# One set-up of a virtual environment at a time (`make demo` and `make test` started together
# on a fresh machine would otherwise install into the same venv at once).
mkdir -p "$(dirname "$VENV")"
exec 9>"$VENV.setup-lock"
if ! flock -n 9; then say "another set-up of $VENV is running: waiting for it"; flock 9; fi
SUDO=""; [ "$(id -u)" != "0" ] && SUDO=sudo
apt_install() {
  if [ -n "$SUDO" ] && ! command -v sudo >/dev/null; then
    say "not root and no sudo: install $* by hand"; exit 1
  fi
  apt_waiting $SUDO apt-get update -qq
  apt_waiting env DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@"
}
# Run an apt command, waiting while another apt or dpkg holds its lock (a second set-up, or
# the system's unattended upgrades): `apt-get update` does not honour DPkg::Lock::Timeout.
# Any other failure ends the set-up at once.
apt_waiting() {
  local out i
  for i in $(seq 120); do
    if out=$("$@" 2>&1); then return 0; fi
    case "$out" in
      *"Could not get lock"*|*"Unable to lock"*)
        [ "$i" = 1 ] && say "another apt or dpkg holds its lock: waiting (up to 10 minutes)"
        sleep 5 ;;
      *) echo "$out" >&2; return 1 ;;
    esac
  done
  echo "$out" >&2; return 1
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

# 2. Packages, exactly the tested versions: torch's CPU build first (scripts/torch_cpu.sh: so
#    that nothing pulls the CUDA wheels, several GB), then every dependency at its version in
#    requirements.lock (`make lock` regenerates it), then this package in editable mode with
#    --no-deps (its dependencies are all in the lock), then the packages of
#    requirements-nodeps.txt with --no-deps (cgn-pytorch: its pinned requirements are stale;
#    only its checkpoint is read). Redone only when requirements.lock, requirements-nodeps.txt
#    or pyproject.toml changes (editable: code changes need no re-install).
#    FETCHBENCH_UNLOCKED=1 installs the newest versions pyproject.toml allows instead
#    (untested; for a Python version the lock cannot be installed on).
LOCK=requirements.lock
NODEPS=requirements-nodeps.txt
stamp="$VENV/.fetchbench-installed"
want=$(cat pyproject.toml "$LOCK" "$NODEPS" | sha256sum | cut -d' ' -f1)
# `pip check`, less its complaints about requirements-nodeps.txt's packages' own pins.
nodeps_names=$(sed -n 's/^\([A-Za-z0-9_.-]*\)==.*/\1/p' "$NODEPS")
pip_check() {
  local out
  out=$("$VENV/bin/pip" check 2>&1) && return 0
  for name in $nodeps_names; do out=$(echo "$out" | grep -iv "^$name " || true); done
  [ -z "$out" ] && return 0
  echo "$out"; return 1
}
install_nodeps() {
  say "installing $(echo $nodeps_names) with --no-deps ($NODEPS)"
  "$VENV/bin/pip" install -q --no-deps --require-hashes -r "$NODEPS"
}
[ "${FETCHBENCH_UNLOCKED:-}" = 1 ] && want="unlocked-$want"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  torch_pin=$(sed -n 's/^torch==//p' "$LOCK")
  have_torch=$("$VENV/bin/python" -c "import importlib.metadata as m; print(m.version('torch').split('+')[0])" 2>/dev/null || true)
  if [ "$have_torch" != "$torch_pin" ]; then
    . scripts/torch_cpu.sh
    install_torch_cpu "$VENV" "$torch_pin"
  fi
  if [ "${FETCHBENCH_UNLOCKED:-}" = 1 ]; then
    say "FETCHBENCH_UNLOCKED=1: installing fetchbench_ms (editable) with the newest dependencies pyproject.toml allows (not the tested versions)"
    "$VENV/bin/pip" install -q -e ".[dev]"
    install_nodeps
  else
    lock_py=$(sed -n 's/^# Made on .* with Python \([0-9]*\.[0-9]*\).*/\1/p' "$LOCK")
    venv_py=$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
    if [ -n "$lock_py" ] && [ "$lock_py" != "$venv_py" ]; then
      say "note: $LOCK was made on Python $lock_py, $VENV has Python $venv_py; installing it anyway"
    fi
    say "installing the locked dependencies ($LOCK: $(grep -c '^[^#]' "$LOCK") packages)"
    if ! "$VENV/bin/pip" install -q -r "$LOCK"; then
      say "pip could not install $LOCK on Python $venv_py. Choices: PYTHON=python$lock_py (the tested version," \
          "with a new FETCHBENCH_VENV), FETCHBENCH_UNLOCKED=1 (newest versions allowed by pyproject.toml," \
          "untested), or \`make lock\` to lock for this Python"
      exit 1
    fi
    say "installing fetchbench_ms (editable, --no-deps: its dependencies come from the lock)"
    "$VENV/bin/pip" install -q --no-deps -e .
    install_nodeps
    # --no-deps would hide a dependency added to pyproject.toml but not yet to the lock
    if ! pip_check; then
      say "the installed packages do not satisfy pyproject.toml: run \`make lock\` after changing its dependencies"
      exit 1
    fi
  fi
  echo "$want" > "$stamp"
else
  say "virtual environment $VENV is up to date ($LOCK unchanged)"
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
