#!/usr/bin/env bash
# Issue 18, session 39 (BENCHMARKS.md, "AMLNet from random weights on dim and inpainted images"):
# session 38's fine-tunes could not move how the range is read, so here AMLNet (cpu_heat) learns
# from random weights, with the step count of the default's first phase (4,000 at batch 32, the
# default rate), on session 38's probe set: session 37's no-cart v3 images (40 % dim surroundings)
# with the robot's dark parts inpainted in a quarter of them (experiments/inpaint_dark.py); then
# session 38's size-cue check without the zoom stage, and the default AMLNet's rows beside it (RUNS/cue_default_nozoom)
# and the held-out set (reported only). Every stage resumes.
#   bash experiments/retrain_scratch.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s39}"
PY="${PYTHON:-python}"
[ -f "$DATA/s38_inpaint_train/camera.json" ] || { echo "missing $DATA/s38_inpaint_train: make it with experiments/inpaint_dark.py (BENCHMARKS.md, session 38)" >&2; exit 2; }
"$PY" -m rhaml_jax.train --stage amlnet --config cpu_heat --data "$DATA/s38_inpaint_train" --out "$RUNS/aml_scratch" \
  --seed 39 --steps 4000 --batch 32 --warmup 200 --val-every 1000 --ckpt-every 250 --val-batches 8 --no-progress \
  $( [ -d "$RUNS/aml_scratch/checkpoints" ] && echo --resume )
[ -d "$RUNS/export/aml_scratch" ] || "$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/aml_scratch', '$RUNS/export/aml_scratch')"
SETS=("$DATA"/s38_sc/uniform_{grey,black} "$DATA"/s38_sc/other_room "$DATA"/s38_sc2/uniform_{grey,black} "$DATA"/val_ood/sine "$DATA"/val_ood_s2/sine)
"$PY" experiments/size_cue.py check "${SETS[@]}" --out "$RUNS/cue_aml_scratch_nozoom" --evaluate-args="--no-zoom --amlnet $RUNS/export/aml_scratch"
"$PY" experiments/size_cue.py check "${SETS[@]}" --out "$RUNS/cue_default_nozoom" --evaluate-args="--no-zoom"   # the control
"$PY" experiments/size_cue.py check "$DATA"/heldout/{circle,sine} --out "$RUNS/heldout_aml_scratch_nozoom" \
  --evaluate-args="--no-zoom --amlnet $RUNS/export/aml_scratch"
