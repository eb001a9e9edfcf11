"""Parameter initialisation on the host.

Eager `jax.random` initialisation compiles one threefry kernel per distinct tensor shape
(about a minute for the paper network on this CPU), and jitting the whole initialiser took
minutes to compile.  So initial values are drawn with numpy from a generator seeded by the
explicit JAX key's bits: still a pure function of the key, and instantaneous."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

__all__ = ["HostInit"]


class HostInit:
    def __init__(self, key):
        """`key=None`: shapes only (every tensor zero), for abstract builds."""
        if key is None:
            self.rng = None
        else:
            data = np.asarray(jax.random.key_data(key)).astype(np.uint64).ravel()
            self.rng = np.random.default_rng([int(v) for v in data])

    def trunc_normal(self, shape, std: float = 0.02) -> nnx.Param:
        """N(0, std^2) truncated at +-2 std (InceptionNeXt's trunc_normal_(std=.02))."""
        if self.rng is None:
            return self.zeros(shape)
        x = self.rng.standard_normal(shape)
        bad = np.abs(x) > 2.0
        while bad.any():
            x[bad] = self.rng.standard_normal(int(bad.sum()))
            bad = np.abs(x) > 2.0
        return nnx.Param(jnp.asarray(std * x, jnp.float32))

    def he_normal(self, shape) -> nnx.Param:
        fan_in = int(np.prod(shape[:-1]))
        if self.rng is None:
            return self.zeros(shape)
        return nnx.Param(jnp.asarray(self.rng.standard_normal(shape) * np.sqrt(2.0 / fan_in), jnp.float32))

    @staticmethod
    def zeros(shape) -> nnx.Param:
        return nnx.Param(jnp.zeros(shape, jnp.float32))

    @staticmethod
    def full(shape, value: float) -> nnx.Param:
        return nnx.Param(jnp.full(shape, value, jnp.float32))
