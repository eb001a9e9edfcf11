# Issue 15's blocks shared by the refiner scripts (sourced; need DATA, RUNS, PY; look_bench also C, the checkpoints folder).
#
# refiner_run RUN CONFIG DATA_SET INIT SEED [TRAIN_ARGS...]: `train --stage refiner` at the refiners'
# rate, warm-up, batch and checkpointing (resumed when the run exists), then its export to $RUNS/export/RUN.
refiner_run() {
  local run=$1 config=$2 set=$3 init=$4 seed=$5
  shift 5
  "$PY" -m rhaml_jax.train --stage refiner --config "$config" --data "$DATA/$set" --out "$RUNS/$run" \
    --init "$init" --lr 3e-4 --warmup 100 --batch 16 --seed "$seed" --ckpt-every 250 --no-progress "$@" \
    $( [ -d "$RUNS/$run/checkpoints" ] && echo --resume )
  [ -d "$RUNS/export/$run" ] || "$PY" -c "from rhaml_jax.refine import export_refiner as e; e('$RUNS/$run', '$RUNS/export/$run')"
}
# val_bench NAME [BENCH_ARGS...]: experiments/bench_refine.py on the 2 x 100 validation frames (our look,
# seeds 7 and 8, every 10th frame of circle + sine) -> $RUNS/NAME_s{7,8}.json (kept: a rerun skips it).
val_bench() {
  local name=$1 s
  shift
  for s in 7 8; do
    [ -f "$RUNS/${name}_s$s.json" ] || "$PY" experiments/bench_refine.py --data "$DATA/val_scen_s${s}_500/circle" \
      "$DATA/val_scen_s${s}_500/sine" --stride 10 --no-oracle "$@" --json "$RUNS/${name}_s$s.json"
  done
}
# look_bench NAME [BENCH_ARGS...]: the cascade from the paper's noise (every 10th frame) on one circle
# of each look: ours (seed 7), OOD (seed 1), one paint grey and purple, and the same two with the
# robot's own model (val_mono_cad) -> $RUNS/NAME_LOOK.json (kept: a rerun skips it)
look_bench() {
  local name=$1 look set
  shift
  for look in ours:val_scen_s7_500/circle ood:val_ood/circle grey:val_mono/circle_grey cad_grey:val_mono_cad/circle_grey \
              purple:val_mono/circle_purple cad_purple:val_mono_cad/circle_purple; do
    set=${look#*:}; look=${look%%:*}
    [ -f "$RUNS/${name}_$look.json" ] || "$PY" experiments/bench_refine.py --data "$DATA/$set" --starts noise --stride 10 \
      --no-oracle --mirror fine --scorer $C/scorer_flip_wide_cpu --flip-threshold 0.8 --post-iter 0 --fine-iter 2 "$@" \
      --json "$RUNS/${name}_$look.json" > "$RUNS/${name}_$look.log" 2>&1
  done
}
# test_sets, the test-set block: the whole
# pipeline on our and the held-out circle + sine (reported only, after a choice made on validation), then
# issue 15's table (experiments/bench_refine.py from the paper's noise and from the IML, every 5th frame
# the IML detected). Each output is kept: a rerun skips it.
#   test_sets NAME FINE_REFINER FINE_ITER MIRROR [EVALUATE_ARGS...]      (MIRROR: RefineConfig.mirror, none|fine|all;
#   FINE_REFINER: one folder, or several separated by spaces, an ensemble; the table's coarse refiner: $REFINER,
#   by default rhaml_jax/checkpoints/refiner_cpu, and more bench_refine.py options in $BENCH_ARGS)
# writes $RUNS/test_NAME_{ours,heldout}_{circle,sine}.json (+ .log) and $RUNS/bench_test_NAME_{ours,heldout}.json.
test_sets() {
  local name=$1 fine=$2 fine_iter=$3 mirror=$4 s j set out
  shift 4
  for s in ours/circle ours/sine heldout/circle heldout/sine; do
    j="$RUNS/test_${name}_$(echo "$s" | tr / _).json"
    [ -f "$j" ] || "$PY" -m rhaml_jax.evaluate --data "$DATA/$s" --modules iml,ir,pgo --zoom-mirror \
      --fine-refiner $fine --fine-iter "$fine_iter" --refine-mirror "$mirror" "$@" --json "$j" > "${j%.json}.log"
  done
  for set in ours heldout; do
    out="$RUNS/bench_test_${name}_$set.json"
    [ -f "$out" ] || "$PY" experiments/bench_refine.py --data "$DATA/$set/circle" "$DATA/$set/sine" \
      --iml-json "$RUNS/test_${name}_${set}_circle.json" "$RUNS/test_${name}_${set}_sine.json" --starts noise iml --stride 5 \
      --refiner "${REFINER:-rhaml_jax/checkpoints/refiner_cpu}" --fine-refiner $fine --fine-iter "$fine_iter" --mirror "$mirror" \
      ${BENCH_ARGS:-} --no-oracle --json "$out"
  done
}
