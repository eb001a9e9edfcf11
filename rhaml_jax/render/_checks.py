"""Boundary checks: bad input raises RhamlError naming the argument, never yields NaN.

Checks run on concrete values only; inside a caller's jit/vmap/grad (tracers) they are
skipped, and the traced code itself stays finite for any finite input.
"""

from __future__ import annotations

import jax
import jaxlie
import numpy as np

from rhaml_jax.errors import RhamlError, check_finite


def concrete(x) -> bool:
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def pose_params(T) -> "jax.Array":
    """jaxlie.SE3 (batch axes allowed) -> its (..., 7) wxyz_xyz parameters, checked."""
    if not isinstance(T, jaxlie.SE3):
        raise RhamlError(f"T_cam_model: expected a jaxlie.SE3, got {type(T).__name__}")
    p = T.wxyz_xyz
    if concrete(p):
        check_finite("T_cam_model", p)
    return p


def intrinsics(K) -> "jax.Array":
    if hasattr(K, "K") and not isinstance(K, (np.ndarray, jax.Array)):
        K = K.K  # a rhaml_jax.camera.Camera
    if concrete(K):
        a = np.asarray(K)
        if a.shape != (3, 3):
            raise RhamlError(f"K: expected shape (3, 3), got {a.shape}")
        check_finite("K", a)
        if a[0, 0] <= 0 or a[1, 1] <= 0 or np.any(a[2] != [0, 0, 1]):
            raise RhamlError(f"K: not a pinhole matrix (fx, fy > 0, last row 0 0 1): {a.tolist()}")
    return K


def image_size(width, height) -> tuple[int, int]:
    try:
        w, h = int(width), int(height)
    except (TypeError, ValueError):
        raise RhamlError(f"width, height: expected integers, got {width!r}, {height!r}") from None
    if w <= 0 or h <= 0 or w != width or h != height:
        raise RhamlError(f"width, height: must be positive integers, got {width!r} x {height!r}")
    return w, h


def crop_box(box):
    if box is None or not concrete(box):
        return box
    a = np.asarray(box)
    if a.ndim < 1 or a.shape[-1] != 4:
        raise RhamlError(f"box: expected shape (..., 4) = (x0, y0, x1, y1), got {a.shape}")
    check_finite("box", a)
    if np.any(a[..., 2] <= a[..., 0]) or np.any(a[..., 3] <= a[..., 1]):
        bad = a.reshape(-1, 4)[np.flatnonzero(((a[..., 2] <= a[..., 0]) | (a[..., 3] <= a[..., 1])).ravel())[0]]
        raise RhamlError(f"box: zero-size or inverted crop (need x1 > x0 and y1 > y0), got {bad.tolist()}")
    return box


def positive_scalar(name: str, x):
    if concrete(x):
        a = np.asarray(x)
        if a.shape != () or not np.isfinite(a) or a <= 0:
            raise RhamlError(f"{name}: expected a finite positive scalar, got {x!r}")
    return x
