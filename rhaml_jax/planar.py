"""Planar poses (SE(2)) as plain (..., 3) arrays (x, y, psi): the one place for their algebra.

Every package composes robot poses, takes one in another's frame and wraps angles; these are
the definitions they share. Each function takes NumPy or JAX arrays and answers in kind (NumPy
in float64 on the host, e.g. for data generation that must write the same bytes on every run;
JAX under jit, vmap and grad), and broadcasts over leading axes. Angles come out wrapped to
(-pi, pi].

`exp` and `log` are SE(2)'s, in jaxlie's convention (tangent (v_x, v_y, omega)); the pose-graph
solver keeps its own unit-complex parameterisation for speed (`rhaml_jax.pgo`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["wrap_angle", "compose", "between", "inverse", "exp", "log", "range_bearing"]


def _xp(*arrays):
    """jax.numpy if any argument is a JAX array (or tracer), else NumPy."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def wrap_angle(a):
    """Angle(s) wrapped to (-pi, pi]; differentiable everywhere (atan2 of sin, cos)."""
    xp = _xp(a)
    return xp.arctan2(xp.sin(a), xp.cos(a))


def compose(a, b):
    """a * b: pose b, given in a's frame, expressed in a's parent frame."""
    xp = _xp(a, b)
    c, s = xp.cos(a[..., 2]), xp.sin(a[..., 2])
    return xp.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     wrap_angle(a[..., 2] + b[..., 2])], -1)


def between(a, b):
    """a^-1 * b: pose b expressed in a's frame (both given in one parent frame)."""
    xp = _xp(a, b)
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    c, s = xp.cos(a[..., 2]), xp.sin(a[..., 2])
    return xp.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], -1)


def inverse(a):
    """a^-1."""
    xp = _xp(a)
    c, s = xp.cos(a[..., 2]), xp.sin(a[..., 2])
    return xp.stack([-(c * a[..., 0] + s * a[..., 1]), s * a[..., 0] - c * a[..., 1], wrap_angle(-a[..., 2])], -1)


def _v_coefficients(xp, w):
    """sin(w)/w and (1 - cos w)/w of SE(2)'s left Jacobian V, Taylor series near w = 0 (guard:
    the divisions are 0/0 there; the safe denominator keeps values and gradients finite)."""
    small = xp.abs(w) < 1e-3
    ws = xp.where(small, 1.0, w)
    a = xp.where(small, 1.0 - w * w / 6.0, xp.sin(ws) / ws)
    b = xp.where(small, w / 2.0 - w**3 / 24.0, (1.0 - xp.cos(ws)) / ws)
    return a, b


def exp(tau):
    """SE(2) exponential: tangent (..., 3) (v_x, v_y, omega) -> pose (x, y, psi)."""
    xp = _xp(tau)
    vx, vy, w = tau[..., 0], tau[..., 1], tau[..., 2]
    a, b = _v_coefficients(xp, w)
    return xp.stack([a * vx - b * vy, b * vx + a * vy, wrap_angle(w)], -1)


def log(p):
    """SE(2) logarithm: pose (..., 3) -> tangent (v_x, v_y, omega), omega in (-pi, pi]."""
    xp = _xp(p)
    w = wrap_angle(p[..., 2])
    a, b = _v_coefficients(xp, w)
    det = a * a + b * b  # >= (2/pi)^2 for |w| <= pi: V is always invertible
    return xp.stack([(a * p[..., 0] + b * p[..., 1]) / det, (-b * p[..., 0] + a * p[..., 1]) / det, w], -1)


def range_bearing(xy, min_x: float = 0.0):
    """(..., 2) planar points -> (range, bearing) as seen from the origin looking along +x.
    With `min_x` > 0 the forward coordinate is clamped first (points behind or at the camera
    get a finite range and a bearing within (-pi/2, pi/2))."""
    xp = _xp(xy)
    x = xp.maximum(xy[..., 0], min_x) if min_x > 0 else xy[..., 0]
    return xp.hypot(x, xy[..., 1]), xp.arctan2(xy[..., 1], x)
