#!/usr/bin/env python3
"""Forward against forward + backward time of one paper-size AIncep block and its parts.

    python experiments/profile_block_grad.py

At the shapes of the paper's stage 1 (8 x 56 x 56 x 96) and stage 3 (8 x 14 x 14 x 384), times
jitted forward and jitted grad (of sum(out^2) with respect to parameters and input) of: the
whole block (training mode), its token mixer, the ACN branch, one 1 x 11 depthwise branch, the
MLP (two 1 x 1 convolutions with GELU) and the BatchNorm. Calls interleaved over 5 rounds,
medians; glibc malloc tuned as by the command-line tools (rhaml_jax.allocator). A grad /
forward ratio far above 3 points at a backward pass worth writing by hand.
"""
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
from flax import nnx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.allocator import tune_allocator  # noqa: E402
from rhaml_jax.amlnet import ops  # noqa: E402
from rhaml_jax.amlnet.block import AIncepBlock  # noqa: E402
from rhaml_jax.amlnet.config import get_config  # noqa: E402
from rhaml_jax.amlnet.init import HostInit  # noqa: E402

PARTS = ("block", "mixer", "acn", "dw", "mlp", "bn")


def part_fn(gd, rest, part: str, C: int):
    """f(params, x) computing `part` of the block whose graph is (gd, params, rest)."""

    def run(p, x):
        m = nnx.merge(gd, p, rest, copy=True)
        if part == "block":
            return m(x, True)
        if part == "mixer":
            return m.mixer(x)
        if part == "acn":
            return m.mixer.acn(x[..., : C // 8])
        if part == "dw":
            return ops.depthwise_1d(x[..., : C // 8], m.mixer.band_w[...], m.mixer.band_w_b[...], axis=2)
        if part == "mlp":
            return ops.mlp(x, m.fc1[...], m.fc1_b[...], m.fc2[...], m.fc2_b[...])
        return m.norm(x, True)

    return run


def main():
    tune_allocator()
    cfg = get_config("paper")
    for H, C, ratio in ((56, 96, 4), (14, 384, 4)):
        gd, params, rest = nnx.split(AIncepBlock(C, ratio, cfg, init=HostInit(jax.random.key(0))), nnx.Param, ...)
        x = jax.random.normal(jax.random.key(0), (8, H, H, C))
        fs = {}
        for part in PARTS:
            f = part_fn(gd, rest, part, C)
            fs[part, "fwd"] = jax.jit(f)
            fs[part, "grad"] = jax.jit(jax.grad(lambda p, x, f=f: jnp.sum(f(p, x) ** 2), argnums=(0, 1)))
        ts = {k: [] for k in fs}
        for _ in range(5):
            for k, f in fs.items():
                jax.block_until_ready(f(params, x))
                t = time.perf_counter()
                jax.block_until_ready(f(params, x))
                ts[k].append(time.perf_counter() - t)
        print(f"shape 8 x {H} x {H} x {C}")
        for part in PARTS:
            a, b = statistics.median(ts[part, "fwd"]) * 1e3, statistics.median(ts[part, "grad"]) * 1e3
            print(f"  {part:6s} fwd {a:8.2f} ms  grad (fwd + bwd) {b:8.2f} ms  ratio {b / a:5.2f}")


if __name__ == "__main__":
    main()
