#!/usr/bin/env bash
# Session 37's training images (experiments/retrain_dim.sh, retrain_log.sh): 6,000 no-cart v3
# images at 320 x 256, 40 % with dim surroundings, seed 37; skipped when already complete.
#   bash experiments/dim_room_data.sh DATA_ROOT        # writes DATA_ROOT/s37_dim2_train
set -euo pipefail
DATA="${1:-/work/data}"; PY="${PYTHON:-python}"
if [ ! -f "$DATA/s37_dim2_train/.complete" ]; then
  "$PY" -m rhaml_jax.generate --out "$DATA/s37_dim2_train" --num 5250 --negatives 750 --width 320 --height 256 --workers 2 \
    --seed 37 --ranges.repaint-prob 0.5 --ranges.cart-prob 0 --ranges.dim-room-prob 0.4
  touch "$DATA/s37_dim2_train/.complete"
fi
