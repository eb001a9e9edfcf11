"""The pose graph with and without the odometry-calibrated range model (pgo.range_model), on
the shipped IML's estimates of circle and sine: what calibrating the shared range error buys.

  python experiments/range_calibration.py --data /work/data [--slope]

IML estimates are cached beside the data's name in --cache (a pure function of the images).
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="folder holding circle/ and sine/")
    ap.add_argument("--cache", default="/tmp")
    ap.add_argument("--slope", action="store_true", help="also fit the range slope c_1")
    a = ap.parse_args()
    import jax
    import jax.numpy as jnp

    from rhaml_jax import iml, metrics, pgo, sequence, tune_allocator
    from rhaml_jax.data import read_bop

    tune_allocator()
    m, p = iml.load_iml(zoom_mirror=True)
    out = {}
    for name in ("circle", "sine"):
        cache = os.path.join(a.cache, f"iml_{os.path.basename(os.path.abspath(a.data))}_{name}.npz")
        sc = sequence.load_scene(read_bop(os.path.join(a.data, name)))
        if not os.path.exists(cache):
            est = [jax.device_get(iml.localize_jit(m, p, sc.seq.images[i:i + 25], sc.seq.K[i:i + 25]))
                   for i in range(0, len(sc.frames), 25)]
            np.savez(cache, xypsi=np.concatenate([e.xypsi for e in est]), o=np.concatenate([e.o for e in est]),
                     flip=np.concatenate([e.flip_prob for e in est]))
        d = np.load(cache)
        det, flip = jnp.asarray(d["o"] >= 0.5), jnp.asarray(d["flip"])
        rv = pgo.rendezvous_from_frames(jnp.asarray(sc.seq.odom_a), jnp.asarray(sc.seq.odom_b),
                                        pgo.observation_from_xy_yaw_rp(jnp.asarray(d["xypsi"])), jnp.asarray(sc.seq.a_observes))
        r = pgo.fuse_jit(rv, pgo.FusionConfig(), valid=det, flip_prob=flip)
        c = jax.jit(pgo.range_model, static_argnames="slope")(rv, r.odom_a_T_odom_b, (r.inlier & det).astype(jnp.float32),
                                                              slope=a.slope)
        r2 = pgo.fuse_jit(pgo.rescale_observations(rv, c), pgo.FusionConfig(), valid=det, flip_prob=flip)
        o = sc.observed
        ratio = float(np.median(np.hypot(*d["xypsi"][o, :2].T) / np.hypot(*sc.gt[o, :2].T)))
        out[name] = {"median_range_ratio_iml": ratio, "c": np.asarray(c).tolist()}
        for k, v in (("iml", d["xypsi"]), ("fuse", r.relative), ("fuse_calibrated", r2.relative)):
            out[name][k] = metrics.summarize(np.asarray(v)[o], sc.gt[o])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
