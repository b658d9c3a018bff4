#!/usr/bin/env bash
# One shard of an imitation run on one GPU node, within a fixed time (docs/imitation.md). The
# training files of the whole dataset (~15 GB) take ~2-3 hours of a 16-core node to convert,
# so a run can go over shards: each call converts the next demos while the trainers learn
# from the chunks finished so far:
#   - scripts/imitation/convert_demos_for_imitation.py converts demos [START, START+COUNT) of TRAJ into
#     ROOT/data (a chunk of 128 demos at a time; the manifest is rewritten after each);
#   - meanwhile the trainers run in rounds of ROUND seconds, each round resuming
#     ROOT/runs/<kind>/checkpoint.pt on whatever chunks are finished (--new-data; every data
#     hash and the step it began at go into the checkpoint and the export's JSON) and exporting
#     ROOT/export/imit_<kind>.pt (fp16) + .json at its end;
#   - everything has stopped SECONDS after the start.
# Keep (or restore) ROOT/runs/<kind>/checkpoint.pt from the previous shard to go on with a run.
#
#   bash scripts/imitation/imitation_shard.sh ROOT TRAJ START COUNT SECONDS
#
# Environment: STEPS_MLP, STEPS_TRANSFORMER, STEPS_DIFFUSION (each run's schedule length;
# defaults 30000 / 16000 / 16000), NUM_ENVS (replay processes, default 13 beside the
# trainers, 16 alone), ROUND (seconds, default 300), DEVICE (default cuda), TRAIN_ARGS (more
# trainer flags), PYTHON, TRAIN_SECONDS: when set, convert alone until SECONDS - TRAIN_SECONDS, then
# train (on the H100 the renderer and the trainers share the GPU: a chunk took 385 s alone and
# 565 s beside the trainers, docs/imitation.md "The first checkpoints"), and FRAME_STRIDE: the
# converter's --frame-stride K (default 1; K keeps every K-th step of each stage and renders
# only those, docs/imitation.md "Frame stride"). Keep K for the whole run: the trainers refuse
# a checkpoint trained at another K; its policies are deployed with --policy-stride K.
# OVERLAP_REPLAY=1 (with FRAME_STRIDE > 1) adds the converter's --overlap-replay: the next
# chunk's state-only replay runs in the background during a chunk's render pass (measured on
# the 16-core H100 node: no gain, the two share the CPUs; docs/imitation.md).
# CHUNK: demos per converter chunk (default 128; START must be a multiple of it): smaller
# chunks waste less of the time limit, which the converter never starts a chunk past.
# WAIT_FOR=PATH (with TRAIN_SECONDS): the trainers start only once PATH exists, so a run's
# checkpoints can still be arriving (one transfer a call) while the demos convert.
# KINDS: the trainers to run (default "mlp transformer diffusion"; add act for ACT, whose
# schedule is STEPS_ACT, default 16000). INIT_FROM=DIR: a trainer without a checkpoint in
# ROOT/runs/<kind> starts from DIR/imit_<kind>.pt (an earlier shard's export: the trainers'
# --init-from, weights and step without the optimiser's state; ~15 MB for three against the
# full checkpoints' 85 MB). SAVE_EVERY=STEPS: the trainers' --save-every (a candidate export every
# STEPS steps in ROOT/runs/<kind>/candidates/, chosen from on val tasks afterwards by
# scripts/imitation/select_checkpoint.py; docs/imitation.md "Choosing the checkpoint").
set -euo pipefail
case "${1:-}" in -h|--help) sed -n '2,39p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;; esac
ROOT=${1:?usage: imitation_shard.sh ROOT TRAJ START COUNT SECONDS}
TRAJ=${2:?TRAJ: the demos h5}
START=${3:?START: the first demo, a multiple of CHUNK (128)}
COUNT=${4:?COUNT: demos to convert}
SECONDS_TOTAL=${5:?SECONDS: seconds this job may take}
PY=${PYTHON:-python3}
ROUND=${ROUND:-${TRAIN_SECONDS:-300}}
# Replay processes: all 16 cores when converting alone, else 13 beside the three trainers.
if [[ -n "${TRAIN_SECONDS:-}" ]]; then NUM_ENVS=${NUM_ENVS:-16}; else NUM_ENVS=${NUM_ENVS:-13}; fi
overlap=""
[[ "${OVERLAP_REPLAY:-0}" != 1 ]] || overlap="--overlap-replay"
declare -A STEPS=([mlp]=${STEPS_MLP:-30000} [transformer]=${STEPS_TRANSFORMER:-16000} [diffusion]=${STEPS_DIFFUSION:-16000}
                  [act]=${STEPS_ACT:-16000})
read -r -a kinds <<< "${KINDS:-mlp transformer diffusion}"
for kind in "${kinds[@]}"; do
    [[ -n "${STEPS[$kind]:-}" ]] || { echo "KINDS: unknown trainer '$kind'; valid: ${!STEPS[*]}" >&2; exit 2; }
    if [[ -n "${INIT_FROM:-}" && ! -f "$INIT_FROM/imit_$kind.pt" && ! -f "$INIT_FROM/imit_$kind.pt.planes.xz" ]]; then
        echo "INIT_FROM: no $INIT_FROM/imit_$kind.pt for the $kind trainer" >&2; exit 2
    fi
done
deadline=$(( $(date +%s) + SECONDS_TOTAL ))
mkdir -p "$ROOT/export" "$ROOT/logs" "$ROOT/runs"
say() { echo "[shard $(date +%H:%M:%S)] $*" | tee -a "$ROOT/logs/shard.log"; }

say "converting demos $START..$((START + COUNT)) of $TRAJ (frame stride ${FRAME_STRIDE:-1}${overlap:+, replays overlapped}); trainers in rounds of ${ROUND} s until $(date -d @$deadline +%H:%M:%S)"
$PY scripts/imitation/convert_demos_for_imitation.py --traj-path "$TRAJ" --out "$ROOT/data" --start "$START" --count "$COUNT" \
    --chunk "${CHUNK:-128}" --num-envs "$NUM_ENVS" --device "${DEVICE:-cuda}" --time-limit $((SECONDS_TOTAL - ${TRAIN_SECONDS:-120})) \
    --frame-stride "${FRAME_STRIDE:-1}" $overlap \
    >> "$ROOT/logs/convert.log" 2>&1 &
converter=$!
until compgen -G "$ROOT/data/chunk_*.imit.h5" > /dev/null; do
    kill -0 $converter 2> /dev/null || { say "the converter stopped before its first chunk"; tail -20 "$ROOT/logs/convert.log"; exit 1; }
    sleep 5
done
if [[ -n "${TRAIN_SECONDS:-}" ]]; then
    say "converting alone, then training for the last ${TRAIN_SECONDS} s"
    wait $converter || say "the converter exited with $?"
    if [[ -n "${WAIT_FOR:-}" ]]; then
        say "waiting for $WAIT_FOR before training"
        until [[ -e "$WAIT_FOR" ]]; do
            (( $(date +%s) < deadline - 150 )) || { say "$WAIT_FOR never came: no training"; exit 1; }
            sleep 5
        done
    fi
fi
round=0
while :; do
    left=$(( deadline - $(date +%s) ))
    (( left >= 150 )) || break
    limit=$(( left - 60 < ROUND ? left - 60 : ROUND ))
    round=$((round + 1))
    say "round $round: $(ls "$ROOT"/data/chunk_*.imit.h5 | wc -l) chunks, ${limit} s"
    pids=()
    for kind in "${kinds[@]}"; do
        init=()  # read only while the run folder has no checkpoint (a later round resumes its own)
        [[ -z "${INIT_FROM:-}" ]] || init=(--init-from "$INIT_FROM/imit_$kind.pt")
        save=()  # candidates for scripts/imitation/select_checkpoint.py
        [[ -z "${SAVE_EVERY:-}" ]] || save=(--save-every "$SAVE_EVERY")
        $PY baselines/imitation/train_$kind.py --data "$ROOT/data" --run "$ROOT/runs/$kind" --steps "${STEPS[$kind]}" \
            --time-limit "$limit" --new-data --eval-every 0 --export --export-path "$ROOT/export/imit_$kind.pt" \
            --device "${DEVICE:-cuda}" "${init[@]}" "${save[@]}" ${TRAIN_ARGS:-} >> "$ROOT/logs/train_$kind.log" 2>&1 &
        pids+=($!)
    done
    status=0
    for pid in "${pids[@]}"; do wait "$pid" || status=$?; done
    (( status == 0 )) || { say "a trainer failed (exit $status)"; tail -20 "$ROOT"/logs/train_*.log; exit 1; }
    done_all=1
    for kind in "${kinds[@]}"; do grep -q "done: ${STEPS[$kind]} steps" "$ROOT/logs/train_$kind.log" || done_all=0; done
    (( done_all == 0 )) || { say "every schedule is finished"; break; }
done
[[ -n "${TRAIN_SECONDS:-}" ]] || wait $converter || say "the converter exited with $?"
say "finished: $(grep -h 'chunks done' "$ROOT/logs/convert.log" | tail -1)"
touch "$ROOT/done"
