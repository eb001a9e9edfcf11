#!/usr/bin/env python3
"""Interleaved comparison of `rhaml_pgo` variants on the RHAML-size graph: band solver (twisted,
thomas) x XLA threading (one thread as `rhaml_pgo_jit`, or the default thread pool).

    python experiments/compare_rhaml_pgo.py [--k 100] [--rounds 20] [--calls 50]

Float64. Every variant is compiled first; then `--rounds` rounds each run every variant
`--calls` times in turn, so that load from other processes hits all alike; prints the median
and quartiles over all calls of each variant.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.pgo import RhamlPGOConfig, rhaml_pgo  # noqa: E402
from rhaml_jax.pgo._rhaml_graph import SMALL_GRAPH_COMPILER_OPTIONS  # noqa: E402
from rhaml_jax.pgo._simulate import simulate_rendezvous  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--k", type=int, default=100, help="rendezvous")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--calls", type=int, default=50, help="calls per variant and round")
    a = ap.parse_args()
    rv = jax.tree.map(jnp.asarray, simulate_rendezvous(a.k, seed=0).rendezvous)
    compiled = {}
    for how in ("twisted", "thomas"):
        cfg = RhamlPGOConfig()
        cfg = dataclasses.replace(cfg, solver=dataclasses.replace(cfg.solver, band_solver=how))
        for threads, opts in (("one thread", SMALL_GRAPH_COMPILER_OPTIONS), ("thread pool", None)):
            lowered = jax.jit(lambda rv, cfg=cfg: rhaml_pgo(rv, cfg)).lower(rv)
            compiled[how, threads] = lowered.compile(opts) if opts else lowered.compile()
    ts = {k: [] for k in compiled}
    for _ in range(a.rounds):
        for k, f in compiled.items():
            jax.block_until_ready(f(rv))
            for _ in range(a.calls):
                t = time.perf_counter()
                jax.block_until_ready(f(rv))
                ts[k].append(time.perf_counter() - t)
    print(f"K = {a.k}, float64, load average {os.getloadavg()[0]:.1f}")
    for (how, threads), v in ts.items():
        q1, q2, q3 = (1e3 * x for x in statistics.quantiles(v, n=4))
        print(f"{how:8s} {threads:12s} median {q2:.3f} ms (p25 {q1:.3f}, p75 {q3:.3f})")


if __name__ == "__main__":
    main()
