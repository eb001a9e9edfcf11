#!/bin/bash
# Scores one set of networks on the validation sets, as the shipping choices are made
# (BENCHMARKS.md, "How a default is chosen"): ours (circle + sine of seeds 7 and 8, 500 frames
# each), the OOD look (circle + sine with odometry of seeds 1 and 2; random and background of seed 1
# for detection) and the one-paint looks (circle + sine of seed 7, 300 frames each, the robot
# purple, orange or grey: experiments/val_mono.py; and the same images with the robot's own model as
# the set's model, val_mono_cad, from session 46 on), with `evaluate --modules iml,ir,pgo
# --zoom-mirror`; then the rows of experiments/pipeline_from_json.py. Never the held-out set. Two
# labels are compared by experiments/compare_validation.py.
#
#   LABEL=fit NETS=RUN/networks bash experiments/validate_networks.sh      # NETS/{amlnet,zoom,refiner[,fine]}
#   LABEL=default bash experiments/validate_networks.sh                    # the shipped defaults
#   LABEL=wb EXTRA="--white-balance" bash experiments/validate_networks.sh # more evaluate options
#   LABEL=redet EXTRA_PGO="--redetect-threshold 0.2" bash ...              # options of the pose-graph runs only
set -e
: "${LABEL:?}" "${DATA:=/work/data}" "${EV:=/work/runs/validation}"
PY=${PY:-python}
mkdir -p "$EV"
NETARGS=()
[ -n "$NETS" ] && NETARGS=(--amlnet "$NETS/amlnet" --zoom "$NETS/zoom" --refiner "$NETS/refiner")
[ -n "$NETS" ] && [ -e "$NETS/fine" ] && NETARGS+=(--fine-refiner "$NETS/fine")   # a cascade's second refiner
json() { echo "$EV/${LABEL}_$(echo "$1" | tr / _).json"; }  # set -> its evaluate output (kept: a rerun skips it)
ev() {  # set modules
  j=$(json "$1")
  pgo=(); [[ "$2" == *pgo* ]] && pgo=($EXTRA_PGO)
  [ -f "$j" ] || $PY -m rhaml_jax.evaluate --data "$DATA/$1" --modules "$2" --zoom-mirror "${NETARGS[@]}" $EXTRA "${pgo[@]}" --json "$j" > "${j%.json}.log"
}
OURS="val_scen_s7_500/circle val_scen_s7_500/sine val_scen_s8_500/circle val_scen_s8_500/sine"
OOD="val_ood/circle val_ood/sine val_ood_s2/circle val_ood_s2/sine"
MONO=$(for c in purple orange grey; do for s in circle sine; do echo "val_mono/${s}_$c"; done; done)
CAD=$(echo "$MONO" | sed s/val_mono/val_mono_cad/)
for d in $OURS $OOD $MONO $CAD; do ev "$d" iml,ir,pgo; done
for d in val_ood/random val_ood/background; do ev "$d" iml,ir; done
args=(--set ours); for d in $OURS; do args+=("$(json "$d")" "$DATA/$d"); done
args+=(--set ood); for d in $OOD; do args+=("$(json "$d")" "$DATA/$d"); done
args+=(--set mono); for d in $MONO; do args+=("$(json "$d")" "$DATA/$d"); done
args+=(--set cad); for d in $CAD; do args+=("$(json "$d")" "$DATA/$d"); done
$PY experiments/pipeline_from_json.py "${args[@]}" --out "$EV/${LABEL}_summary.json"
for d in val_ood/random val_ood/background; do
  $PY -c "import json,sys; m=json.load(open(sys.argv[1]))['metrics']; print(sys.argv[2], 'detection accuracy', round(m['detection_accuracy'], 3))" \
      "$(json "$d")" "$d"
done
