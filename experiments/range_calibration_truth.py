"""What the pose graph's range calibration fits when the observations are the truth: the true
relative poses of a BOP sequence (their ranges scaled by exp(N(0, --noise)) per frame, and by
--scales), fused with the sequence's odometry by `pgo.fuse_calibrated` with one transform between
the odometry frames for the whole sequence and with one per --windows rows. Prints the fitted c_0
minus the true log scale, and the fused ATE (the uncalibrated fusion's first). A biased fit here
comes from the odometry, not from any localiser (BENCHMARKS.md, "The range calibration read the
odometry's drift").

  python experiments/range_calibration_truth.py DATA/circle DATA/sine [--scales 1.0 1.03] [--windows 200 100 50 25]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import metrics, pgo
from rhaml_jax.data import read_bop
from rhaml_jax.sequence import group_scenes, load_scene

FIT = jax.jit(pgo.fuse_calibrated, static_argnames=("cfg", "window"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="+", type=Path, help="BOP scenario folders (one rendezvous sequence each)")
    ap.add_argument("--scales", nargs="+", type=float, default=[1.0, 1.03])
    ap.add_argument("--windows", nargs="+", type=int, default=[200, 100, 50, 25])
    ap.add_argument("--noise", type=float, default=0.005, help="per-frame log-range noise of the observations")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    for data in a.data:
        scene = load_scene(list(group_scenes(read_bop(data)).values())[0])
        seq, gt, seen = scene.seq, scene.gt, scene.observed
        for scale in a.scales:
            obs = gt.copy()
            obs[:, :2] *= (scale * np.exp(np.random.default_rng(a.seed).normal(0, a.noise, len(gt))))[:, None]
            rv = pgo.rendezvous_from_frames(seq.odom_a, seq.odom_b,
                                            pgo.observation_from_xy_yaw_rp(jnp.asarray(obs, jnp.float32)), seq.a_observes)
            valid = jnp.asarray(seen)
            off = metrics.summarize(np.asarray(pgo.fuse_jit(rv, pgo.FusionConfig(), valid=valid).relative)[seen], gt[seen])
            cells = []
            for window in (None, *a.windows):
                fusion, c = FIT(rv, pgo.FusionConfig(), valid, None, window=window)
                m = metrics.summarize(np.asarray(fusion.relative)[seen], gt[seen])
                cells.append(f"{window or 'one'}: {100 * (float(c[0]) - np.log(scale)):+.2f} %, ATE {m['ate']:.4f}")
            print(f"{data.parent.name}/{data.name} x {scale}: uncalibrated ATE {off['ate']:.4f} | " + " | ".join(cells), flush=True)


if __name__ == "__main__":
    main()
