"""Milliseconds of the batch pose-graph step (`pipeline.fuse_estimates`: fuse, calibrate the range,
fuse again) on one sequence's stored refined estimates, for several range-window settings, measured
side by side in one process: each setting's median over `--repeats` calls, the settings' calls
interleaved so that load on the machine falls on all alike.

  python experiments/time_range_window.py --run EVAL.json --data DATA [--repeats 30]

Settings: one transform for the whole sequence; a transform per 200 rows always (session 40); the
window only under a 2 % scale (session 41's default: both calibrations run).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from rhaml_jax import pipeline
from rhaml_jax.data import read_bop
from rhaml_jax.iml import Estimate
from rhaml_jax.sequence import group_scenes, load_scene

SETTINGS = {"one transform": dict(range_window=None), "window always": dict(range_window_max_scale=None),
            "window under 2 %": dict(range_window_max_scale=0.02)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", type=Path, required=True, help="an evaluate --modules iml,ir,pgo --json output")
    ap.add_argument("--data", type=Path, required=True, help="its BOP data folder")
    ap.add_argument("--repeats", type=int, default=30)
    a = ap.parse_args()
    rows = json.loads(a.run.read_text())["frames"]
    if "ir_est" not in rows[0]:
        ap.error(f"{a.run}: no ir_est rows (run evaluate --modules iml,ir,pgo)")
    seq = load_scene(list(group_scenes(read_bop(a.data)).values())[0]).seq
    n = len(rows)
    est = Estimate(xypsi=jnp.asarray([r["ir_est"] for r in rows], jnp.float32), o=jnp.ones(n, jnp.float32),
                   flip_prob=jnp.asarray([r["ir_flip_prob"] for r in rows], jnp.float32), roll_pitch=jnp.zeros((n, 2), jnp.float32))
    det = jnp.asarray([r["detected"] for r in rows])
    fns = {}
    for name, kw in SETTINGS.items():
        cfg = pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), **kw)
        fn = jax.jit(lambda e, d, cfg=cfg: pipeline.fuse_estimates(cfg, e, d, seq.odom_a, seq.odom_b, seq.a_observes))
        jax.block_until_ready(fn(est, det))  # compile
        fns[name] = fn
    times = {name: [] for name in fns}
    for _ in range(a.repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(fn(est, det))
            times[name].append(time.perf_counter() - t)
    for name, ts in times.items():
        print(f"{name:18s} {1e3 * statistics.median(ts):8.1f} ms  ({n} rows, median of {a.repeats})")


if __name__ == "__main__":
    main()
