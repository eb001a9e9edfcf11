#!/usr/bin/env bash
# Issue 15, session 44 (BENCHMARKS.md, "A front/back scorer"): the front/back scorer (config
# scorer_flip_cpu: the refined pose against it turned by 180 deg about the model's box centre)
# trained on session 40's images (run flip), then fine-tuned on images with robots in one paint
# mixed with session 40's sets (run flip_mono); each one's offline flip counts on the default's
# stored validation runs (label ens_native; experiments/flip_scorer.py), where the threshold is
# chosen. Every stage resumes (training with --resume; a finished set, export or sweep is kept).
# Needs session 40's images (experiments/retrain_fine_more.sh) and the default's validation runs in EV
# (LABEL=ens_native bash experiments/validate_networks.sh).
#   bash experiments/flip_scorer.sh DATA_ROOT RUNS_ROOT [EV]
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s44}"; EV="${3:-/work/runs/validation}"
PY="${PYTHON:-python}"
source "$(dirname "$0")/_flip_scorer.sh"
scorer_run flip scorer_flip_cpu s40_refine_mix 10000 --lr 1e-3 --warmup 200 --seed 44     # 43 min here, beside short evaluations
flip_sweep flip "$RUNS/export/flip"
# robots in one paint (half of them; half of the rest repainted), 3,600 images, with session 40's two sets
[ -f "$DATA/s44_flip_mono/.complete" ] || { "$PY" -m rhaml_jax.generate --out "$DATA/s44_flip_mono" --num 3600 --negatives 0 \
  --seed 441 --workers 2 --ranges.repaint-prob 0.5 --ranges.monochrome-prob 0.5 && touch "$DATA/s44_flip_mono/.complete"; }
[ -d "$DATA/s44_flip_mix" ] || "$PY" experiments/mix_bop.py --out "$DATA/s44_flip_mix" \
  "$DATA/s44_flip_mono" "$DATA/s40_refine_v1" "$DATA/s40_refine_v3"
scorer_run flip_mono scorer_flip_cpu s44_flip_mix 4000 --lr 5e-4 --warmup 100 --seed 441 --init "$RUNS/export/flip"
flip_sweep flip_mono "$RUNS/export/flip_mono"
# Then the validation by the rule (the pipeline's search runs between the coarse and the fine
# iterations; threshold 0.9 from the sweep of run flip), and the test and held-out sets, reported only:
#   LABEL=flip_s44 EXTRA="--scorer $RUNS/export/flip --flip-threshold 0.9 --post-iter 0" bash experiments/validate_networks.sh
#   python experiments/compare_validation.py ens_native flip_s44 --out compare_ens_native_flip_s44.json
#   python -m rhaml_jax.evaluate --data DATA/SET --modules iml,ir,pgo --zoom-mirror --scorer ... --flip-threshold 0.9 --post-iter 0
# Run flip's export is shipped as rhaml_jax/checkpoints/scorer_flip_cpu (opt-in: not the default).
