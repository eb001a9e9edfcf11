"""Batch against online robust fusion (`pgo.fuse` / `pgo.fuse_online`) on the same sequences:
accuracy per frame index and milliseconds per update.

    .venv/bin/python experiments/bench_pgo_online.py --out runs/bench_pgo_online.md [--frames 500] [--repeats 1]

Sequences as experiments/bench_pgo_robust.py (seed 0): circle, sine (static observer) and two
moving robots, `--frames` frames, outlier-free and with 40 % flipped + 10 % wrong observations.
Online row k uses only the rendezvous <= k (one `fuse` per row in one compiled `lax.scan`);
batch rows use the whole sequence. Per frame-index bucket: ATE (eq. 12) of the relative pose
over the rendezvous frames in it, online and batch; A_0 T B_0 translation error of the online
estimate at the end of each bucket. Times: median over `--repeats` calls after the compiling
one, float64; ms per update = online wall time / frames. Shared machine: see the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax import pgo  # noqa: E402
from rhaml_jax.metrics import ate  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import timed  # noqa: E402
from bench_pgo_robust import CFG, sequence  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("runs/bench_pgo_online.md"))
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--scenarios", default="circle,sine,two_robots")
    a = ap.parse_args()
    N = a.frames
    edges = [e for e in (0, 10, 50, 100, 250, N) if e <= N]
    buckets = list(zip(edges[:-1], edges[1:]))
    head = " | ".join(f"{lo}-{hi - 1}" for lo, hi in buckets)
    lines = [f"frames {N}, float64, load average {os.getloadavg()[0]:.1f} (shared 2-core machine)", "",
             f"| sequence | outliers | ATE online / batch per frame index: {head} | online A0TB0 cm at bucket ends "
             "| batch A0TB0 cm | batch ms | online ms per update |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for name in a.scenarios.split(","):
        for ff, gf in ((0.0, 0.0), (0.4, 0.1)):
            seq = sequence(name, N, 0, ff, gf)
            rv, valid = jax.tree.map(jnp.asarray, seq.rendezvous), jnp.asarray(seq.valid)
            b, tb = timed(lambda: pgo.fuse_jit(rv, CFG, valid), a.repeats)
            o, to = timed(lambda: pgo.fuse_online_jit(rv, CFG, valid), a.repeats)
            cells, a0 = [], []
            for lo, hi in buckets:
                m = np.zeros(N, bool)
                m[lo:hi] = True
                m &= seq.valid
                if not m.any():
                    cells.append("-")
                else:
                    f = lambda r: float(ate(jnp.asarray(np.asarray(r)[m]), jnp.asarray(seq.true_relative[m])))  # noqa: E731
                    cells.append(f"{f(o.relative):.3f} / {f(b.relative):.3f}")
                d = np.asarray(o.a0_T_b0)[hi - 1] - seq.a0_T_b0
                a0.append(f"{100 * np.hypot(d[0], d[1]):.1f}")
            db = np.asarray(b.a0_T_b0) - seq.a0_T_b0
            row = (f"| {name} | {'none' if ff == 0 else f'{ff:.0%} flips + {gf:.0%} gross'} | {' ; '.join(cells)} | "
                   f"{' ; '.join(a0)} | {100 * np.hypot(db[0], db[1]):.1f} | {1e3 * tb:.0f} | {1e3 * to / N:.1f} |")
            print(row, flush=True)
            lines.append(row)
    text = "\n".join(lines)
    print(text)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
