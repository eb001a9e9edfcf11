#!/usr/bin/env bash
# Issue 15, session 42 (BENCHMARKS.md, "The fine refiner on renders at the image's pixel centres"):
# the default fine refiner (refiner_fine_more_cpu) trained 10,000 more steps at batch 16 from fine
# starts on session 40's images, with its render made at the image's own pixel centres and cropped
# as the observed image is (RefinerConfig.native = 128: config refiner_fine_native_cpu); then the
# cascade from the paper's noise on 2 x 100 validation frames (our look, seeds 7 and 8;
# experiments/bench_refine.py), two fine iterations. Every stage resumes.
# Needs session 40's images (experiments/retrain_fine_more.sh renders them).
#   bash experiments/retrain_fine_native.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s42}"
PY="${PYTHON:-python}"
run=fine_native
"$PY" -m rhaml_jax.train --stage refiner --config refiner_fine_native_cpu --data "$DATA/s40_refine_mix" --out "$RUNS/$run" \
  --init rhaml_jax/checkpoints/refiner_fine_more_cpu --lr 3e-4 --warmup 100 --steps 10000 --batch 16 --seed 42 \
  --val-every 1000 --ckpt-every 250 --val-batches 8 --no-progress $( [ -d "$RUNS/$run/checkpoints" ] && echo --resume )
[ -d "$RUNS/export/$run" ] || "$PY" -c "from rhaml_jax.refine import export_refiner as e; e('$RUNS/$run', '$RUNS/export/$run')"
for s in 7 8; do
  out="$RUNS/bench_${run}_s$s.json"
  [ -f "$out" ] || "$PY" experiments/bench_refine.py --data "$DATA/val_scen_s${s}_500/circle" "$DATA/val_scen_s${s}_500/sine" \
    --starts noise --stride 10 --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner "$RUNS/export/$run" --fine-iter 2 \
    --no-oracle --json "$out"
done
