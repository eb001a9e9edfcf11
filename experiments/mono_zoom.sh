#!/bin/bash
# Session 25: the zoom stage fine-tuned on robots in one paint (AppearanceConfig.monochrome_prob),
# against a control of the same data without them, scored on the validation sets (BENCHMARKS.md,
# "Robots in one paint"). Needs /work/data/val_mono (experiments/val_mono.py), val_scen_s7_500,
# val_scen_s8_500, val_ood, and a fit run's plain-look images (DATA_V1).
set -e
PY=${PY:-python}
DATA_V1=${DATA_V1:-/work/runs/s23/fit_p163/data/train_v1}
OUT=${OUT:-/work/runs/s25/mono}; EV=${EV:-/work/runs/s25/ev}
mkdir -p $OUT $EV
for v in mono mono0; do
  p=$([ $v = mono ] && echo 0.5 || echo 0)   # monochrome is drawn last: the two sets differ only in those robots' paint
  $PY -m rhaml_jax.generate --out /work/data/${v}_train --num 5400 --negatives 600 --width 320 --height 256 --workers 2 \
      --seed 25 --ranges.repaint-prob 0.5 --ranges.monochrome-prob $p
  $PY -c "from rhaml_jax.data import mix_sets; mix_sets('/work/data/${v}_mix', ['/work/data/${v}_train', '$DATA_V1'])"
  $PY -m rhaml_jax.train --stage zoom --config zoom_cpu_luma --data /work/data/${v}_mix --out $OUT/run_$v --zoom-length-m 0.455 \
      --w-xy 69.4 526 --init rhaml_jax/checkpoints/zoom_fit_cpu --lr 5e-4 --warmup 100 --steps 3000 --batch 32 \
      --val-every 750 --ckpt-every 250 --val-batches 8 --no-progress $( [ -d $OUT/run_$v/checkpoints ] && echo --resume )
  $PY -c "from rhaml_jax.amlnet import export_weights; export_weights('$OUT/run_$v', '$OUT/zoom_$v')"
  # the flip probability calibrated on the fine-tune's own validation split, as fit does (IML+PGO weighs the flips by it)
  $PY -m rhaml_jax.calibrate_flips --data /work/data/${v}_train --split val --zoom $OUT/zoom_$v --zoom-mirror
done
for m in def mono mono0; do
  Z=$([ $m = def ] && echo "" || echo "--zoom $OUT/zoom_$m")
  for d in val_mono/sine_purple val_mono/sine_orange val_mono/sine_grey val_scen_s7_500/circle val_scen_s7_500/sine \
           val_scen_s8_500/circle val_scen_s8_500/sine val_ood/circle val_ood/sine; do
    j=$EV/${m}_$(echo $d | tr / _).json
    [ -f $j ] || $PY -m rhaml_jax.evaluate --data /work/data/$d --modules iml --zoom-mirror $Z --json $j
  done
  sets=""; for s in "ours val_scen_s7_500/circle val_scen_s7_500/sine val_scen_s8_500/circle val_scen_s8_500/sine" \
                    "ood val_ood/circle val_ood/sine" "mono val_mono/sine_purple val_mono/sine_orange val_mono/sine_grey"; do
    set -- $s; sets="$sets --set $1"; shift
    for d in "$@"; do sets="$sets $EV/${m}_$(echo $d | tr / _).json /work/data/$d"; done
  done
  $PY experiments/pipeline_from_json.py $sets --out $EV/${m}_summary.json
done
