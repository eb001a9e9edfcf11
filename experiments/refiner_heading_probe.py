"""Does the learned refiner respond to a heading error? One learned iteration from the truth with
the heading turned by +-DPSI (and optionally shifted in x), on every STRIDE-th frame of a BOP
scenario: the heading change it makes, whose sign should oppose the error's.

  python experiments/refiner_heading_probe.py --data /work/data/ours/circle [--refiner CKPT]
      [--stride 50] [--dpsi 20] [--shift 0.15]
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--refiner", default=None, help="default: the shipped refiner_cpu")
    ap.add_argument("--stride", type=int, default=50)
    ap.add_argument("--dpsi", type=float, default=20.0, help="heading error (deg)")
    ap.add_argument("--shift", type=float, default=0.15, help="also a start with this x error (m)")
    a = ap.parse_args(argv)
    import jax

    from rhaml_jax import refine
    from rhaml_jax.data import load_rgb, read_bop
    from rhaml_jax.planar import wrap_angle

    frames = [f for f in read_bop(a.data) if f.observed][:: a.stride]
    cfg, (refiner, mesh, _) = refine.load_stage(a.refiner, a.data)
    once = jax.jit(lambda im, K, x: refine.refine(refiner, mesh, im, K, x, refine.RefineConfig(n_iter=1)).iterates)
    images = [load_rgb(f.rgb).astype(np.float32) / 255.0 for f in frames]
    rows = []
    for dpsi in (-a.dpsi, a.dpsi):
        for shift in (0.0, a.shift):
            change = []
            for f, im in zip(frames, images):
                x0 = np.asarray(f.xypsi, np.float32) + np.array([shift, 0.0, np.deg2rad(dpsi)], np.float32)
                it = np.asarray(once(im, f.K.astype(np.float32), x0))
                change.append(np.degrees(wrap_angle(it[1, 2] - it[0, 2])))
            rows.append({"heading_error_deg": dpsi, "x_error_m": shift, "frames": len(change),
                         "change_mean_deg": float(np.mean(change)), "change_std_deg": float(np.std(change))})
            print(rows[-1], flush=True)
    return rows


if __name__ == "__main__":
    main()
