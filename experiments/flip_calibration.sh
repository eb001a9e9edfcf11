#!/bin/bash
# IML's flip probability, raw and calibrated (BENCHMARKS.md, "IML's flip probability", session 15):
# the calibration is fitted on a validation split (calibrate_flips writes it into a copy of the
# zoom checkpoint), then evaluate runs IML + the pose graph with it and with --raw-flip-ranking.
#
#   AMLNET=CKPT ZOOM=CKPT VAL=BOP_SET_WITH_VAL_SPLIT DATA=/work/data OUT=DIR bash experiments/flip_calibration.sh
#
# (session 15: the shipped pair with VAL=/work/data/v1_small; a fit's networks with VAL=FIT/data/train)
set -e
: "${AMLNET:?}" "${ZOOM:?}" "${VAL:?}" "${DATA:=/work/data}" "${OUT:?}"
PY=${PY:-python}
mkdir -p "$OUT"; rm -rf "$OUT/zoom" && cp -r "$ZOOM" "$OUT/zoom"
$PY -m rhaml_jax.calibrate_flips --data "$VAL" --split val --amlnet "$AMLNET" --zoom "$OUT/zoom" --zoom-mirror > "$OUT/calibration.json"
for set in circle sine heldout/sine; do
  t=$(echo $set | tr / _)
  for raw in "" --raw-flip-ranking; do
    $PY -m rhaml_jax.evaluate --data "$DATA/$set" --modules iml,pgo --amlnet "$AMLNET" --zoom "$OUT/zoom" --zoom-mirror $raw \
        --json "$OUT/${t}_$([ -z "$raw" ] && echo calibrated || echo raw).json" > /dev/null
  done
done
