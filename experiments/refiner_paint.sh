#!/usr/bin/env bash
# Issue 15, session 46 (BENCHMARKS.md, "Refiners trained on repainted renders"): the coarse and the fine
# refiner fine-tuned 5,000 steps with their renders repainted half the time (`RefinerConfig.paint_prob`
# 0.5, configs refiner_paint_cpu / refiner_fine_paint_cpu) on the scorer's image mix (half the robots of
# s44_flip_mono in one paint, with session 40's v1 + v3: experiments/flip_wide.sh makes it), both at
# once; then the cascade from the paper's noise on one circle of each validation look (look_bench, experiments/_test_sets.sh).
# Every stage resumes.
#   bash experiments/refiner_paint.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s46}"
PY="${PYTHON:-python}"
. "$(dirname "$0")/_test_sets.sh"
C=rhaml_jax/checkpoints
refiner_run paint refiner_paint_cpu s44_flip_mix $C/refiner_cpu 46 --steps 5000 --val-every 1000 --val-batches 8 \
  > "$RUNS/paint.log" 2>&1 &
refiner_run fine_paint refiner_fine_paint_cpu s44_flip_mix $C/refiner_fine_more_cpu 461 --steps 5000 --val-every 1000 \
  --val-batches 8 > "$RUNS/fine_paint.log" 2>&1 &
wait
FINE=($C/refiner_fine_more_cpu $C/refiner_fine_native_cpu)
look_bench bench_default --refiner $C/refiner_cpu --fine-refiner "${FINE[@]}"
look_bench bench_coarse --refiner "$RUNS/export/paint" --fine-refiner "${FINE[@]}"
look_bench bench_both --refiner "$RUNS/export/paint" --fine-refiner "$RUNS/export/fine_paint" $C/refiner_fine_native_cpu
look_bench bench_paint --refiner "$RUNS/export/paint" --fine-refiner "$RUNS/export/fine_paint"
# The test and held-out sets, reported only (after the choice on validation: `compare_validation.py
# wide_s45 paint_both_s46`): the whole pipeline with the defaults, which are now these refiners, then
# issue 15's table with them and the default scorer (_test_sets.sh's test_sets).
REFINER=$C/refiner_paint_cpu BENCH_ARGS="--scorer $C/scorer_flip_wide_cpu --flip-threshold 0.8 --post-iter 0" \
  test_sets paint "$C/refiner_fine_paint_cpu $C/refiner_fine_native_cpu" 2 fine
