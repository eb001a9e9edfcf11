#!/bin/bash
# The refiner learns the heading (BENCHMARKS.md, session 17): refiner_cpu with the disentangled
# loss (rotation part x10), 2,000 steps on plain-look (v1) crops, 10,000 more from those weights,
# then 2,000 on v3 crops or on v3 + v1 crops (MIX: session 17's refiner_cpu, step 2,000 of v1_long_mix),
# then 6,000 more on MIX at a lower rate (session 18: the shipped refiner_cpu, step 6,000 of v1_long_mix_long);
# each measured on the validation splits (experiments/refiner_val.py) and read part by part
# (experiments/refiner_update_corr.py).
#
#   V1=BOP_SET V3=BOP_SET MIX=BOP_SET OUT=DIR bash experiments/refiner_heading.sh
#   python -c "from rhaml_jax.refine import export_refiner; export_refiner('DIR/v1_long_mix_long', 'rhaml_jax/checkpoints/refiner_cpu')"
#
# (session 17: V1=/work/data/refine_v1, V3=the from-scratch fit's data/refine, MIX=rhaml_jax.data.mix_sets
# of the two, as refiner_curriculum.sh)
set -e
: "${V1:?}" "${V3:?}" "${MIX:?}" "${OUT:?}"
PY=${PY:-python}
ref() { out=$1; shift; [ -d "$out/checkpoints" ] && R=--resume || R=
        $PY -m rhaml_jax.train --stage refiner --config refiner_cpu --batch 16 --val-batches 4 --no-progress --out "$out" $R "$@"; }
ref "$OUT/v1" --data "$V1" --steps 2000 --val-every 500 --ckpt-every 250
ref "$OUT/v1_long" --data "$V1" --init "$OUT/v1" --lr 1e-3 --warmup 100 --steps 10000 --val-every 1000 --ckpt-every 1000
ref "$OUT/v1_long_v3" --data "$V3" --init "$OUT/v1_long" --lr 5e-4 --warmup 100 --steps 2000 --val-every 500 --ckpt-every 500
ref "$OUT/v1_long_mix" --data "$MIX" --init "$OUT/v1_long" --lr 5e-4 --warmup 100 --steps 2000 --val-every 500 --ckpt-every 500
ref "$OUT/v1_long_mix_long" --data "$MIX" --init "$OUT/v1_long_mix" --lr 3e-4 --warmup 100 --steps 6000 --val-every 1000 --ckpt-every 500
for run in v1 v1_long v1_long_v3 v1_long_mix v1_long_mix_long; do
  $PY experiments/refiner_update_corr.py --refiner "$OUT/$run" --data "$V1" > "$OUT/corr_$run.jsonl"
  for split in V1 V3; do
    $PY experiments/refiner_val.py --refiner "$OUT/$run" --data "${!split}" --num 96 --json "$OUT/val_${run}_$split.json"
  done
done
