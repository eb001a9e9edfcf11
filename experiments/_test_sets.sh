# Issue 15's test-set block, shared by the refiner scripts (sourced; needs DATA, RUNS, PY): the whole
# pipeline on our and the held-out circle + sine (reported only, after a choice made on validation), then
# issue 15's table (experiments/bench_refine.py from the paper's noise and from the IML, every 5th frame
# the IML detected). Each output is kept: a rerun skips it.
#   test_sets NAME FINE_REFINER FINE_ITER MIRROR [EVALUATE_ARGS...]      (MIRROR: RefineConfig.mirror, none|fine|all)
# writes $RUNS/test_NAME_{ours,heldout}_{circle,sine}.json (+ .log) and $RUNS/bench_test_NAME_{ours,heldout}.json.
test_sets() {
  local name=$1 fine=$2 fine_iter=$3 mirror=$4 s j set out
  shift 4
  for s in ours/circle ours/sine heldout/circle heldout/sine; do
    j="$RUNS/test_${name}_$(echo "$s" | tr / _).json"
    [ -f "$j" ] || "$PY" -m rhaml_jax.evaluate --data "$DATA/$s" --modules iml,ir,pgo --zoom-mirror \
      --fine-refiner "$fine" --fine-iter "$fine_iter" --refine-mirror "$mirror" "$@" --json "$j" > "${j%.json}.log"
  done
  for set in ours heldout; do
    out="$RUNS/bench_test_${name}_$set.json"
    [ -f "$out" ] || "$PY" experiments/bench_refine.py --data "$DATA/$set/circle" "$DATA/$set/sine" \
      --iml-json "$RUNS/test_${name}_${set}_circle.json" "$RUNS/test_${name}_${set}_sine.json" --starts noise iml --stride 5 \
      --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner "$fine" --fine-iter "$fine_iter" --mirror "$mirror" --no-oracle --json "$out"
  done
}
