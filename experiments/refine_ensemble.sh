#!/usr/bin/env bash
# Issue 15, session 43 (BENCHMARKS.md, "An ensemble of fine refiners"): the fine iterations averaging
# the updates of two fine refiners (`refine(fine=(a, b))`, `evaluate --fine-refiner A B`), mirrored as
# the default is: the shipped default with session 42's native-render run (RUNS/export/fine_native,
# experiments/retrain_fine_native.sh; shipped now as refiner_fine_native_cpu) and with session 39's
# refiner_fine_long_cpu, on 2 x 100 validation frames (our look, seeds 7 and 8) from the paper's noise
# and from the truth (the whole cascade started there); then a third member trained (42 min here, beside other jobs),
# the IR time, and the test and held-out sets (reported only). The validation by the rule:
#   LABEL=ens_native EXTRA="--fine-refiner MORE NATIVE" bash experiments/validate_networks.sh
# Every output is kept: a rerun skips it.
#   bash experiments/refine_ensemble.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s43}"
PY="${PYTHON:-python}"
. "$(dirname "$0")/_test_sets.sh"
ck=rhaml_jax/checkpoints
more=$ck/refiner_fine_more_cpu; native=${NATIVE:-$ck/refiner_fine_native_cpu}; long=$ck/refiner_fine_long_cpu
cascade=(--starts noise truth --refiner $ck/refiner_cpu --fine-iter 2 --mirror fine)
val_bench ens_more_native "${cascade[@]}" --fine-refiner $more "$native"
val_bench ens_more_long "${cascade[@]}" --fine-refiner $more $long
val_bench ens_more "${cascade[@]}" --fine-refiner $more                        # the default, the control
val_bench ens_more_native_f3 --starts noise --refiner $ck/refiner_cpu --fine-iter 3 --mirror fine --fine-refiner $more "$native"
# A third member: the native-render config trained as session 42's run was, but from
# refiner_fine_long_cpu (another start) with another seed, then the three-member ensemble.
refiner_run fine_native_b refiner_fine_native_cpu s40_refine_mix $long 43 --steps 10000 --val-every 1000 --val-batches 8
val_bench ens_three "${cascade[@]}" --fine-refiner $more "$native" "$RUNS/export/fine_native_b"
# The IR stage's time, the ensemble (the default) against its first member alone, interleaved medians.
[ -f "$RUNS/time_ensemble.log" ] || "$PY" experiments/time_refine_iterations.py --data "$DATA/ours/circle" --batch 8 --repeats 15 \
  --settings 4,2,fine --fine-refiner $more > "$RUNS/time_ensemble.log"
# The test and held-out sets with the ensemble (reported only, after the choice on validation).
test_sets ensemble "$more $native" 2 fine
sets=(); for set in ours heldout; do sets+=(--set $set "$RUNS/test_ensemble_${set}_circle.json" "$DATA/$set/circle" "$RUNS/test_ensemble_${set}_sine.json" "$DATA/$set/sine"); done
[ -f "$RUNS/pipeline_test_ensemble.json" ] || "$PY" experiments/pipeline_from_json.py "${sets[@]}" --out "$RUNS/pipeline_test_ensemble.json"
