"""Refined errors by range band, from `experiments/bench_refine.py --json` outputs: per band of the
true range, mean |dx| (cm), mean |relative range error| (%) and mean |dpsi| (deg) after one learned
stage (default: the last iteration row; the convergence check is not applied).

  python experiments/refine_bands.py OUT.json [OUT.json ...] [--start noise] [--stage -1] [--end-on] [--worst N]

--end-on splits each band into end-on views (relative heading within 20 deg of head-on or
tail-on) and the others, and adds the mean signed range error (%). --worst N lists the N frames
with the largest |dx| (their place in the pooled frames, range, relative heading, signed range error).

Several JSONs (e.g. validation seeds 7 and 8) are pooled.
"""

from __future__ import annotations

import argparse
import json

import jax.numpy as jnp
import numpy as np

from rhaml_jax import metrics

BANDS = (0.0, 3.0, 4.5, 6.0, 9.0)  # m


def relative_heading_deg(xypsi: np.ndarray) -> np.ndarray:
    """(N,) the robot's heading relative to the line of sight, (-180, 180] deg, from planar poses (N, 3)."""
    return np.rad2deg((xypsi[:, 2] - np.arctan2(xypsi[:, 1], xypsi[:, 0]) + np.pi) % (2 * np.pi) - np.pi)


def end_on(rel_deg: np.ndarray) -> np.ndarray:
    """(N,) bool: within 20 deg of head-on or tail-on."""
    rel = np.abs(rel_deg)
    return np.minimum(rel, 180 - rel) < 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("json", nargs="+")
    ap.add_argument("--start", default="noise", help="which start's frames: noise or iml")
    ap.add_argument("--stage", type=int, default=-1, help="row of learned_iterates (0: the start; -1: the last iteration)")
    ap.add_argument("--end-on", action="store_true", help="end-on views apart, with the signed range error")
    ap.add_argument("--worst", type=int, default=0, help="list this many frames of the largest |dx|")
    a = ap.parse_args()
    gt, est = [], []
    for path in a.json:
        runs = [p for p in json.load(open(path))["per_frame"] if p["start"] == a.start]
        if not runs:
            raise SystemExit(f"{path}: no per-frame rows of start {a.start!r}")
        gt.append(np.asarray(runs[0]["gt"])); est.append(np.asarray(runs[0]["learned_iterates"])[:, a.stage])
    gt, est = np.concatenate(gt), np.concatenate(est)
    d = np.asarray(metrics.abs_errors(jnp.asarray(est, jnp.float32), jnp.asarray(gt, jnp.float32)))
    r = np.hypot(gt[:, 0], gt[:, 1])
    signed = np.hypot(est[:, 0], est[:, 1]) / r - 1
    rel = relative_heading_deg(gt)
    ends = end_on(rel)
    views = (("end-on ", ends), ("other ", ~ends)) if a.end_on else (("", np.ones_like(ends)),)
    for lo, hi in zip(BANDS[:-1], BANDS[1:]):
        for view, v in views:
            k = v & (r >= lo) & (r < hi)
            if k.any():
                bias = f", range bias {100 * signed[k].mean():+.2f} %" if a.end_on else ""
                print(f"{view}{lo:.1f}-{hi:.1f} m ({k.sum()}): |dx| {100 * d[k, 0].mean():.2f} cm, |range| {100 * np.abs(signed[k]).mean():.2f} %, "
                      f"|dpsi| {np.rad2deg(d[k, 2]).mean():.2f} deg{bias}")
    for i in np.argsort(-d[:, 0])[: a.worst]:
        print(f"frame {i}: range {r[i]:.2f} m, relative heading {rel[i]:+.0f} deg, |dx| {100 * d[i, 0]:.2f} cm, "
              f"range {100 * signed[i]:+.2f} %")

if __name__ == "__main__":
    main()
