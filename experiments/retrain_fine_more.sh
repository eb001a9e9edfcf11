#!/usr/bin/env bash
# Issue 15, session 40 (BENCHMARKS.md, "The fine refiner on twice the images"): session 39's
# default fine refiner (refiner_fine_long_cpu) trained 10,000 more steps at batch 16 from fine
# starts, on twice session 39's images: its 4,800 (3,200 plain-look v1, 1,600 randomised v3) plus
# 4,800 new ones (2,400 v1, seed 401; 2,400 v3, seed 402), since in session 39 the validation loss
# flattened while the training loss still fell; then the cascade from the paper's noise on 2 x 100
# validation frames (our look, seeds 7 and 8; experiments/bench_refine.py), with one and two fine
# iterations. Every stage resumes.
# Needs session 39's images (experiments/retrain_fine_plain.sh renders them).
#   bash experiments/retrain_fine_more.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s40}"
PY="${PYTHON:-python}"; WORKERS="${WORKERS:-2}"
gen() {  # out seed count look-args
  [ -f "$DATA/$1/.complete" ] || { "$PY" -m rhaml_jax.generate --out "$DATA/$1" --num "$3" --negatives 0 --seed "$2" --workers "$WORKERS" ${@:4}; touch "$DATA/$1/.complete"; }
}
gen s40_refine_v1 401 2400 --appearance v1
gen s40_refine_v3 402 2400 --ranges.repaint-prob 0.5
[ -d "$DATA/s40_refine_mix" ] || "$PY" experiments/mix_bop.py --out "$DATA/s40_refine_mix" \
  "$DATA/s39_refine_v1" "$DATA/s39_refine_v1b" "$DATA/s39_refine_v3" "$DATA/s40_refine_v1" "$DATA/s40_refine_v3"
. "$(dirname "$0")/_test_sets.sh"
run=fine_more
refiner_run $run refiner_fine_cpu s40_refine_mix rhaml_jax/checkpoints/refiner_fine_long_cpu 40 \
  --steps 10000 --val-every 1000 --val-batches 8
for f in 1 2; do  # fine iterations (session 39's default 1, now 2); the default network's rows: experiments/refine_iterations.sh
  val_bench "bench_${run}_f$f" --starts noise --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner "$RUNS/export/$run" --fine-iter $f
done
# After the choice (on validation: LABEL=fine_more_f2 NETS=... EXTRA="--fine-iter 2" and then, with the
# windowed range calibration, LABEL=fine_more_f2_win, experiments/validate_networks.sh; compare_validation.py),
# the test and held-out sets, reported only: the whole pipeline with the defaults (this network, shipped as
# refiner_fine_more_cpu, two fine iterations, range_window auto), its pose-graph rows refitted without the
# window, then issue 15's table (bench_refine.py from the paper's noise and from the IML, every 5th frame the
# IML detected).
test_sets final rhaml_jax/checkpoints/refiner_fine_more_cpu 2 none --range-window-max-scale None  # session 40's pose graph: the window always
sets=(); for set in ours heldout; do sets+=(--set $set "$RUNS/test_final_${set}_circle.json" "$DATA/$set/circle" "$RUNS/test_final_${set}_sine.json" "$DATA/$set/sine"); done
[ -f "$RUNS/pipeline_test_final.json" ] || "$PY" experiments/pipeline_from_json.py "${sets[@]}" --out "$RUNS/pipeline_test_final.json"
[ -f "$RUNS/pipeline_test_final_nowindow.json" ] || "$PY" experiments/pipeline_from_json.py "${sets[@]}" --metric range_window null --out "$RUNS/pipeline_test_final_nowindow.json"
