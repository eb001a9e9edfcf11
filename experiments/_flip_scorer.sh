# Blocks shared by the front/back scorer scripts, flip_scorer.sh and flip_wide.sh (sourced; need
# DATA, RUNS, EV, PY).
#
# scorer_run RUN CONFIG SET STEPS [TRAIN_ARGS...]: `train --stage scorer` at batch 16 with the scorers'
# checkpointing, logging and validation (resumed when the run exists; skipped once it reached STEPS),
# then its export to $RUNS/export/RUN.
scorer_run() {
  local run=$1 config=$2 set=$3 steps=$4
  shift 4
  grep -qs "\"step\": $steps," "$RUNS/$run/metrics.jsonl" || \
    "$PY" -m rhaml_jax.train --stage scorer --config "$config" --data "$DATA/$set" --out "$RUNS/$run" --steps "$steps" \
      --batch 16 --val-every 1000 --val-batches 8 --ckpt-every 250 --log-every 50 --no-progress "$@" \
      $( [ -d "$RUNS/$run/checkpoints" ] && echo --resume )
  [ -e "$RUNS/export/$run" ] || "$PY" -c "from rhaml_jax.refine.scorer import export_scorer as e; e('$RUNS/$run', '$RUNS/export/$run')"
}
# flip_sweep NAME SCORER [FLIP_SCORER_ARGS...]: experiments/flip_scorer.py with SCORER on the 14 validation
# sequences' stored default runs (label ens_native in EV) -> $RUNS/NAME_val.json and .log (kept: a rerun skips it).
flip_sweep() {
  local name=$1 scorer=$2 d sets args=()
  shift 2
  sets="val_scen_s7_500/circle val_scen_s7_500/sine val_scen_s8_500/circle val_scen_s8_500/sine
    val_ood/circle val_ood/sine val_ood_s2/circle val_ood_s2/sine"
  for c in purple orange grey; do for s in circle sine; do sets="$sets val_mono/${s}_$c"; done; done
  for d in $sets; do args+=(--run "$EV/ens_native_$(echo "$d" | tr / _).json" "$DATA/$d"); done
  [ -e "$RUNS/${name}_val.json" ] || "$PY" experiments/flip_scorer.py --scorer "$scorer" "${args[@]}" "$@" \
    --out "$RUNS/${name}_val.json" | tee "$RUNS/${name}_val.log"
}
