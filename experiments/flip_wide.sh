#!/usr/bin/env bash
# Issue 15, session 45 (BENCHMARKS.md, "A front/back scorer for the estimates IR leaves"): the shipped
# front/back scorer (scorer_flip_cpu, session 44's run flip) fine-tuned (config scorer_flip_wide_cpu)
# from estimates anywhere half the time (far_prob 0.5, soft targets of sigma 30 deg: on unfamiliar looks
# IR leaves headings tens of degrees off, which the shipped scorer, trained within 6 deg, turns) and its
# renders repainted half the time (paint_prob 0.5: half of those in one paint), on the images session
# 44's flip_mono fine-tune had (robots in one paint or repainted, mixed with session 40's two sets). Then the offline sweeps on the
# default's stored validation runs, plain and with the mirrored read (flip_scorer.py --mirror), of the
# shipped scorer and the new one. Every stage resumes (training with --resume; a finished set, export
# or sweep is kept).
# Needs the default's validation runs in EV (LABEL=ens_native bash experiments/validate_networks.sh).
#   bash experiments/flip_wide.sh DATA_ROOT RUNS_ROOT [EV]
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s45}"; EV="${3:-/work/runs/validation}"
PY="${PYTHON:-python}"; WORKERS="${WORKERS:-1}"
gen() {  # out seed count generate-args
  [ -f "$DATA/$1/.complete" ] || { "$PY" -m rhaml_jax.generate --out "$DATA/$1" --num "$3" --negatives 0 --seed "$2" \
    --workers "$WORKERS" "${@:4}" && touch "$DATA/$1/.complete"; }
}
gen s44_flip_mono 441 3600 --ranges.repaint-prob 0.5 --ranges.monochrome-prob 0.5
gen s40_refine_v3 402 2400 --ranges.repaint-prob 0.5
gen s40_refine_v1 401 2400 --appearance v1
[ -d "$DATA/s44_flip_mix" ] || "$PY" experiments/mix_bop.py --out "$DATA/s44_flip_mix" \
  "$DATA/s44_flip_mono" "$DATA/s40_refine_v1" "$DATA/s40_refine_v3"
source "$(dirname "$0")/_flip_scorer.sh"
scorer_run flip_wide scorer_flip_wide_cpu s44_flip_mix 5000 --lr 5e-4 --warmup 100 --seed 451 \
  --init rhaml_jax/checkpoints/scorer_flip_cpu
flip_sweep flip_mirror rhaml_jax/checkpoints/scorer_flip_cpu --mirror       # the shipped scorer's, with the mirrored read
flip_sweep flip_wide "$RUNS/export/flip_wide" --mirror
