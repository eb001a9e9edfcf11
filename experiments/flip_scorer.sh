#!/usr/bin/env bash
# Issue 15, session 44 (BENCHMARKS.md, "A front/back scorer"): the front/back scorer
# (config scorer_flip_cpu: the refined pose against it turned by 180 deg about the model's box
# centre) trained on session 40's images, then its offline flip counts on the default's stored
# validation runs (label ens_native; experiments/flip_scorer.py), where the threshold is chosen.
# Every stage resumes (the training with --resume; a finished sweep is kept).
#   bash experiments/flip_scorer.sh DATA_ROOT RUNS_ROOT [EV]
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s44}"; EV="${3:-/work/runs/validation}"
PY="${PYTHON:-python}"
run="$RUNS/flip"
resume=(); [ -e "$run/checkpoints" ] && resume=(--resume)
grep -qs '"step": 10000' "$run/metrics.jsonl" || \
  $PY -m rhaml_jax.train --stage scorer --config scorer_flip_cpu --data "$DATA/s40_refine_mix" --out "$run" \
    --steps 10000 --batch 16 --lr 1e-3 --warmup 200 --val-every 1000 --val-batches 8 --ckpt-every 250 --log-every 50 \
    --seed 44 --no-progress "${resume[@]}"
[ -e "$RUNS/export/flip" ] || $PY -c "from rhaml_jax.refine.scorer import export_scorer; export_scorer('$run', '$RUNS/export/flip')"
sets="val_scen_s7_500/circle val_scen_s7_500/sine val_scen_s8_500/circle val_scen_s8_500/sine
val_ood/circle val_ood/sine val_ood_s2/circle val_ood_s2/sine"
for c in purple orange grey; do for s in circle sine; do sets="$sets val_mono/${s}_$c"; done; done
args=()
for d in $sets; do args+=(--run "$EV/ens_native_$(echo "$d" | tr / _).json" "$DATA/$d"); done
[ -e "$RUNS/flip_scorer_val.json" ] || $PY experiments/flip_scorer.py --scorer "$RUNS/export/flip" "${args[@]}" \
  --out "$RUNS/flip_scorer_val.json" | tee "$RUNS/flip_scorer_val.log"
