# Sourced by scripts/setup.sh and scripts/maint/lock.sh (not run on its own).
# install_torch_cpu VENV VERSION: installs torch==VERSION into VENV, its CPU build where the
# PyTorch CPU index is reachable, so that nothing pulls torch's CUDA wheels (several GB).
# Where that index is not reachable (offline mirrors, this project's CI) the package index
# is used as it is: pip's own configuration (find-links, local indexes) decides the build.
# FETCHBENCH_TORCH_INDEX picks another index; set it empty to use the package index only.
install_torch_cpu() {
  local venv=$1 version=$2
  local index=${FETCHBENCH_TORCH_INDEX-https://download.pytorch.org/whl/cpu}
  local extra=()
  if [ -n "$index" ] && "$venv/bin/python" -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1] + '/torch/', timeout=5)" "$index" 2>/dev/null; then
    extra=(--extra-index-url "$index")
  fi
  echo "[${SAY_PREFIX:-setup}] installing torch==$version (CPU build)${extra:+ from $index}"
  "$venv/bin/pip" install -q "torch==$version" "${extra[@]}"
}
