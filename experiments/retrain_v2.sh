#!/usr/bin/env bash
# Issue 18 (an experiment, not the shipped networks: BENCHMARKS.md, "Retraining on v2 data"): the
# shipped amlnet_cpu + zoom_cpu fine-tuned on v2 (appearance-randomised) data mixed
# with v1 data (the v2-only fine-tune stalled: BENCHMARKS.md, "Retraining on v2 data"). Every
# stage resumes (generation is a pure function of (seed, index): rerunning rewrites the same bytes).
#   bash experiments/retrain_v2.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs}"
PY="${PYTHON:-python}"
INIT_AMLNET="${INIT_AMLNET:-rhaml_jax/checkpoints/amlnet_cpu}"
INIT_ZOOM="${INIT_ZOOM:-rhaml_jax/checkpoints/zoom_cpu}"
AMLNET_STEPS="${AMLNET_STEPS:-3000}"; ZOOM_STEPS="${ZOOM_STEPS:-3000}"
gen() {  # gen OUT ARGS...: a training set at 320 x 256, once
  local out="$1"; shift
  if [ ! -f "$out/.complete" ]; then
    "$PY" -m rhaml_jax.generate --out "$out" --width 320 --height 256 --workers 2 "$@"
    touch "$out/.complete"
  fi
}
gen "$DATA/v2_train" --num 20000 --negatives 3000 --seed 2                    # 23,000 images, v2 look
gen "$DATA/v1_train" --num 8750 --negatives 1250 --seed 5 --appearance v1     # 10,000 images, v1 look
"$PY" experiments/mix_bop.py --out "$DATA/mix_train" "$DATA/v2_train" "$DATA/v1_train"
"$PY" -m rhaml_jax.train --stage amlnet --config cpu --data "$DATA/mix_train" --out "$RUNS/amlnet_mix" \
  --init "$INIT_AMLNET" --steps "$AMLNET_STEPS" --lr 5e-4 --warmup 100 --val-every 500 --ckpt-every 250 --no-progress \
  $( [ -d "$RUNS/amlnet_mix/checkpoints" ] && echo --resume )
"$PY" -m rhaml_jax.train --stage zoom --config zoom_cpu --data "$DATA/mix_train" --out "$RUNS/zoom_mix" \
  --init "$INIT_ZOOM" --steps "$ZOOM_STEPS" --lr 5e-4 --warmup 100 --val-every 500 --ckpt-every 500 --w-xy 69.4 526 --no-progress \
  $( [ -d "$RUNS/zoom_mix/checkpoints" ] && echo --resume )
"$PY" -c "from rhaml_jax.amlnet import export_weights as e; e('$RUNS/amlnet_mix', '$RUNS/export/amlnet_cpu'); e('$RUNS/zoom_mix', '$RUNS/export/zoom_cpu')"
echo "exported to $RUNS/export/{amlnet_cpu,zoom_cpu}"
