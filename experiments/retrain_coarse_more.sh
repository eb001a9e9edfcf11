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
. "$(dirname "$0")/_test_sets.sh"
run=coarse_more
refiner_run $run refiner_cpu s40_refine_mix rhaml_jax/checkpoints/refiner_cpu 41 --steps 10000 --val-every 1000 --val-batches 8
for net in rhaml_jax/checkpoints/refiner_cpu "$RUNS/export/$run"; do
  val_bench "bench_$(basename "$net")" --starts noise --refiner "$net" --fine-refiner rhaml_jax/checkpoints/refiner_fine_more_cpu --fine-iter 2
done
