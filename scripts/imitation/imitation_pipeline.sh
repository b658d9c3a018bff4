#!/usr/bin/env bash
# The imitation baselines from nothing on one GPU node (16 cores): demos -> training files ->
# the four policies (MLP, Transformer, diffusion, ACT), a candidate every STEPS/5 steps -> the
# checkpoint of each chosen on 100 `val` tasks (scripts/imitation/select_checkpoint.py) -> every method on
# them on `val`. Every stage resumes, so the same command continues after an interruption (the
# root folder must survive). Test tasks are never used here: they are run once, by `fetchbench
# eval --suite test`, for the shipped checkpoints.
#
#   bash scripts/imitation/imitation_pipeline.sh ROOT [DEMOS] [STEPS]
#     ROOT   work folder (demos, data, runs, eval); DEMOS successful demos (default 5000);
#     STEPS  training steps per policy (default 30000)
#
# Checkpoints end in ROOT/export/imit_<kind>.{pt,json} (the JSON records the val choice); ship them
# with scripts/maint/ship_imitation.py.
set -euo pipefail
case "${1:-}" in -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;; esac
ROOT=${1:?usage: imitation_pipeline.sh ROOT [DEMOS] [STEPS]}
DEMOS=${2:-5000}
STEPS=${3:-30000}
PY=${PYTHON:-python3}
mkdir -p "$ROOT/export"

# 1. demonstrations on the train suite (docs/demos.md)
$PY -m fetchbench_ms.demos.run -e FetchBench-v0 --task-suite train -n "$DEMOS" --only-count-success \
    --record-dir "$ROOT/demos" --traj-name train --num-procs 16
# 2. compact training files through ManiSkill's replay tool (docs/imitation.md)
$PY scripts/imitation/convert_demos_for_imitation.py --traj-path "$ROOT/demos/FetchBench-v0/motionplanning/train.h5" \
    --out "$ROOT/data" --count "$DEMOS" --chunk 128 --num-envs 16 --device cuda
# 3. the four policies at once on the one GPU (small models); each validates on 32 val tasks
for kind in mlp transformer diffusion act; do
    $PY baselines/imitation/train_$kind.py --data "$ROOT/data" --run "$ROOT/runs/$kind" --steps "$STEPS" \
        --save-every $(( STEPS / 5 )) --eval-workers 5 > "$ROOT/export/train_$kind.log" 2>&1 &
done
wait
# 3b. each policy's checkpoint: the candidate with the best success on val tasks 0:100
for kind in mlp transformer diffusion act; do
    $PY scripts/imitation/select_checkpoint.py --candidates "$ROOT/runs/$kind/candidates" --tasks 0:100 --workers 16 \
        --out "$ROOT/select/e2e-$kind" --export-path "$ROOT/export/imit_$kind.pt"
done
# 4. every method on the first 100 val tasks (never test here)
for method in e2e-mlp e2e-transformer e2e-diffusion e2e-act cgn-imit-mlp cgn-imit-transformer cgn-imit-diffusion \
    cgn-imit-act; do
    kind=${method##*-}
    $PY -m fetchbench_ms eval --method "$method" --suite val --tasks 0:100 --workers 16 \
        --policy-checkpoint "$ROOT/export/imit_$kind.pt" --out "$ROOT/eval/$method"
done
