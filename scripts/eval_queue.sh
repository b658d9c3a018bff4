#!/usr/bin/env bash
# Many evaluations on one machine with several GPUs: one lane per GPU, each running the
# queue's next run with its own GPU, cores and workers, until the queue is empty.
#
#   bash scripts/eval_queue.sh JOBS OUT [WORKERS_PER_LANE]      # default 16 workers a lane
#
# JOBS: one run a line, "NAME [VAR=VALUE ...] ARGS..." with ARGS those of `fetchbench eval` but
# --workers and --out, e.g. "ga-mesh-trajopt-paper-val600 --method ga-mesh-trajopt --suite val
# --tasks 0:600"; VAR=VALUE words before ARGS set that run's environment
# (FETCHBENCH_TRAJOPT_DEVICE=cpu: its optimiser on the CPU).
# Lines appended to OUT/queue while it runs are run too. A run goes to OUT/NAME (a run already
# there resumes), its log to OUT/logs/NAME.log, its lane, start, end (unix s) and exit status to
# OUT/logs/times.txt; on a GPU machine, memory is sampled into OUT/logs/gpu-memory.log
# (scripts/bench/log_gpu_memory.sh, every $MEMLOG_SECONDS s, default 20). Lanes: the GPUs nvidia-smi lists (CUDA_VISIBLE_DEVICES),
# or $LANES lanes on the CPU when it lists none; the cores are split between the lanes
# (taskset) and each worker runs one torch thread. $PYTHON: the interpreter (default python3).
set -euo pipefail
case "${1:-}" in -h|--help) sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;; esac
if [ $# -lt 2 ] || [ ! -f "$1" ]; then
  echo "usage: bash scripts/eval_queue.sh JOBS OUT [WORKERS_PER_LANE]  (JOBS: a file of 'NAME ARGS...' lines; --help)" >&2
  exit 2
fi
jobs=$1; out=$2; workers=${3:-16}
case "$workers" in ''|*[!0-9]*|0) echo "eval_queue: WORKERS_PER_LANE must be a whole number >= 1, not '$workers'" >&2; exit 2 ;; esac
here=$(cd "$(dirname "$0")/.." && pwd)
python=${PYTHON:-python3}
gpus=$( (nvidia-smi -L 2>/dev/null || true) | grep -c '^GPU' || true)
lanes=$gpus; [ "$lanes" -gt 0 ] || lanes=${LANES:-1}
runs=$(grep -v '^[[:space:]]*\(#.*\)\?$' "$jobs" || true)  # without blank lines and comments
if [ -z "$runs" ]; then echo "eval_queue: $jobs has no run to do" >&2; exit 1; fi
mkdir -p "$out/logs"
printf '%s\n' "$runs" >> "$out/queue"
cores=$(nproc); per=$(( cores / lanes )); [ "$per" -ge 1 ] || per=1
memlog=
if [ "$gpus" -gt 0 ]; then
  bash "$here/scripts/bench/log_gpu_memory.sh" "$out/logs/gpu-memory.log" "${MEMLOG_SECONDS:-20}" & memlog=$!
  trap 'kill $memlog 2>/dev/null || true' EXIT
fi
echo "[eval_queue] $lanes lane(s), $per cores and $workers workers each; queue $out/queue"

lane() {  # lane INDEX: pop and run jobs until the queue is empty
  local i=$1 line name args start rc words envs
  while true; do
    line=$(flock "$out/queue.lock" bash -c 'f=$1; l=$(head -n 1 "$f"); sed -i 1d "$f"; printf "%s" "$l"' _ "$out/queue")
    [ -n "$line" ] || return 0
    name=${line%% *}; args=${line#"$name"}
    read -r -a words <<< "$args"; envs=()
    while [ ${#words[@]} -gt 0 ] && [[ ${words[0]} =~ ^[A-Za-z_][A-Za-z0-9_]*= ]]; do
      envs+=("${words[0]}"); words=("${words[@]:1}")
    done
    start=$(date +%s); rc=0
    echo "[eval_queue] lane $i: $name"
    env ${gpus:+CUDA_VISIBLE_DEVICES=$i} OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 "${envs[@]}" \
      taskset -c $(( i * per ))-$(( i * per + per - 1 )) \
      "$python" -m fetchbench_ms eval "${words[@]}" --workers "$workers" --out "$out/$name" > "$out/logs/$name.log" 2>&1 || rc=$?
    echo "$name lane=$i start=$start end=$(date +%s) rc=$rc" >> "$out/logs/times.txt"
    echo "[eval_queue] lane $i: $name ended (exit $rc)"
  done
}
[ "$gpus" -gt 0 ] || gpus=  # no GPU: the lanes set no CUDA_VISIBLE_DEVICES
for i in $(seq 0 $(( lanes - 1 ))); do lane "$i" & done
wait $(jobs -p | grep -vx "${memlog:-none}")
failed=$(grep -c ' rc=[1-9]' "$out/logs/times.txt" || true)
echo "[eval_queue] done: $(wc -l < "$out/logs/times.txt") run(s) in $out/logs/times.txt, $failed failed"
[ "$failed" -eq 0 ]
