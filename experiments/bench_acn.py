#!/usr/bin/env python3
"""Dense ACN (K = 3, 5, 7) forward and forward + backward at the paper network's stage shapes
(batch 8; branch width C/8 = 12, 24, 48, 96): the im2col form `acn.acn` uses against the form
it replaced (per direction one XLA convolution with the kernels zero-padded to 1 x 7 and
stacked) and against the reference (six lax convolutions, eq. 2 term by term).

    python experiments/bench_acn.py [--runs 7]

Medians of --runs calls after a warm-up; glibc malloc tuned as by the command-line tools.
"""
import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.allocator import tune_allocator  # noqa: E402
from rhaml_jax.amlnet import ops  # noqa: E402
from rhaml_jax.amlnet.acn import _mix_weights, acn, acn_reference, init_acn_params  # noqa: E402
from rhaml_jax.amlnet.bench import median_seconds  # noqa: E402

K = (3, 5, 7)


def acn_stacked_conv(p, x, kernels, dense):
    """The replaced form: one XLA 1 x kmax (kmax x 1) convolution per direction."""
    n, c, kmax = len(kernels), x.shape[-1], max(kernels)
    m = _mix_weights(ops.pointwise(x, p["mix"]), n)
    out = x
    for ui, (u, axis) in enumerate((("x", 2), ("y", 1))):
        w = jnp.concatenate([jnp.pad(p[f"{u}{k}"], ((kmax // 2 - k // 2,) * 2, (0, 0), (0, 0))) for k in kernels], axis=2)
        y = ops.dense_1d_ref(x, w, jnp.concatenate([p[f"b{u}{k}"] for k in kernels]), axis=axis)
        for v in range(n):
            out = out + m[..., ui, v, None] * y[..., v * c : (v + 1) * c]
    return out


def median_ms(f, args, runs):
    jax.block_until_ready(f(*args))  # compile and warm up
    return 1e3 * median_seconds(lambda: f(*args), runs)[0]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    tune_allocator()
    print("| stage (8 x H x W x C/8) | form | forward ms | forward + backward ms |")
    print("| --- | --- | --- | --- |")
    for stage, (hw, c) in enumerate(((56, 12), (28, 24), (14, 48), (7, 96)), 1):
        x = jax.random.normal(jax.random.key(0), (8, hw, hw, c))
        p = init_acn_params(jax.random.key(1), c, K, True)
        ct = jax.random.normal(jax.random.key(2), x.shape)
        for name, f in (("im2col matmul (used)", acn), ("stacked XLA conv (before)", acn_stacked_conv), ("6 lax convs (reference)", acn_reference)):
            fwd = jax.jit(lambda p, x, f=f: f(p, x, K, True))
            grad = jax.jit(jax.grad(lambda p, x, f=f: jnp.sum(f(p, x, K, True) * ct), argnums=(0, 1)))
            print(f"| {stage} (8 x {hw} x {hw} x {c}) | {name} | {median_ms(fwd, (p, x), args.runs):.2f} | {median_ms(grad, (p, x), args.runs):.2f} |", flush=True)


if __name__ == "__main__":
    main()
