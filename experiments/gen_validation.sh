#!/bin/bash
# Renders the data sets that experiments/validate_networks.sh scores (ours: circle + sine of seeds
# 7 and 8, 500 frames each; the OOD look of seeds 1 and 2; the one-paint look, and its images with
# the robot's own model as the set's model: val_mono_cad) and, for the reported-only columns, our
# circle + sine (seed 0) and the held-out appearance set. A set already on disk is skipped, so an
# interrupted run resumes. About 15 min for the validation sets and 15 more for the held-out set with
# one worker each, two sets at a time on this 2-core machine.
#
#   PY=.venv/bin/python bash experiments/gen_validation.sh [DATA]       # DATA defaults to /work/data
set -e
DATA=${1:-/work/data}
PY=${PY:-python}
gen() {  # out, then generate's arguments
  out=$1; shift; mkdir -p "$(dirname "$out")"
  [ -f "$out/.done" ] || { $PY -m rhaml_jax.generate --out "$out" --workers 1 "$@" > "$out.log" 2>&1 && touch "$out/.done"; }
}
mkdir -p "$DATA"
gen "$DATA/val_ood" --ood-validation --seed 1 &
gen "$DATA/val_ood_s2" --ood-validation --seed 2 &
wait
for s in 7 8; do
  for sc in circle sine; do gen "$DATA/val_scen_s${s}_500/$sc" --scenario $sc --frames 500 --seed $s & done
  wait
done
[ -f "$DATA/val_mono/.done" ] && [ -d "$DATA/val_mono_cad" ] || { $PY experiments/val_mono.py --out "$DATA/val_mono" \
  --scenarios sine circle --cad-out "$DATA/val_mono_cad" > "$DATA/val_mono.log" 2>&1 && touch "$DATA/val_mono/.done"; }
gen "$DATA/ours/circle" --scenario circle &
gen "$DATA/ours/sine" --scenario sine &
wait
gen "$DATA/heldout" --heldout
