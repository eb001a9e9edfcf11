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
run=flip_wide
grep -qs '"step": 5000,' "$RUNS/$run/metrics.jsonl" || \
  "$PY" -m rhaml_jax.train --stage scorer --config scorer_flip_wide_cpu --data "$DATA/s44_flip_mix" --out "$RUNS/$run" \
    --steps 5000 --batch 16 --lr 5e-4 --warmup 100 --seed 451 --init rhaml_jax/checkpoints/scorer_flip_cpu \
    --val-every 1000 --val-batches 8 --ckpt-every 250 --log-every 50 --no-progress \
    $( [ -d "$RUNS/$run/checkpoints" ] && echo --resume )
[ -e "$RUNS/export/$run" ] || "$PY" -c "from rhaml_jax.refine.scorer import export_scorer as e; e('$RUNS/$run', '$RUNS/export/$run')"
sweep() {  # name scorer: experiments/flip_scorer.py --mirror on the 14 validation sequences' stored default runs
  local d sets args=()
  sets="val_scen_s7_500/circle val_scen_s7_500/sine val_scen_s8_500/circle val_scen_s8_500/sine
    val_ood/circle val_ood/sine val_ood_s2/circle val_ood_s2/sine"
  for c in purple orange grey; do for s in circle sine; do sets="$sets val_mono/${s}_$c"; done; done
  for d in $sets; do args+=(--run "$EV/ens_native_$(echo "$d" | tr / _).json" "$DATA/$d"); done
  [ -e "$RUNS/${1}_val.json" ] || "$PY" experiments/flip_scorer.py --scorer "$2" "${args[@]}" --mirror \
    --out "$RUNS/${1}_val.json" | tee "$RUNS/${1}_val.log"
}
sweep flip rhaml_jax/checkpoints/scorer_flip_cpu
sweep $run "$RUNS/export/$run"
