#!/bin/bash
# AMLNet's training step rate as fit's budget rule charges it (`fitting._plan.RATES`): `cpu_heat`,
# batch 32, from random weights, on a fit run's v3 training set, for two checkouts side by side
# (alternating, REPS times each); then the median seconds per step after the first 30 steps, from
# each run's metrics.jsonl. Run it on a quiet machine.
#
#   DATA=RUN/data/train A=/path/to/checkout_a B=/path/to/checkout_b bash experiments/amlnet_step_rate.sh
set -e
: "${DATA:?}" "${A:?}" "${B:?}" "${OUT:=/tmp/amlnet_step_rate}" "${REPS:=2}" "${STEPS:=150}"
PY=${PY:-python}
mkdir -p "$OUT"
for rep in $(seq "$REPS"); do
  for tag in a b; do
    src=$A; [ $tag = b ] && src=$B
    run=$OUT/${tag}_$rep; rm -rf "$run"
    PYTHONPATH=$src $PY -m rhaml_jax.train --stage amlnet --config cpu_heat --data "$DATA" --out "$run" \
        --steps "$STEPS" --batch 32 --val-every 100000 --ckpt-every 100000 --no-progress > "$run.log" 2>&1
  done
done
$PY - "$OUT" "$REPS" <<'PYEOF'
import json, sys
import numpy as np
out, reps = sys.argv[1], int(sys.argv[2])
for tag in ("a", "b"):
    per = []
    for rep in range(1, reps + 1):
        rows = [json.loads(line) for line in open(f"{out}/{tag}_{rep}/metrics.jsonl")]
        per.append(float(np.median([32 / r["images_per_s"] for r in rows if r["step"] >= 30 and "images_per_s" in r])))
    print(tag, "median s per step, each run:", [round(p, 3) for p in per])
PYEOF
