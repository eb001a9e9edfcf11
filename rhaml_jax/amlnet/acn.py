"""Anisotropic convolution (ACN), the paper's eqs. (1)-(2).

For a C-channel input X and a kernel set K = {k_1..k_n}:
  omega_p = softmax over the n sizes, per direction, of f(X[p])   (f: 1x1 conv, no bias,
            C -> 2n outputs; the weights are shared across channels, as in AIC-Net)
  out[p]  = X[p] + sum_{u in {x, y}} sum_v omega^u_{p,v} g(X, k_v, phi^u_v)[p]
with g the 1 x k (u = x, along W) or k x 1 (u = y, along H) 'same' convolution with bias,
dense (C -> C, the paper's size) or depthwise.  K = {} is the plain 3x3 depthwise convolution
of InceptionNeXt (no residual, no mixing weights).

Parameters (a plain dict, also the NNX module's layout):
  mix: (C, 2n) with column u * n + v;  x{k}, y{k}: (k, C, C) dense or (k, C) depthwise;
  bx{k}, by{k}: (C,);  for K = {}: w: (3, 3, C), b: (C,).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from rhaml_jax.amlnet import ops
from rhaml_jax.amlnet.init import HostInit

__all__ = ["acn", "acn_reference", "ACN", "init_acn_params"]


def _mix_weights(logits, n: int):
    b, h, w, _ = logits.shape
    return jax.nn.softmax(logits.reshape(b, h, w, 2, n), axis=-1)


def acn(p: dict, x, kernels: tuple[int, ...], dense: bool):
    """Fast ACN (see ops.py for why it is written this way)."""
    if not kernels:
        return ops.depthwise_2d(x, p["w"], p["b"])
    n, c = len(kernels), x.shape[-1]
    if dense:
        # im2col: per direction, the kmax shifted copies of x side by side (B, H, W, kmax C)
        # times ONE (kmax C, n C) matrix holding every kernel, zero-padded to kmax taps.
        # XLA's own convolution (the form before) was as fast forward, but its backward, the
        # weight gradient above all, was 5-7x its forward at C = 12 and 24: as matrix
        # products the gradient takes about half the time at the paper's stage 1
        # (experiments/bench_acn.py; BENCHMARKS.md, AMLNet speed).
        m = _mix_weights(ops.pointwise(x, p["mix"]), n)
        kmax = max(kernels)
        out = x
        for ui, (u, axis) in enumerate((("x", 2), ("y", 1))):
            w = jnp.concatenate([jnp.pad(p[f"{u}{k}"], ((kmax // 2 - k // 2,) * 2, (0, 0), (0, 0))) for k in kernels], axis=2)
            b = jnp.concatenate([p[f"b{u}{k}"] for k in kernels])
            y = ops.pointwise(ops.im2col_1d(x, kmax, axis), w.reshape(kmax * c, n * c), b)
            for v in range(n):
                out = out + m[..., ui, v, None] * y[..., v * c : (v + 1) * c]
        return out
    m = _mix_weights(ops.pointwise(x, p["mix"]), n)
    out = x
    for ui, (u, axis) in enumerate((("x", 2), ("y", 1))):
        for v, k in enumerate(kernels):
            g = ops.depthwise_1d(x, p[f"{u}{k}"], p[f"b{u}{k}"], axis=axis)
            out = out + m[..., ui, v, None] * g
    return out


def acn_reference(p: dict, x, kernels: tuple[int, ...], dense: bool):
    """The same ACN with plain `lax.conv_general_dilated` calls, term by term as in eq. (2)."""
    if not kernels:
        return ops.depthwise_2d_ref(x, p["w"], p["b"])
    n = len(kernels)
    m = _mix_weights(ops.pointwise_ref(x, p["mix"]), n)
    conv = ops.dense_1d_ref if dense else ops.depthwise_1d_ref
    out = x
    for ui, (u, axis) in enumerate((("x", 2), ("y", 1))):
        for v, k in enumerate(kernels):
            out = out + m[..., ui, v, None] * conv(x, p[f"{u}{k}"], p[f"b{u}{k}"], axis=axis)
    return out


def init_acn_params(init: HostInit | jax.Array, c: int, kernels: tuple[int, ...], dense: bool) -> dict:
    """Initial parameters (truncated normal, std 0.02; zero biases); `init` may be a JAX key."""
    init = init if isinstance(init, HostInit) else HostInit(init)
    if not kernels:
        return {"w": init.trunc_normal((3, 3, c))[...], "b": jnp.zeros((c,))}
    p = {"mix": init.trunc_normal((c, 2 * len(kernels)))[...]}
    for u in "xy":
        for k in kernels:
            p[f"{u}{k}"] = init.trunc_normal((k, c, c) if dense else (k, c))[...]
            p[f"b{u}{k}"] = jnp.zeros((c,))
    return p


class ACN(nnx.Module):
    """NNX holder of the ACN parameters; `impl` picks the fast or the reference kernels."""

    def __init__(self, c: int, kernels: tuple[int, ...], dense: bool, *, init: HostInit):
        self.kernels, self.dense = tuple(kernels), bool(dense)
        self.p = nnx.Dict({k: nnx.Param(v) for k, v in init_acn_params(init, c, kernels, dense).items()})

    def params(self) -> dict:
        return {k: v[...] for k, v in self.p.items()}

    def __call__(self, x, impl: str = "fast"):
        f = acn if impl == "fast" else acn_reference
        return f(self.params(), x, self.kernels, self.dense)
