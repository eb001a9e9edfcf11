#!/usr/bin/env bash
# Issue 18, session 9 (BENCHMARKS.md, "A dense first stage, luminance input, repainted robots"):
# the luminance networks. Runs after experiments/retrain_v2.sh (its v2_train, v1_train, mix_train
# and zoom_mix). Every stage resumes (generation is a pure function of (seed, index)).
#   bash experiments/retrain_robust.sh DATA_ROOT RUNS_ROOT
# 1. cpu_heat (heatmap head, luminance) from scratch and zoom_cpu_luma (from zoom_mix) on mix_train;
# 2. a v3 set: v2 plus whole-robot repainting (repaint_prob 0.5); both fine-tuned on v3 + v2 + v1;
# 3. exported to RUNS/export_robust/{amlnet,zoom}, shipped as rhaml_jax/checkpoints/heat_cpu and
#    zoom_luma_cpu (cp -r RUNS/export_robust/amlnet rhaml_jax/checkpoints/heat_cpu, likewise the zoom).
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs}"
PY="${PYTHON:-python}"
resume() { [ -d "$1/checkpoints" ] && echo --resume || true; }
train() {  # train OUT ARGS...
  local out="$1"; shift
  "$PY" -m rhaml_jax.train --out "$out" --no-progress $(resume "$out") "$@"
}
train "$RUNS/heat" --stage amlnet --config cpu_heat --data "$DATA/mix_train" --steps 2500 --lr 1e-3 --warmup 100 \
  --val-every 250 --ckpt-every 250
train "$RUNS/zoom_luma" --stage zoom --config zoom_cpu_luma --data "$DATA/mix_train" --init "$RUNS/zoom_mix" --steps 2500 \
  --lr 5e-4 --warmup 100 --val-every 500 --ckpt-every 250 --w-xy 69.4 526
if [ ! -f "$DATA/v3_train/.complete" ]; then
  "$PY" -m rhaml_jax.generate --out "$DATA/v3_train" --num 16000 --negatives 2400 --seed 12 --width 320 --height 256 \
    --workers 2 --ranges.repaint-prob 0.5
  touch "$DATA/v3_train/.complete"
fi
[ -d "$DATA/mix3_train" ] || "$PY" experiments/mix_bop.py --out "$DATA/mix3_train" "$DATA/v3_train" "$DATA/v2_train" "$DATA/v1_train"
train "$RUNS/heat_v3" --stage amlnet --config cpu_heat --data "$DATA/mix3_train" --init "$RUNS/heat" --steps 2000 --lr 5e-4 \
  --warmup 100 --val-every 500 --ckpt-every 250
train "$RUNS/zoom_v3" --stage zoom --config zoom_cpu_luma --data "$DATA/mix3_train" --init "$RUNS/zoom_luma" --steps 2500 \
  --lr 5e-4 --warmup 100 --val-every 500 --ckpt-every 250 --w-xy 69.4 526
"$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/heat_v3', '$RUNS/export_robust/amlnet'); e('$RUNS/zoom_v3', '$RUNS/export_robust/zoom')"
echo "exported to $RUNS/export_robust/{amlnet,zoom}"
