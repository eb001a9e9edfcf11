#!/bin/bash
# The zoom stage's heading curriculum from random weights (BENCHMARKS.md, "A curriculum for the
# heading", session 15): 12,000 steps on plain-look (v1) images, then 5,000 on v3 + v1 from them;
# each exported and evaluated (IML) on the v1 and v3 validation splits, our circle and the
# held-out sine, behind one AMLNet. Flips: |dpsi| > 90 deg over the detected robot frames.
#
#   V1=DIR_V1_SET V3=DIR_V3_SET MIX=DIR_MIX_SET AMLNET=CKPT DATA=/work/data OUT=DIR bash experiments/zoom_curriculum.sh
#
# (session 15: V1=fit_p_curric/data/train_v1, V3=fit_p_scratch/data/train, MIX=experiments/mix_bop.py
# of the two, AMLNET=fit_p_scratch/networks/amlnet)
set -e
: "${V1:?}" "${V3:?}" "${MIX:?}" "${AMLNET:?}" "${DATA:=/work/data}" "${OUT:?}"
PY=${PY:-python}
zoom() { out=$1; shift; [ -d "$out/checkpoints" ] && R=--resume || R=
         $PY -m rhaml_jax.train --stage zoom --robot pioneer3dx --config zoom_cpu_luma --zoom-length-m 0.455 --w-xy 69.4 526 \
             --batch 32 --no-progress --out "$out" $R "$@"; }
zoom "$OUT/zoom_v1_12k" --data "$V1" --steps 12000 --val-every 2000
zoom "$OUT/zoom_mix_12k" --data "$MIX" --steps 5000 --val-every 1000 --init "$OUT/zoom_v1_12k" --lr 5e-4 --warmup 100
for tag in zoom_v1_12k zoom_mix_12k; do
  $PY -c "from rhaml_jax.amlnet import export_weights as e; e('$OUT/$tag', '$OUT/net_$tag')"
  ev() { $PY -m rhaml_jax.evaluate --modules iml --amlnet "$AMLNET" --zoom "$OUT/net_$tag" --zoom-mirror --json "$OUT/$1_$tag.json" "${@:2}" > /dev/null; }
  ev v1val --data "$V1" --split val
  ev v3val --data "$V3" --split val
  ev circle --data "$DATA/circle"
  ev heldout_sine --data "$DATA/heldout/sine"
  $PY - "$OUT" "$tag" <<'PY'
import json, sys
from rhaml_jax.metrics import flipped
out, tag = sys.argv[1:]
for s in ("v1val", "v3val", "circle", "heldout_sine"):
    d = json.load(open(f"{out}/{s}_{tag}.json"))
    fr = [f for f in d["frames"] if f["observed"] and f["detected"]]
    n = int(flipped([f["est"][2] for f in fr], [f["gt"][2] for f in fr]).sum())
    print(tag, s, f"ATE {d['metrics']['ate']:.3f} flips {n} of {len(fr)} detection {d['metrics']['detection']}")
PY
done
