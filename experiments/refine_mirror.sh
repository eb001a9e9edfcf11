#!/usr/bin/env bash
# Issue 15, session 42 (BENCHMARKS.md, "What one image tells about the range, and the fine refiner's own
# reading"): how well the pixels pin the range (experiments/range_quantization.py); the default fine
# refiner started at the truth; the cascade from the paper's noise with the learned iterations also
# reading mirrored crops (RefineConfig.mirror), with the default fine refiner and with
# experiments/retrain_fine_native.sh's (run that first); then, after the choice on validation
# (LABEL=mirror_fine NETS=default networks EXTRA="--refine-mirror fine" experiments/validate_networks.sh,
# LABEL=native_mirror with the native fine refiner; compare_validation.py), the test and held-out sets,
# reported only. Each output is kept: a rerun skips it.
#   bash experiments/refine_mirror.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s42}"
PY="${PYTHON:-python}"
. "$(dirname "$0")/_test_sets.sh"
native="$RUNS/export/fine_native"; more=rhaml_jax/checkpoints/refiner_fine_more_cpu
[ -f "$RUNS/rq_val.json" ] || "$PY" experiments/range_quantization.py --data "$DATA/val_scen_s7_500/circle" "$DATA/val_scen_s7_500/sine" --stride 10 --json "$RUNS/rq_val.json"
[ -f "$RUNS/rq_test.json" ] || "$PY" experiments/range_quantization.py --data "$DATA/ours/circle" "$DATA/ours/sine" --stride 5 --json "$RUNS/rq_test.json"
cascade=(--starts noise --refiner rhaml_jax/checkpoints/refiner_cpu)
val_bench bench_f5 "${cascade[@]}" --fine-refiner $more --fine-iter 5                            # the default, 5 fine iterations
val_bench bench_mirrorlit_fine "${cascade[@]}" --fine-refiner $more --fine-iter 2 --mirror fine
val_bench bench_mirrorlit_fine_f3 "${cascade[@]}" --fine-refiner $more --fine-iter 3 --mirror fine --starts noise truth
val_bench bench_mirrorlit_all_f3 "${cascade[@]}" --fine-refiner $more --fine-iter 3 --mirror all
val_bench bench_fine_native_mirror "${cascade[@]}" --fine-refiner "$native" --fine-iter 2 --mirror fine
val_bench bench_fine_native_mirror_f4 "${cascade[@]}" --fine-refiner "$native" --fine-iter 4 --mirror fine
truth=(--starts truth --n-iter 2 --max-final-step None)                                       # a fine refiner alone, from the truth
val_bench truth_fine_more "${truth[@]}" --refiner $more
val_bench truth_fine_more_mirror "${truth[@]}" --refiner $more --mirror all
val_bench truth_fine_native "${truth[@]}" --refiner "$native"
val_bench truth_fine_native_mirror "${truth[@]}" --refiner "$native" --mirror all
[ -f "$RUNS/time_mirror.log" ] || "$PY" experiments/time_refine_iterations.py --data "$DATA/ours/circle" --batch 8 --repeats 9 \
  --settings 4,2 4,2,fine --fine-refiner "$native" > "$RUNS/time_mirror.log"
test_sets mirror $more 2 fine
sets=(); for set in ours heldout; do sets+=(--set $set "$RUNS/test_mirror_${set}_circle.json" "$DATA/$set/circle" "$RUNS/test_mirror_${set}_sine.json" "$DATA/$set/sine"); done
[ -f "$RUNS/pipeline_test_mirror.json" ] || "$PY" experiments/pipeline_from_json.py "${sets[@]}" --out "$RUNS/pipeline_test_mirror.json"
