"""Where the time of the RHAML-size pose graph goes: each stage of `rhaml_pgo` jitted alone.

    python experiments/profile_rhaml_pgo.py [--k 100] [--repeats 300]

Every stage is compiled as `rhaml_pgo_jit` is (Eigen's thread pool off for these small kernels);
one line times Algorithm 1 with XLA's default threading for comparison.
Prints medians (ms) of: Algorithm 1 end to end; DeleteErroneousNodes + ConstructPoseGraph +
CalculateInformationMatrix; one linearisation (the ladder's normal equations); one
block-tridiagonal solve by `twisted_solve` and by `thomas_solve`; the whole GN loop.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.pgo import RhamlPGOConfig, rhaml_pgo, rhaml_pgo_jit  # noqa: E402
from rhaml_jax.pgo._banded import thomas_solve, twisted_solve  # noqa: E402
from rhaml_jax.pgo._ladder import ladder_iterate, ladder_normal_equations  # noqa: E402
from rhaml_jax.pgo._residuals import inverse, poses_to_se2  # noqa: E402
from rhaml_jax.pgo._rhaml_graph import SMALL_GRAPH_COMPILER_OPTIONS, _prepare  # noqa: E402
from rhaml_jax.pgo._simulate import simulate_rendezvous  # noqa: E402
from rhaml_jax.pgo._solver import Problem  # noqa: E402


def jit1(f):
    """jit with the options `rhaml_pgo_jit` uses (XLA kernels on one thread)."""
    return jax.jit(f, compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)


def median_ms(f, *args, repeats: int) -> float:
    jax.block_until_ready(f(*args))
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(f(*args))
        ts.append(time.perf_counter() - t)
    return 1e3 * statistics.median(ts)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--k", type=int, default=100, help="rendezvous")
    ap.add_argument("--repeats", type=int, default=300)
    a = ap.parse_args()
    cfg = RhamlPGOConfig()
    rv = jax.tree.map(jnp.asarray, simulate_rendezvous(a.k, seed=0).rendezvous)
    prepare = jit1(lambda rv: _prepare(rv, cfg.sigma_deg, cfg.kappa, cfg.tau))
    _, g, info = prepare(rv)
    n = g.poses.shape[0]
    both = poses_to_se2(jnp.concatenate([g.poses, g.measurements])).unit_complex_xy
    robust = jnp.ones((a.k, 3), bool).at[:, :2].set(False).reshape(-1)
    p = Problem(both[:n], inverse(both[n:]), g.edges[:, 0], g.edges[:, 1], info, robust, None, None, None)
    lin = jit1(lambda T, p: ladder_normal_equations(T, p, g.a_observes, cfg.solver))
    D, Lo, gg, _ = lin(p.T0, p)
    D = D + jnp.eye(6)  # the gauge block of group 0 is the identity already; keep every block SPD
    r = -gg[..., None]
    rows = {
        "rhaml_pgo_jit (Algorithm 1 end to end, one-thread XLA kernels)": median_ms(rhaml_pgo_jit, rv, repeats=a.repeats),
        "rhaml_pgo jitted with XLA's default thread pool": median_ms(jax.jit(rhaml_pgo), rv, repeats=a.repeats),
        "prepare (delete + construct + information)": median_ms(prepare, rv, repeats=a.repeats),
        "one linearisation (ladder normal equations)": median_ms(lin, p.T0, p, repeats=a.repeats),
        "one solve, twisted_solve (both ends in one scan; the default)": median_ms(jit1(twisted_solve), D, Lo, r,
                                                                                   repeats=a.repeats),
        "one solve, thomas_solve (scan of block LDL^T)": median_ms(jit1(thomas_solve), D, Lo, r, repeats=a.repeats),
        "GN loop (ladder_iterate)": median_ms(jit1(lambda p: ladder_iterate(p, g.a_observes, cfg.solver)), p,
                                              repeats=a.repeats),
    }
    print(f"K = {a.k}, float64, XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}, load average {os.getloadavg()[0]:.1f}")
    for k, v in rows.items():
        print(f"{k}: {v:.3f} ms")


if __name__ == "__main__":
    main()
