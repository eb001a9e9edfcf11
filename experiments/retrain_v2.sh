#!/usr/bin/env bash
# Issue 18: the shipped amlnet_cpu + zoom_cpu fine-tuned on v2 (appearance-randomised) data.
# Reproduces rhaml_jax/checkpoints/{amlnet_cpu,zoom_cpu} of session 7 from the session-6 ones
# (git show <commit>:rhaml_jax/checkpoints/... or the tag in BENCHMARKS.md); every stage resumes.
#   bash experiments/retrain_v2.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs}"
PY="${PYTHON:-python}"
INIT_AMLNET="${INIT_AMLNET:-rhaml_jax/checkpoints/amlnet_cpu}"
INIT_ZOOM="${INIT_ZOOM:-rhaml_jax/checkpoints/zoom_cpu}"
# 23,000 images at 320 x 256 (20,000 with the robot, 3,000 background-only), v2 look, seed 2
if [ ! -f "$DATA/v2_train/.complete" ]; then
  "$PY" -m rhaml_jax.generate --out "$DATA/v2_train" --num 20000 --negatives 3000 --width 320 --height 256 --workers 2 --seed 2
  touch "$DATA/v2_train/.complete"
fi
"$PY" -m rhaml_jax.train --stage amlnet --config cpu --data "$DATA/v2_train" --out "$RUNS/amlnet_v2" \
  --init "$INIT_AMLNET" --steps 4000 --lr 5e-4 --warmup 100 --val-every 500 --ckpt-every 250 --no-progress \
  $( [ -d "$RUNS/amlnet_v2/checkpoints" ] && echo --resume )
"$PY" -m rhaml_jax.train --stage zoom --config zoom_cpu --data "$DATA/v2_train" --out "$RUNS/zoom_v2" \
  --init "$INIT_ZOOM" --steps 3000 --lr 5e-4 --warmup 100 --val-every 500 --ckpt-every 500 --w-xy 69.4 526 --no-progress \
  $( [ -d "$RUNS/zoom_v2/checkpoints" ] && echo --resume )
"$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/amlnet_v2', '$RUNS/export/amlnet_cpu'); e('$RUNS/zoom_v2', '$RUNS/export/zoom_cpu')"
echo "exported to $RUNS/export/{amlnet_cpu,zoom_cpu}"
