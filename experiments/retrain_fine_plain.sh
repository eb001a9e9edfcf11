#!/usr/bin/env bash
# Issue 15, session 39 (BENCHMARKS.md, "The fine refiner trained longer"): the shipped fine
# refiner (refiner_fine_cpu) trained 10,000 more steps at batch 16 from fine starts, on 3,200
# plain-look (v1) images at 640 x 480 (two generate runs, seeds 391 and 392, mixed by symlinks;
# run fine_v1long) and on those plus 1,600 randomised-look (v3) ones (run fine_mix: exported as
# rhaml_jax/checkpoints/refiner_fine_long_cpu, the default); a 3,000-step probe on the first 800
# plain-look images first (fine_v1); then the cascade from the paper's noise on 2 x 100 validation
# frames (our look, seeds 7 and 8; experiments/bench_refine.py). Every stage resumes.
#   bash experiments/retrain_fine_plain.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s39}"
PY="${PYTHON:-python}"
gen() {  # out seed count look-args
  [ -f "$DATA/$1/.complete" ] || { "$PY" -m rhaml_jax.generate --out "$DATA/$1" --num "$3" --negatives 0 --seed "$2" --workers 1 ${@:4}; touch "$DATA/$1/.complete"; }
}
gen s39_refine_v1 391 800 --appearance v1
gen s39_refine_v1b 392 2400 --appearance v1
gen s39_refine_v3 393 1600 --ranges.repaint-prob 0.5      # the randomised look (fit's v3) of the control
[ -d "$DATA/s39_refine_v1mix" ] || "$PY" experiments/mix_bop.py --out "$DATA/s39_refine_v1mix" "$DATA/s39_refine_v1" "$DATA/s39_refine_v1b"
[ -d "$DATA/s39_refine_mix" ] || "$PY" experiments/mix_bop.py --out "$DATA/s39_refine_mix" "$DATA/s39_refine_v1" "$DATA/s39_refine_v1b" "$DATA/s39_refine_v3"
. "$(dirname "$0")/_test_sets.sh"
train() {  # data run steps val_batches val_every
  refiner_run "$2" refiner_fine_cpu "$1" rhaml_jax/checkpoints/refiner_fine_cpu 39 --steps "$3" --val-every "$5" --val-batches "$4"
}
train s39_refine_v1 fine_v1 3000 4 500
train s39_refine_v1mix fine_v1long 10000 8 1000
train s39_refine_mix fine_mix 10000 8 1000           # the control: the same steps with a third of the images randomised
bench() {  # label fine-refiner [bench args]
  val_bench "bench_$1" --starts noise --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner "$2" "${@:3}"
}
bench default rhaml_jax/checkpoints/refiner_fine_cpu
bench fine_v1 "$RUNS/export/fine_v1"
bench fine_v1long "$RUNS/export/fine_v1long"
bench fine_mix "$RUNS/export/fine_mix"
# After the choice (fine_mix, on validation: experiments/validate_networks.sh with NETS = the default
# networks + fine, then experiments/compare_validation.py), the test and held-out sets, reported only:
# the whole pipeline with the old and the new fine refiner, then issue 15's table (bench_refine.py from
# the paper's noise and from the IML, every 5th frame the IML detected).
for fine in refiner_fine_cpu refiner_fine_long_cpu; do  # one fine iteration, session 39's default
  test_sets "$fine" "rhaml_jax/checkpoints/$fine" 1 none
done
