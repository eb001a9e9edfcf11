"""Edge residuals r = Log(z^-1 x_i^-1 x_j) on SE(2) and their analytic Jacobians.

Poses are jaxlie SE2 parameter arrays (..., 4) = (cos, sin, x, y) and are perturbed on the
right, x <- x Exp(delta), as in jaxlie. With E = z^-1 x_i^-1 x_j:
    dr/d delta_j = Jr^-1(r)                       (jaxlie's `SE2.jlog`)
    dr/d delta_i = -Jr^-1(r) Adj(x_j^-1 x_i)
The formulas are written out per component (the same maths as jaxlie's SE2.log, jlog, exp and
adjoint, which the tests compare against): XLA compiles a handful of fused elementwise ops
several times faster than the general matrix code, and the solver loop recompiles per graph
size. Small angles use Taylor series behind `jnp.where` with safe denominators, so values
and gradients stay finite at theta = 0.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie

__all__ = ["Linearization", "poses_to_se2", "se2_to_poses", "compose", "inverse", "log", "residuals",
           "linearize", "retract"]


class Linearization(NamedTuple):
    r: jax.Array  # (E, 3) residuals
    J_i: jax.Array  # (E, 3, 3) d r / d delta_i
    J_j: jax.Array  # (E, 3, 3) d r / d delta_j


def poses_to_se2(xyt: jax.Array) -> jaxlie.SE2:
    """(N, 3) (x, y, theta) -> batched jaxlie SE2 (angles need not be wrapped)."""
    return jaxlie.SE2.from_xy_theta(xyt[..., 0], xyt[..., 1], xyt[..., 2])


def se2_to_poses(T: jaxlie.SE2) -> jax.Array:
    """Batched SE2 -> (N, 3) (x, y, theta) with theta in (-pi, pi]."""
    p = T.unit_complex_xy  # (N, 4) cos, sin, x, y
    return jnp.stack([p[..., 2], p[..., 3], jnp.arctan2(p[..., 1], p[..., 0])], axis=-1)


def compose(a: jax.Array, b: jax.Array) -> jax.Array:
    """a b for SE2 parameter arrays (..., 4)."""
    ca, sa, xa, ya = jnp.moveaxis(a, -1, 0)
    cb, sb, xb, yb = jnp.moveaxis(b, -1, 0)
    return jnp.stack([ca * cb - sa * sb, sa * cb + ca * sb, ca * xb - sa * yb + xa, sa * xb + ca * yb + ya], -1)


def inverse(a: jax.Array) -> jax.Array:
    c, s, x, y = jnp.moveaxis(a, -1, 0)
    return jnp.stack([c, -s, -(c * x + s * y), s * x - c * y], -1)


def _half_cot(theta, c, s):
    """a = (theta/2) cot(theta/2) and b = (1 - a) / theta from theta = atan2(s, c), with no
    further transcendental call: cot(theta/2) = s / (1 - c) = (1 + c) / s, whichever has no
    cancellation; Taylor series for |theta| < 1e-2 (safe at 0, |theta| <= pi)."""
    half = 0.5 * theta
    small = jnp.abs(theta) < 1e-2
    pos = c >= 0.0
    num = jnp.where(pos, 1.0 + c, s)
    den = jnp.where(pos, s, 1.0 - c)
    den = jnp.where(small, 1.0, den)
    t2 = theta * theta
    a = jnp.where(small, 1.0 - t2 / 12.0 - t2 * t2 / 720.0, half * num / den)
    safe_theta = jnp.where(small, 1.0, theta)
    b = jnp.where(small, theta / 12.0 + theta * t2 / 720.0, (1.0 - a) / safe_theta)
    return a, b


def log(e: jax.Array) -> jax.Array:
    """SE(2) Log of parameter arrays (..., 4) -> (..., 3) (v_x, v_y, theta)."""
    c, s, x, y = jnp.moveaxis(e, -1, 0)
    theta = jnp.arctan2(s, c)
    a, _ = _half_cot(theta, c, s)
    half = 0.5 * theta
    return jnp.stack([a * x + half * y, -half * x + a * y, theta], -1)


def _edge_errors(T, Z_inv, i, j):
    rel = compose(inverse(T[i]), T[j])  # x_i^-1 x_j
    return compose(Z_inv, rel), rel


def residuals(T: jax.Array, Z_inv: jax.Array, i: jax.Array, j: jax.Array) -> jax.Array:
    """T (N, 4), Z_inv (E, 4) inverse measurements, i, j (E,) -> (E, 3) residuals."""
    return log(_edge_errors(T, Z_inv, i, j)[0])


def linearize(T: jax.Array, Z_inv: jax.Array, i: jax.Array, j: jax.Array) -> Linearization:
    e, rel = _edge_errors(T, Z_inv, i, j)
    c, s, x, y = jnp.moveaxis(e, -1, 0)
    theta = jnp.arctan2(s, c)
    a, b = _half_cot(theta, c, s)
    half = 0.5 * theta
    v0, v1 = a * x + half * y, -half * x + a * y
    r = jnp.stack([v0, v1, theta], -1)
    zero, one = jnp.zeros_like(theta), jnp.ones_like(theta)
    r0, r1 = b * v0 + 0.5 * v1, -0.5 * v0 + b * v1
    Jj = jnp.stack([a, -half, r0, half, a, r1, zero, zero, one], -1).reshape(*theta.shape, 3, 3)
    # Adj(x_j^-1 x_i) = Adj(rel^-1), rel^-1 = (c, -s, -(c x + s y), s x - c y)
    rc, rs, rx, ry = jnp.moveaxis(rel, -1, 0)
    ix, iy = -(rc * rx + rs * ry), rs * rx - rc * ry
    adj = jnp.stack([rc, rs, iy, -rs, rc, -ix, zero, zero, one], -1).reshape(*theta.shape, 3, 3)
    Ji = -(Jj @ adj)
    return Linearization(r, Ji, Jj)


def exp(delta: jax.Array) -> jax.Array:
    """SE(2) Exp of (..., 3) tangents -> parameter arrays (..., 4)."""
    vx, vy, theta = jnp.moveaxis(delta, -1, 0)
    c, s = jnp.cos(theta), jnp.sin(theta)
    small = jnp.abs(theta) < 1e-2
    safe = jnp.where(small, 1.0, theta)
    t2 = theta * theta
    sin_t = jnp.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, s / safe)  # sin(t)/t
    # (1 - cos t)/t = sin^2 t / ((1 + cos t) t): no cancellation, no further sin / cos call
    # (which XLA expands inline: fewer of them compile faster); (1 - cos t)/t next to t = pi
    one_c = 1.0 + c
    far = one_c < 1e-3
    cos_t = jnp.where(small, theta / 2.0 - theta * t2 / 24.0,
                      jnp.where(far, (1.0 - c) / safe, s * s / (jnp.where(far, 1.0, one_c) * safe)))
    return jnp.stack([c, s, sin_t * vx - cos_t * vy, cos_t * vx + sin_t * vy], -1)


def retract(T: jax.Array, delta: jax.Array) -> jax.Array:
    """x Exp(delta) per node: T (N, 4), delta (N, 3); renormalises the unit complex numbers."""
    out = compose(T, exp(delta))
    n = jnp.sqrt(out[..., 0] ** 2 + out[..., 1] ** 2)
    return out.at[..., :2].divide(n[..., None])
