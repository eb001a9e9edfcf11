"""Offline trial of a two-threshold detection: frames IML scored under the pipeline's threshold
(o < 0.5) but at or above LOW are called detected where their IML estimate agrees with the pose
graph fused from the confident frames (the stored pipeline answer `est`): position within GATE of
the range, heading within HEADING deg of it or of its opposite (the graph tries both). Writes the
validation label anew for `compare_validation.py`, which refits the pose graph from the stored
estimates; the newly called frames carry IML's estimate in the IR rows (IR never ran on them).

    python experiments/redetect_offline.py --base default --low 0.2 --gate 0.1 --out OUT
    python experiments/compare_validation.py default LABEL --ev OUT      # OUT also needs links to EV/default_*
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rhaml_jax.pipeline import agrees


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="default")
    ap.add_argument("--ev", type=Path, default=Path("/work/runs/validation"))
    ap.add_argument("--low", type=float, required=True, help="the second, lower objectness threshold")
    ap.add_argument("--gate", type=float, default=0.1, help="position gate, a fraction of the fused range")
    ap.add_argument("--heading", type=float, default=30.0, help="heading gate (deg), modulo 180 deg")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    label = f"{a.base}redet{a.low:g}g{a.gate:g}".replace(".", "p")
    a.out.mkdir(parents=True, exist_ok=True)
    for path in sorted(a.ev.glob(f"{a.base}_val_*.json")):
        seq = path.stem[len(a.base) + 1:]
        if seq.endswith("background") or seq.endswith("random"):  # no pose graph there to gate by
            continue
        d = json.loads(path.read_text())
        rows = [x for x in d["frames"] if not x["detected"] and x["o"] >= a.low]
        if rows:  # the pipeline's own gate (pipeline.agrees), on IML's estimates against the stored answer
            ok = np.asarray(agrees(np.array([x["iml_est"] for x in rows]), np.array([x["est"] for x in rows]), a.gate,
                                   a.heading))
            for x, k in zip(rows, ok):
                x["detected"] = bool(k)
        n = int(sum(x["detected"] for x in rows))
        (a.out / f"{label}_{seq}.json").write_text(json.dumps(d))
        print(f"{label} {seq}: {n} frames called detected")


if __name__ == "__main__":
    main()
