#!/usr/bin/env bash
# Issue 18, session 37 (BENCHMARKS.md, "Dim rooms in training do not take the long range away"):
# the default AMLNet and zoom stage fine-tuned (and a zoom stage trained from random weights) on
# no-cart v3 images of which 40 % have dim surroundings (`AppearanceConfig.dim_room_prob`, the
# robot's dark parts kept dark), then the size-cue check on session 36's composites
# (experiments/size_cue.py composite, written to DATA/size_cue and DATA/size_cue_s2). Every stage resumes (generation is a pure function of
# (seed, index); the checks keep their runs).
#   bash experiments/retrain_dim.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s37}"
PY="${PYTHON:-python}"
bash experiments/dim_room_data.sh "$DATA"
"$PY" -m rhaml_jax.train --stage amlnet --config cpu_heat --data "$DATA/s37_dim2_train" --out "$RUNS/aml_dim2" \
  --init rhaml_jax/checkpoints/heat_nocart_cpu --lr 5e-4 --warmup 100 --steps 1500 --batch 32 --val-every 500 \
  --ckpt-every 250 --val-batches 8 --no-progress $( [ -d "$RUNS/aml_dim2/checkpoints" ] && echo --resume )
"$PY" -m rhaml_jax.train --stage zoom --config zoom_cpu_luma --data "$DATA/s37_dim2_train" --out "$RUNS/zoom_dim2" \
  --init rhaml_jax/checkpoints/zoom_fit_cpu --lr 5e-4 --warmup 100 --steps 3000 --batch 32 --val-every 1000 \
  --ckpt-every 500 --val-batches 8 --w-xy 69.4 526 --no-progress $( [ -d "$RUNS/zoom_dim2/checkpoints" ] && echo --resume )
"$PY" -m rhaml_jax.train --stage zoom --config zoom_cpu_luma --data "$DATA/s37_dim2_train" --out "$RUNS/zoom_scratch" \
  --lr 1e-3 --warmup 200 --steps 5000 --batch 32 --val-every 1000 --ckpt-every 500 --val-batches 8 --w-xy 69.4 526 \
  --no-progress $( [ -d "$RUNS/zoom_scratch/checkpoints" ] && echo --resume )
for n in aml_dim2 zoom_dim2 zoom_scratch; do
  [ -d "$RUNS/export/$n" ] || "$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/$n', '$RUNS/export/$n')"
done
SETS=("$DATA"/size_cue/uniform_{grey,black} "$DATA"/size_cue/other_room "$DATA"/size_cue_s2/uniform_{grey,black} "$DATA"/val_ood/sine "$DATA"/val_ood_s2/sine)
cue() {  # the checks, then the held-out set (reported only)
  "$PY" experiments/size_cue.py check "${SETS[@]}" --out "$RUNS/cue_$1" --evaluate-args="$2"
  "$PY" experiments/size_cue.py check "$DATA"/heldout/{circle,sine} --out "$RUNS/heldout_$1" --evaluate-args="$2"
}
cue default_nozoom "--no-zoom"
cue aml_dim2_nozoom "--no-zoom --amlnet $RUNS/export/aml_dim2"
cue default ""
cue zoom_dim2 "--zoom $RUNS/export/zoom_dim2"
SETS+=("$DATA"/val_scen_s7_500/sine)
cue zoom_scratch "--zoom $RUNS/export/zoom_scratch"
