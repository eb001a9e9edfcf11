#!/usr/bin/env bash
# Issue 15, session 41 (BENCHMARKS.md, "The coarse refiner on session 40's images"): the default coarse
# refiner (refiner_cpu, session 18: 20,000 steps on fewer images) trained 10,000 more steps at batch 16
# from coarse starts (the paper's noise and IML-like errors), on session 40's 9,600 images (v1 + v3),
# as session 40 did for the fine refiner; then the cascade from the paper's noise on 2 x 100
# validation frames (our look, seeds 7 and 8; experiments/bench_refine.py) with the default fine
# refiner. Every stage resumes. Needs session 40's image mix (experiments/retrain_fine_more.sh).
#   bash experiments/retrain_coarse_more.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s41}"
PY="${PYTHON:-python}"
run=coarse_more
"$PY" -m rhaml_jax.train --stage refiner --config refiner_cpu --data "$DATA/s40_refine_mix" --out "$RUNS/$run" \
  --init rhaml_jax/checkpoints/refiner_cpu --lr 3e-4 --warmup 100 --steps 10000 --batch 16 --seed 41 \
  --val-every 1000 --ckpt-every 250 --val-batches 8 --no-progress $( [ -d "$RUNS/$run/checkpoints" ] && echo --resume )
[ -d "$RUNS/export/$run" ] || "$PY" -c "from rhaml_jax.refine import export_refiner as e; e('$RUNS/$run', '$RUNS/export/$run')"
for s in 7 8; do
  for net in rhaml_jax/checkpoints/refiner_cpu "$RUNS/export/$run"; do
    out="$RUNS/bench_$(basename "$net")_s$s.json"
    [ -f "$out" ] || "$PY" experiments/bench_refine.py --data "$DATA/val_scen_s${s}_500/circle" "$DATA/val_scen_s${s}_500/sine" \
      --starts noise --stride 10 --refiner "$net" --no-oracle --json "$out" \
      --fine-refiner rhaml_jax/checkpoints/refiner_fine_more_cpu --fine-iter 2
  done
done
