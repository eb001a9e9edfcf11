#!/usr/bin/env bash
# Issue 15, session 46 (BENCHMARKS.md, "Refiners trained on repainted renders"): session 45's front/back
# scorer (scorer_flip_wide_cpu) changed two things at once, estimates anywhere with a wide target and
# repainted renders; each alone here (configs scorer_flip_far_cpu, scorer_flip_paint_cpu), the same
# recipe as experiments/flip_wide.sh (5,000 steps from scorer_flip_cpu on s44_flip_mix, rate 5e-4,
# seed 451), then the same offline sweep on the default's stored validation runs. Every stage resumes.
# Needs flip_wide.sh's images and the default's validation runs in EV (label ens_native).
#   bash experiments/flip_ablation.sh DATA_ROOT RUNS_ROOT [EV]
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s46}"; EV="${3:-/work/runs/validation}"
PY="${PYTHON:-python}"
source "$(dirname "$0")/_flip_scorer.sh"
for part in paint far; do
  scorer_run flip_$part scorer_flip_${part}_cpu s44_flip_mix 5000 --lr 5e-4 --warmup 100 --seed 451 \
    --init rhaml_jax/checkpoints/scorer_flip_cpu
  flip_sweep flip_$part "$RUNS/export/flip_$part" --mirror
done
