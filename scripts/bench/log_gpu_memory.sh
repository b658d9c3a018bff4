#!/usr/bin/env bash
# Samples GPU and host memory every few seconds while a long evaluation runs, for
# scripts/bench/gpu_memory.py to summarise (docs/evaluation.md, "Throughput"):
#
#   bash scripts/bench/log_gpu_memory.sh LOG [SECONDS] &     # default every 20 s; kill it after the run
#
# Each sample: "T <unix time>", one line per GPU (index, memory used, utilisation), one line
# per process on a GPU (GPU uuid, pid, memory used: torch's pool, the renderer's and the CUDA
# context together), then "RSS_MB <resident MiB of all python3 processes> NPROC <count>".
set -u
case "${1:-}" in
  -h|--help) sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
  ""|-*) echo "usage: bash scripts/bench/log_gpu_memory.sh LOG [SECONDS]  (--help says more)" >&2; exit 2 ;;
esac
log=$1; every=${2:-20}
command -v nvidia-smi >/dev/null || { echo "log_gpu_memory: nvidia-smi not found (a GPU machine is needed)" >&2; exit 1; }
while true; do
  {
    echo "T $(date +%s)"
    nvidia-smi --query-gpu=index,memory.used,utilization.gpu --format=csv,noheader
    nvidia-smi --query-compute-apps=gpu_uuid,pid,used_memory --format=csv,noheader
    echo "RSS_MB $(ps -C python3 -o rss= | awk '{s += $1} END {print s / 1024}') NPROC $(ps -C python3 -o pid= | wc -l)"
  } >> "$log"
  sleep "$every"
done
