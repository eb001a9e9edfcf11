"""Robust kernels on the squared Mahalanobis norm s2 = r^T Lambda r (IRLS weights).

Each kernel returns rho(s2) with cost = 0.5 * sum rho (so "none" is GTSAM's 0.5 r^T Lambda r,
"huber" is GTSAM's Huber: s^2/2 inside k, k s - k^2/2 outside, "cauchy" is
k^2/2 log(1 + s^2/k^2)) and the weight w = d rho / d s2 used in the normal equations.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["robust_rho_and_weight"]


def robust_rho_and_weight(s2: jax.Array, kernel: str, delta: float) -> tuple[jax.Array, jax.Array]:
    """s2: (E,) squared Mahalanobis norms -> (rho (E,), weight (E,))."""
    if kernel == "none":
        return s2, jnp.ones_like(s2)
    k = jnp.asarray(delta, s2.dtype)
    if kernel == "huber":
        inside = s2 <= k * k
        s = jnp.sqrt(jnp.where(inside, k * k, s2))  # safe: never sqrt(0) on the used branch
        rho = jnp.where(inside, s2, 2.0 * k * s - k * k)
        w = jnp.where(inside, 1.0, k / s)
        return rho, w
    if kernel == "cauchy":
        q = s2 / (k * k)
        return k * k * jnp.log1p(q), 1.0 / (1.0 + q)
    raise ValueError(f"robust kernel: unknown {kernel!r} (none, huber, cauchy)")
