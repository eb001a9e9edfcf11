"""Where IML's front/back flips are, in finer bins than `evaluate`'s `iml_flips_by_view`: by the
view (`metrics.view_deg`: 0 deg, the robot's back faces the camera; 180 deg, its front) and by
range, from stored `evaluate --json` output (no network runs here).

    python experiments/flips_by_view.py LABEL=EVAL.json [LABEL=EVAL.json ...] [--out OUT.json]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from rhaml_jax.metrics import flipped, view_deg

VIEW_BINS_DEG = (0, 30, 60, 90, 120, 150, 180)
RANGE_BINS_M = (0, 3, 4, 5, 6, 100)


def flips_binned(frames: list[dict]) -> dict:
    """Flips of IML's estimate over the detected frames with the robot in view, in all and per bin
    (each bin: [flips, frames])."""
    seen = [f for f in frames if f["observed"] and f["detected"]]
    est = np.array([f["iml_est"] for f in seen], float).reshape(-1, 3)
    gt = np.array([f["gt"] for f in seen], float).reshape(-1, 3)
    flip = np.asarray(flipped(est[:, 2], gt[:, 2]), bool)
    view = view_deg(gt)
    rng = np.hypot(gt[:, 0], gt[:, 1])

    def binned(x, edges):
        return {f"{a}-{b}": [int(flip[(x >= a) & (x < b)].sum()), int(((x >= a) & (x < b)).sum())]
                for a, b in zip(edges[:-1], edges[1:])}

    return {"flips": int(flip.sum()), "frames": len(seen), "by_view_deg": binned(view, VIEW_BINS_DEG[:-1] + (180.1,)),
            "by_range_m": binned(rng, RANGE_BINS_M)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", metavar="LABEL=EVAL.json")
    ap.add_argument("--out")
    a = ap.parse_args()
    res = {}
    for item in a.runs:
        label, _, path = item.partition("=")
        res[label] = r = flips_binned(json.loads(open(path).read())["frames"])
        pct = lambda fn: f"{100 * fn[0] / fn[1]:.0f} % of {fn[1]}" if fn[1] else "-"  # noqa: E731
        print(f"{label}: {r['flips']} flips of {r['frames']}; by view (deg): "
              + "; ".join(f"{k} {pct(v)}" for k, v in r["by_view_deg"].items())
              + "; by range (m): " + "; ".join(f"{k} {pct(v)}" for k, v in r["by_range_m"].items()))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
