"""Milliseconds per frame of the IR stage's learned iterations for several (coarse, fine) iteration
counts (and `RefineConfig.mirror` settings), measured side by side in one process: the shipped refiner cascade on a batch of frames of a
BOP set (jax.vmap of `refine.refine`, no alignment), each setting's median over `--repeats` calls,
the settings' calls interleaved so that load on the machine falls on all alike.

  python experiments/time_refine_iterations.py --data DATA/circle --batch 8 --repeats 15 --settings 4,1 4,2 4,2,fine
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import data, refine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--settings", nargs="+", default=["4,1", "4,2"], help="n_iter,fine_iter[,mirror]")
    ap.add_argument("--fine-refiner", type=Path, action="append", default=[],
                    help="also time these fine refiners in every setting (default: the shipped one alone)")
    ap.add_argument("--scorer", type=Path, help="also time every setting with this heading scorer's search (`--post-iter` after it)")
    ap.add_argument("--post-iter", type=int, default=0, help="with --scorer: RefineConfig.post_iter")
    a = ap.parse_args()
    frames = [f for f in data.read_bop(a.data) if f.observed][: a.batch]
    if len(frames) < a.batch:
        raise SystemExit(f"{a.data}: {len(frames)} frames with the robot in view, --batch {a.batch} asked")
    _, st = refine.load_stage(None, a.data)  # the shipped cascade; each setting brings its own RefineConfig
    fines = {"": st.fine, **{f" {p}": refine.load_refiner(p, data.load_bop_model(a.data)) for p in a.fine_refiner}}
    images = jnp.asarray(np.stack([data.load_rgb(f.rgb) for f in frames]), jnp.float32) / 255
    Ks = jnp.asarray(np.stack([f.K for f in frames]), jnp.float32)
    init = jnp.asarray(np.stack([f.xypsi for f in frames]), jnp.float32) + jnp.array([0.05, 0.03, 0.1])
    scorers = {"": None} if a.scorer is None else {"": None, " +scorer": refine.load_scorer(a.scorer, data.load_bop_model(a.data))}
    fns = {}
    for s in a.settings:
        n, f, *m = s.split(",")
        rc = refine.RefineConfig(align=None, n_iter=int(n), fine_iter=int(f), mirror=m[0] if m else "none", post_iter=a.post_iter)
        for name, fine in fines.items():
            for sname, sc in scorers.items():
                fns[s + name + sname] = fn = jax.jit(jax.vmap(lambda im, K, i, rc=rc, fine=fine, sc=sc: refine.refine(
                    st.refiner, st.mesh, im, K, i, rc, fine=fine, scorer=sc).xypsi))
                jax.block_until_ready(fn(images, Ks, init))  # compile
    ts = {s: [] for s in fns}
    for _ in range(a.repeats):
        for s, fn in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(fn(images, Ks, init))
            ts[s].append(time.perf_counter() - t)
    base = statistics.median(next(iter(ts.values())))
    for s in ts:
        m = statistics.median(ts[s])
        print(f"n_iter,fine_iter[,mirror] {s}: {1e3 * m / a.batch:.1f} ms per frame at batch {a.batch} ({m / base:.2f}x the first)")


if __name__ == "__main__":
    main()
