"""Speed of the JAX lidar and log-odds mapping against plain NumPy/Python versions, side by side.

  PYTHONPATH=. python experiments/bench_lidar.py

- ray casting: 360 beams against a random field's wall segments, one scan; jitted JAX
  (`mapping.cast_rays`) against the same formula as a NumPy loop over segments;
- mapping: the scans of one `explore` robot (every 2nd of its steps) into a 480 x 480 grid
  (`mapping.robot_map`: one `lax.scan`, each scan vectorised) against a Python loop over scans
  that does each scan's cell updates with NumPy (np.unique of the sampled cells).
Medians of 5 repeats after a warm-up (compilation excluded and reported separately).
"""

from __future__ import annotations

import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.mapping import ExploreConfig, GridSpec, beam_angles, cast_rays, integrate_scans, simulate_exploration


def median_time(fn, repeats=5):
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def numpy_cast(segments, origin, directions, max_range):
    best = np.full(len(directions), max_range)
    for a, b in segments:
        e = b - a
        q = a - origin
        den = directions[:, 0] * e[1] - directions[:, 1] * e[0]
        ok = np.abs(den) > 1e-12
        den = np.where(ok, den, 1.0)
        t = (q[0] * e[1] - q[1] * e[0]) / den
        u = (q[0] * directions[:, 1] - q[1] * directions[:, 0]) / den
        hit = ok & (t > 0) & (u >= 0) & (u <= 1)
        best = np.where(hit & (t < best), t, best)
    return best


def numpy_map(poses, ranges, spec: GridSpec, cfg):
    lo = np.zeros((spec.height, spec.width), np.float32)
    ang = beam_angles(cfg)
    step = spec.resolution / 2
    ts = (np.arange(int(np.ceil(cfg.max_range / step))) + 0.5) * step
    size = spec.height * spec.width
    for pose, r in zip(poses, ranges):
        th = pose[2] + ang
        d = np.stack([np.cos(th), np.sin(th)], -1)
        pts = pose[None, None, :2] + ts[None, :, None] * d[:, None]
        ok = ts[None] < r[:, None] - spec.resolution / 2
        j = np.floor((pts[..., 0] - spec.x0) / spec.resolution).astype(int)
        i = np.floor((pts[..., 1] - spec.y0) / spec.resolution).astype(int)
        inside = ok & (i >= 0) & (i < spec.height) & (j >= 0) & (j < spec.width)
        free = np.unique(i[inside] * spec.width + j[inside])
        hp = pose[None, :2] + r[:, None] * d
        hj = np.floor((hp[:, 0] - spec.x0) / spec.resolution).astype(int)
        hi = np.floor((hp[:, 1] - spec.y0) / spec.resolution).astype(int)
        hin = (r < cfg.max_range) & (hi >= 0) & (hi < spec.height) & (hj >= 0) & (hj < spec.width)
        hit = np.unique(hi[hin] * spec.width + hj[hin])
        delta = np.zeros(size, np.float32)
        delta[free] = cfg.l_free
        delta[hit] = cfg.l_occ
        lo = np.clip(lo + delta.reshape(lo.shape), cfg.l_min, cfg.l_max)
    return lo


def main():
    cfg = ExploreConfig()
    run = simulate_exploration(0, cfg)
    segs = run.field.segments
    pose = run.truth_a[100]
    th = pose[2] + beam_angles(cfg.lidar)
    d = np.stack([np.cos(th), np.sin(th)], -1)
    args = (jnp.asarray(segs, jnp.float32), jnp.asarray(pose[None, :2], jnp.float32), jnp.asarray(d[None], jnp.float32),
            cfg.lidar.max_range)
    t = time.perf_counter()
    jax.block_until_ready(cast_rays(*args))
    compile_cast = time.perf_counter() - t
    jax_cast = median_time(lambda: jax.block_until_ready(cast_rays(*args)), 20)
    np_cast = median_time(lambda: numpy_cast(segs, pose[:2], d, cfg.lidar.max_range), 20)
    ref = numpy_cast(segs, pose[:2], d, cfg.lidar.max_range)
    assert np.allclose(np.asarray(cast_rays(*args))[0], ref, atol=1e-4)

    n = int(np.ceil(2 * 14.0 / cfg.resolution))
    spec = GridSpec(-14.0, -14.0, n, n, cfg.resolution)
    poses, ranges = run.odom_a[::2], run.ranges_a[::2]
    z = jnp.zeros((n, n), jnp.float32)
    jp, jr = jnp.asarray(poses), jnp.asarray(ranges)
    t = time.perf_counter()
    jax.block_until_ready(integrate_scans(z, jp, jr, spec, cfg.lidar))
    compile_map = time.perf_counter() - t
    jax_map = median_time(lambda: jax.block_until_ready(integrate_scans(z, jp, jr, spec, cfg.lidar)))
    np_map = median_time(lambda: numpy_map(poses, ranges, spec, cfg.lidar), 3)
    lo = np.asarray(integrate_scans(z, jp, jr, spec, cfg.lidar)[0])
    # float32 log-odds summed in another order may differ in the last bit; cells must agree
    assert np.abs(lo - numpy_map(poses, ranges, spec, cfg.lidar)).max() < 1e-4
    print(json.dumps({
        "segments": len(segs), "beams": cfg.lidar.beams,
        "cast_ms": {"jax": 1e3 * jax_cast, "numpy": 1e3 * np_cast, "numpy_over_jax": np_cast / jax_cast,
                    "jax_compile_s": compile_cast},
        "map": {"scans": len(poses), "grid": [n, n], "jax_s": jax_map, "numpy_s": np_map, "numpy_over_jax": np_map / jax_map,
                "jax_compile_s": compile_map},
    }))


if __name__ == "__main__":
    main()
