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
. "$(dirname "$0")/_test_sets.sh"
run=fine_native
refiner_run $run refiner_fine_native_cpu s40_refine_mix rhaml_jax/checkpoints/refiner_fine_more_cpu 42 \
  --steps 10000 --val-every 1000 --val-batches 8
val_bench bench_$run --starts noise --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner "$RUNS/export/$run" --fine-iter 2
