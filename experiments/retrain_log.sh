#!/usr/bin/env bash
# Issue 18, session 38 (BENCHMARKS.md, "A log-luminance channel"): the default AMLNet and zoom
# stage fine-tuned with the log luminance in place of one luminance copy (configs cpu_heat_log,
# zoom_cpu_log; started exactly from the defaults), on session 37's no-cart v3 images with 40 % dim
# surroundings, with session 37's steps, rates and seed (its cpu_heat / zoom_cpu_luma runs are
# the controls: experiments/retrain_dim.sh); then the size-cue check (experiments/size_cue.py
# composite, written to DATA/s38_sc and DATA/s38_sc2, which prints the defaults' rows). Every
# stage resumes.
#   bash experiments/retrain_log.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s38}"
PY="${PYTHON:-python}"
bash experiments/dim_room_data.sh "$DATA"
"$PY" -m rhaml_jax.train --stage amlnet --config cpu_heat_log --data "$DATA/s37_dim2_train" --out "$RUNS/aml_log" \
  --init rhaml_jax/checkpoints/heat_nocart_cpu --lr 5e-4 --warmup 100 --steps 1500 --batch 32 --val-every 500 \
  --ckpt-every 250 --val-batches 8 --no-progress $( [ -d "$RUNS/aml_log/checkpoints" ] && echo --resume )
[ -d "$RUNS/export/aml_log" ] || "$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/aml_log', '$RUNS/export/aml_log')"
"$PY" experiments/size_cue.py composite --robot "$DATA/val_ood/sine" --background "$DATA/val_ood_s2/sine" --out "$DATA/s38_sc" \
  --only "uniform black" "uniform grey" "other room"     # the default IML's rows; kept runs are skipped
"$PY" experiments/size_cue.py composite --robot "$DATA/val_ood_s2/sine" --out "$DATA/s38_sc2" --only "uniform black" "uniform grey"
SETS=("$DATA"/s38_sc/uniform_{grey,black} "$DATA"/s38_sc/other_room "$DATA"/s38_sc2/uniform_{grey,black} "$DATA"/val_ood/sine "$DATA"/val_ood_s2/sine)
cue() {  # the checks, then the held-out set (reported only)
  "$PY" experiments/size_cue.py check "${SETS[@]}" --out "$RUNS/cue_$1" --evaluate-args="$2"
  "$PY" experiments/size_cue.py check "$DATA"/heldout/{circle,sine} --out "$RUNS/heldout_$1" --evaluate-args="$2"
}
cue aml_log_nozoom "--no-zoom --amlnet $RUNS/export/aml_log"
"$PY" -m rhaml_jax.train --stage zoom --config zoom_cpu_log --data "$DATA/s37_dim2_train" --out "$RUNS/zoom_log" \
  --init rhaml_jax/checkpoints/zoom_fit_cpu --lr 5e-4 --warmup 100 --steps 3000 --batch 32 --val-every 1000 \
  --ckpt-every 500 --val-batches 8 --w-xy 69.4 526 --no-progress $( [ -d "$RUNS/zoom_log/checkpoints" ] && echo --resume )
[ -d "$RUNS/export/zoom_log" ] || "$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/zoom_log', '$RUNS/export/zoom_log')"
cue aml_log "--amlnet $RUNS/export/aml_log --zoom rhaml_jax/checkpoints/zoom_fit_cpu"
cue log_pair "--amlnet $RUNS/export/aml_log --zoom $RUNS/export/zoom_log"
