#!/bin/bash
# The refiner's second phase on v3 + v1 crops together (what `fit` does since session 28) redone
# from a finished fit run's first phase, then scored on the validation sets behind that run's IML
# (BENCHMARKS.md, "The refiner's second phase on the mix"). Never the held-out set.
#
#   FIT=RUN OUT=DIR bash experiments/refiner_mix_phase.sh       # RUN: a fit folder (data/refine*, runs/refiner_v1, networks/)
set -e
: "${FIT:?}" "${OUT:?}" "${STEPS:=2000}" "${LABEL:=refiner_mix}"
PY=${PY:-python}
$PY -c "import sys; from rhaml_jax.data import mix_sets; mix_sets(sys.argv[1], [sys.argv[2], sys.argv[3]])" \
    "$OUT/refine_mix" "$FIT/data/refine" "$FIT/data/refine_v1"
# fit's own arguments for the stage (rhaml_jax.fitting._run.refiner_stage)
$PY -m rhaml_jax.train --stage refiner --robot pioneer3dx --config refiner_cpu --data "$OUT/refine_mix" \
    --steps "$STEPS" --batch 16 --seed 0 --val-every $((STEPS / 4)) --ckpt-every 250 --no-progress --val-batches 4 \
    --init "$FIT/runs/refiner_v1" --lr 5e-4 --warmup 100 --out "$OUT/run"
$PY -c "import sys; from rhaml_jax.refine import export_refiner; export_refiner(sys.argv[1], sys.argv[2])" "$OUT/run" "$OUT/nets/refiner"
ln -sfn "$FIT/networks/amlnet" "$OUT/nets/amlnet"; ln -sfn "$FIT/networks/zoom" "$OUT/nets/zoom"
LABEL=$LABEL NETS="$OUT/nets" PY=$PY bash "$(dirname "$0")/validate_networks.sh"
