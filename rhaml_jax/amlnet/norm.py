"""Batch normalisation with explicit running statistics (NNX BatchStat variables).

Training mode normalises with the batch's own mean and (biased) variance over every axis but
the last and updates the running statistics (momentum 0.9, PyTorch's 0.1); inference uses the
running statistics folded into one scale and shift.  Under data parallelism (a batch sharded
over devices inside one jit) the batch mean is the global one, so 1 or N devices agree.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import nnx
from jax import lax

__all__ = ["BatchNorm"]


class BatchNorm(nnx.Module):
    def __init__(self, c: int, momentum: float = 0.9, eps: float = 1e-5):
        self.scale = nnx.Param(jnp.ones((c,)))
        self.bias = nnx.Param(jnp.zeros((c,)))
        self.mean = nnx.BatchStat(jnp.zeros((c,)))
        self.var = nnx.BatchStat(jnp.ones((c,)))
        self.momentum, self.eps = momentum, eps

    def __call__(self, x, train: bool):
        if train:
            axes = tuple(range(x.ndim - 1))
            mean = jnp.mean(x, axes)
            var = jnp.mean(jnp.square(x - mean), axes)
            mo = self.momentum
            self.mean[...] = mo * self.mean[...] + (1 - mo) * lax.stop_gradient(mean)
            self.var[...] = mo * self.var[...] + (1 - mo) * lax.stop_gradient(var)
        else:
            mean, var = self.mean[...], self.var[...]
        inv = self.scale[...] * lax.rsqrt(var + self.eps)
        return x * inv + (self.bias[...] - mean * inv)
