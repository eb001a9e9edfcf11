#!/usr/bin/env bash
# Issue 15, session 40 (BENCHMARKS.md, "How many iterations of each refiner"): the cascade from the
# paper's noise on 2 x 100 validation frames (our look, seeds 7 and 8, every 10th frame of circle +
# sine) with 1-4 iterations of the coarse refiner (refiner_cpu) and 1-2 of the fine one (the default,
# refiner_fine_long_cpu); experiments/bench_refine.py, one JSON per setting (a rerun skips it).
#   bash experiments/refine_iterations.sh DATA_ROOT OUT_DIR
set -euo pipefail
DATA="${1:-/work/data}"; OUT="${2:-/work/runs/s40}"
PY="${PYTHON:-python}"
for s in 7 8; do for n in 1 2 3 4; do for f in 1 2; do
  out="$OUT/iter_n${n}_f${f}_s$s.json"
  [ -f "$out" ] || "$PY" experiments/bench_refine.py --data "$DATA/val_scen_s${s}_500/circle" "$DATA/val_scen_s${s}_500/sine" \
    --starts noise --stride 10 --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner rhaml_jax/checkpoints/refiner_fine_long_cpu \
    --no-oracle --n-iter $n --fine-iter $f --json "$out" > "${out%.json}.log" 2>&1
done; done; done
# After the choice (fine_iter 2, on validation: LABEL=fine_iter2 EXTRA="--fine-iter 2"
# experiments/validate_networks.sh, then experiments/compare_validation.py fine_mix fine_iter2), the test
# and held-out sets, reported only: the whole pipeline, then issue 15's table (from the paper's noise and
# from the IML, every 5th frame the IML detected). Session 39's runs of retrain_fine_plain.sh are the
# one-iteration column.
RUNS="$OUT"; . "$(dirname "$0")/_test_sets.sh"
test_sets fine_iter2 rhaml_jax/checkpoints/refiner_fine_long_cpu 2 none
