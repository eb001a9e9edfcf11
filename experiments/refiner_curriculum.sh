#!/bin/bash
# The refiner's curriculum (BENCHMARKS.md, "A curriculum for the refiner", session 16): from random
# weights, 2,000 steps on plain-look (v1) crops, then 1,000 on v3 crops (or v3 + v1) from those
# weights; each run measured on both validation splits, iteration by iteration
# (experiments/refiner_val.py: point-matching loss, depth / lateral error, heading).
#
#   V1=BOP_SET V3=BOP_SET MIX=BOP_SET OUT=DIR [CONFIG=refiner_cpu] bash experiments/refiner_curriculum.sh
#
# (session 16: V1=/work/data/refine_v1 (`generate --num 800 --negatives 0 --appearance v1 --seed 33`),
# V3=the from-scratch fit's data/refine, MIX=rhaml_jax.data.mix_sets of the two)
set -e
: "${V1:?}" "${V3:?}" "${MIX:?}" "${OUT:?}" "${CONFIG:=refiner_cpu}"
PY=${PY:-python}
ref() { out=$1; shift; [ -d "$out/checkpoints" ] && R=--resume || R=
        $PY -m rhaml_jax.train --stage refiner --config "$CONFIG" --batch 16 --ckpt-every 250 --val-batches 4 --no-progress --out "$out" $R "$@"; }
ref "$OUT/v1" --data "$V1" --steps 2000 --val-every 500
ref "$OUT/v1_v3" --data "$V3" --init "$OUT/v1" --lr 5e-4 --warmup 100 --steps 1000 --val-every 250
ref "$OUT/v1_mix" --data "$MIX" --init "$OUT/v1" --lr 5e-4 --warmup 100 --steps 1000 --val-every 250
for run in v1 v1_v3 v1_mix; do
  for split in V1 V3; do
    $PY experiments/refiner_val.py --refiner "$OUT/$run" --data "${!split}" --num 96 --json "$OUT/val_${run}_$split.json"
  done
done
