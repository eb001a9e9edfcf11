#!/usr/bin/env python3
"""Matrix-product rates, XLA against PyTorch's CPU GEMM, float32 and bfloat16 (float32
accumulation), at 2048^2 and at the paper network's main training shapes: the forward
product x (M, K) @ w (K, N) and the weight gradient's x^T (K, M) @ g (M, N), which contracts
the long pixel axis M.

  python experiments/matmul_dtypes.py [--runs 7]

Both in this process, 2 threads, medians of --runs calls after a warm-up; prints GMAC/s.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from gemm_floor import _median_call  # noqa: E402
from rhaml_jax.allocator import tune_allocator  # noqa: E402

SHAPES = {  # (M, K, N) of a forward product x (M, K) @ w (K, N)
    "2048^2": (2048, 2048, 2048),
    "stage-3 MLP": (1568, 384, 1536),
    "stage-1 MLP": (25088, 96, 384),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    tune_allocator()
    import torch

    torch.set_num_threads(2)
    for name, (m, k, n) in SHAPES.items():
        for dt in ("float32", "bfloat16"):
            x, w, g = jnp.ones((m, k), dt), jnp.ones((k, n), dt), jnp.ones((m, n), dt)
            tx, tw, tg = (torch.ones(*a.shape, dtype=getattr(torch, dt)) for a in (x, w, g))
            fwd = jax.jit(lambda a, b: jnp.dot(a, b, preferred_element_type=jnp.float32))
            wgrad = jax.jit(lambda a, b: jnp.dot(a.T, b, preferred_element_type=jnp.float32))
            for prod, f, ops, top in (("x w", fwd, (x, w), (tx, tw)), ("x^T g", wgrad, (x, g), (tx.T, tg))):
                tj = _median_call(lambda: f(*ops), args.runs)
                tt = _median_call(lambda: top[0] @ top[1], args.runs)
                print(f"{name:12s} {prod:6s} {m}x{k}x{n} {dt:9s} XLA {m * k * n / tj / 1e9:6.1f}  "
                      f"PyTorch {m * k * n / tt / 1e9:6.1f} GMAC/s")


if __name__ == "__main__":
    main()
