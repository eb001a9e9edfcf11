#!/usr/bin/env bash
# Issue 15, session 47 (BENCHMARKS.md, "A segmenter for the cascade's end"): the observed-mask segmenter
# trained on crops around the residuals the refiner cascade leaves (config segmenter_fine_cpu, RGB, on the
# scorer's image mix: experiments/flip_wide.sh makes s44_flip_mix), then the alignment to its masks from
# the default cascade's end on one circle of each validation look (beside the alignment to ground-truth
# masks), the validation sets with it (the choice), and the test sets (reported only). Every stage resumes.
#   bash experiments/segmenter_fine.sh DATA_ROOT RUNS_ROOT
set -euo pipefail
DATA="${1:-/work/data}"; RUNS="${2:-/work/runs/s47}"
PY="${PYTHON:-python}"
. "$(dirname "$0")/_test_sets.sh"
C=rhaml_jax/checkpoints
"$PY" -m rhaml_jax.train --stage segmenter --config segmenter_fine_cpu --data "$DATA/s44_flip_mix" --out "$RUNS/seg_fine" \
  --steps 3500 --batch 32 --lr 2e-3 --warmup 100 --val-every 500 --no-progress \
  $( [ -d "$RUNS/seg_fine/checkpoints" ] && echo --resume ) > "$RUNS/seg_fine.log" 2>&1
[ -d "$RUNS/export/seg_fine" ] || "$PY" -c "from rhaml_jax.refine.segmenter import export_segmenter as e; e('$RUNS/seg_fine', '$RUNS/export/seg_fine')"
SEG="$RUNS/export/seg_fine"
# seg_bench NAME [BENCH_ARGS...]: _test_sets.sh's look_bench (the default cascade from the paper's noise on one
# circle of each look), then SEGMENTER_ALIGN's schedule to the ground-truth masks and to the segmenter's
seg_bench() {
  local name=$1
  shift
  look_bench "$name" --refiner $C/refiner_paint_cpu --fine-refiner $C/refiner_fine_paint_cpu $C/refiner_fine_native_cpu \
    --oracle-from-learned --segmenter "$SEG" --segmenter-from-learned --no-coarse --stages "2:4,4:4,8:3,8:3" "$@"
}
seg_bench seg_bench
# the same at mask threshold 0.4 (where the masks have the true area on the validation looks:
# experiments/segmenter_iou.py --areas --split test --margins 1.4), with the whole IR stage and 2 fine iterations after
seg_bench fa0.4 --mask-threshold 0.4 --no-from-start --fine-after-align 2 --no-oracle-from-learned
# the choice: the validation sets with the alignment (its threshold 0.4, no fine iteration after it, no gate;
# run before AlignConfig.min_turn / max_shift existed, so SEGMENTER_ALIGN's gates are named off here), against
# session 46's default (label paint_both_s46); then the gates applied offline to the two runs (merge_gate.py)
EV=/work/runs/validation
LABEL=seg0_s47 EXTRA="--segmenter $SEG --fine-after-align 0 --mask-threshold 0.4 --no-align-gates" \
  PY="$PY" DATA="$DATA" bash "$(dirname "$0")/validate_networks.sh" > "$RUNS/val_seg0.out" 2>&1
"$PY" experiments/compare_validation.py paint_both_s46 seg0_s47 --looks ours ood mono cad --out "$RUNS/compare_paint_both_s46_seg0_s47.json"
"$PY" experiments/merge_gate.py paint_both_s46 seg0_s47 seggate_s47 --min-turn-deg 4 --max-shift 0.03 --ev "$EV"
"$PY" experiments/compare_validation.py paint_both_s46 seggate_s47 --looks ours ood mono cad --out "$RUNS/compare_paint_both_s46_seggate_s47.json"
# The test and held-out sets, reported only: the pipeline with the alignment, then issue 15's table
BENCH_ARGS="--scorer $C/scorer_flip_wide_cpu --flip-threshold 0.8 --post-iter 0 --segmenter $SEG --segmenter-from-learned
  --mask-threshold 0.4 --no-coarse --stages 2:4,4:4,8:3,8:3 --min-turn-deg 4 --max-shift 0.03 --no-from-start" REFINER=$C/refiner_paint_cpu \
  test_sets seg "$C/refiner_fine_paint_cpu $C/refiner_fine_native_cpu" 2 fine --segmenter "$SEG" --fine-after-align 0 \
  --mask-threshold 0.4
