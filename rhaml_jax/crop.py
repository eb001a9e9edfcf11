"""Crops of the full-resolution image: one definition for every stage that zooms in.

A crop is a box `(x0, y0, x1, y1)` in full-image pixel coordinates with its edges at pixel
borders (the whole W x H image is `(-0.5, -0.5, W - 0.5, H - 0.5)`; pixel centres at integers,
DESIGN.md section 2), resampled to `out_w x out_h` pixels. The same box gives

- the crop's intrinsics, `camera.crop_intrinsics(K, box, out_w, out_h)`, which the renderer
  uses for its crop (`render.silhouette(..., box=box)`), so an observed crop and a rendered crop
  of one box line up pixel for pixel;
- the image crop itself: `crop_image` (JAX: jit, vmap and grad) or `crop_image_host` (NumPy +
  OpenCV, the zoom stage's training data, which the shipped zoom network was trained on), which
  compute the same pixels; `resample` is the one-pass area resize of AMLNet's whole-image input.

Boxes come from `zoom_box` (the zoom-in stage: a square set by the estimate's range),
`object_box` (DeepIM's zoom-in: the projected model extents with a margin) and `network_box`
(AMLNet's whole-image input seen through another camera). Resampling is separable (two small
matrix products, fast on any backend), area-filtered when shrinking and linear when enlarging,
with the border repeated outside the image.
"""

from __future__ import annotations

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.camera import NOMINAL_HEIGHT_M
from rhaml_jax.errors import RhamlError

__all__ = ["MIN_RANGE_M", "box_affine", "box_around", "crop_image", "crop_image_host", "network_box", "object_box",
           "resample", "zoom_box"]

MIN_RANGE_M = 0.5  # estimates nearer than this (or behind the camera) are cropped as if at 0.5 m


def _xp(*arrays):
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def box_around(center_uv, size_wh):
    """(..., 4) box of size (w, h) px centred on the image point (u, v) (..., 2)."""
    xp = _xp(center_uv, size_wh)
    c, half = xp.asarray(center_uv), 0.5 * xp.asarray(size_wh)
    return xp.concatenate([c - half, c + half], -1)


def box_affine(box, out_w: int, out_h: int):
    """(..., 2, 3) affine map from full-image pixels to crop pixels (pixel centres at integers):
    u' = (u - x0) out_w / (x1 - x0) - 0.5, as `camera.crop_intrinsics` maps the principal point."""
    xp = _xp(box)
    box = xp.asarray(box)
    sx = out_w / xp.maximum(box[..., 2] - box[..., 0], 1e-6)  # guard: degenerate box -> huge, finite zoom
    sy = out_h / xp.maximum(box[..., 3] - box[..., 1], 1e-6)
    zero = xp.zeros_like(sx)
    row0 = xp.stack([sx, zero, -box[..., 0] * sx - 0.5], -1)
    row1 = xp.stack([zero, sy, -box[..., 1] * sy - 0.5], -1)
    return xp.stack([row0, row1], -2)


def zoom_box(K, guess_xy, length_m: float, factor: float, centre_z_m: float, h: float = NOMINAL_HEIGHT_M):
    """(..., 4) the zoom-in stage's box for planar estimates (..., 2) (x^, y^) in the observer's
    frame: centred on the projection of (x^, y^, centre_z_m), `factor * length_m * fx / x^` px wide
    and as tall in metres (x^ clamped to MIN_RANGE_M: estimates behind the camera stay finite)."""
    xp = _xp(K, guess_xy)
    K, g = xp.asarray(K), xp.asarray(guess_xy)
    x = xp.maximum(g[..., 0], MIN_RANGE_M)
    fx, fy, cx, cy = K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]
    u = cx + fx * (-g[..., 1]) / x  # optical frame of a robot-frame point: (-y, h - z, x)
    v = cy + fy * (h - centre_z_m) / x
    side = factor * length_m * fx / x
    return box_around(xp.stack([u, v], -1), xp.stack([side, side * fy / fx], -1))


def object_box(K, points_cam, margin: float = 1.4, aspect: float = 1.0):
    """(..., 4) DeepIM's zoom-in box: the bounding box of the projected points (..., P, 3) (e.g.
    the model's bounding-box corners in the camera frame), grown to the aspect w / h = `aspect`,
    times `margin`, about its centre. Points at or behind the camera are clamped to 1 cm depth
    (guard: the box stays finite; callers decline such poses, see `refine`)."""
    xp = _xp(K, points_cam)
    K, p = xp.asarray(K), xp.asarray(points_cam)
    z = xp.maximum(p[..., 2], 0.01)
    u = K[..., None, 0, 0] * p[..., 0] / z + K[..., None, 0, 2]
    v = K[..., None, 1, 1] * p[..., 1] / z + K[..., None, 1, 2]
    lo = xp.stack([u.min(-1), v.min(-1)], -1)
    hi = xp.stack([u.max(-1), v.max(-1)], -1)
    w, hgt = hi[..., 0] - lo[..., 0], hi[..., 1] - lo[..., 1]
    side_w = xp.maximum(w, hgt * aspect) * margin
    return box_around(0.5 * (lo + hi), xp.stack([side_w, side_w / aspect], -1))


def network_box(K, image_wh, net_K, net_wh):
    """(4,) the box of an image taken through K that the network's camera (net_K, net_wh) sees;
    for intrinsics without skew the residual homography K K_net^-1 is this axis-aligned box."""
    xp = _xp(K, net_K)
    K, net_K = xp.asarray(K), xp.asarray(net_K)
    w, h = net_wh
    corners = xp.asarray([[-0.5, -0.5], [w - 0.5, h - 0.5]])  # the network image's outer pixel borders
    u = (corners[:, 0] - net_K[0, 2]) / net_K[0, 0] * K[0, 0] + K[0, 2]
    v = (corners[:, 1] - net_K[1, 2]) / net_K[1, 1] * K[1, 1] + K[1, 2]
    return xp.stack([u[0], v[0], u[1], v[1]])


def _area(n_small, n_in: int, k):
    """(..., n_in) INTER_AREA's weights of small pixel k (...,) of an n_in-pixel axis shrunk to
    n_small pixels: the overlap of its footprint with each input pixel, in pixel-border
    coordinates where input pixel i spans [i, i + 1] and small pixel k [k / f, (k + 1) / f]."""
    f = n_small / n_in
    i = jnp.arange(n_in, dtype=jnp.float32)
    a, b = (k / f)[..., None], ((k + 1) / f)[..., None]
    return jnp.clip(jnp.minimum(b, i + 1) - jnp.maximum(a, i), 0.0, None) * f


def _linear(q, n: int):
    """(..., n) linear-interpolation weights at the pixel-centre coordinates q (...,) of an
    n-pixel axis, the border repeated (OpenCV's BORDER_REPLICATE)."""
    k0 = jnp.floor(q)
    t = (q - k0)[..., None]
    i = jnp.arange(n)
    lo, hi = jnp.clip(k0, 0, n - 1).astype(jnp.int32), jnp.clip(k0 + 1, 0, n - 1).astype(jnp.int32)
    return (1 - t) * (i == lo[..., None]) + t * (i == hi[..., None])


def _axis_weights(lo, hi, n_out: int, n_in: int, shrink):
    """(n_out, n_in) weights of `crop_image_host` along one axis for the box edges [lo, hi]:
    when `shrink` = (f,), an area resize of the whole axis by f to round(n_in f) pixels, then
    linear interpolation in it; else linear interpolation in the input."""
    step = (hi - lo) / n_out
    c = lo + (jnp.arange(n_out) + 0.5) * step  # crop pixel centres in input pixel coordinates
    if shrink is None:
        return _linear(c, n_in)
    n_small = jnp.maximum(1.0, jnp.round(n_in * shrink))
    q = n_small / n_in * (c + 0.5) - 0.5  # ... in the small image's pixel coordinates
    k0 = jnp.floor(q)
    t = (q - k0)[:, None]
    k_lo, k_hi = jnp.clip(k0, 0, n_small - 1), jnp.clip(k0 + 1, 0, n_small - 1)
    return (1 - t) * _area(n_small, n_in, k_lo) + t * _area(n_small, n_in, k_hi)


def _area_weights(lo, hi, n_out: int, n_in: int):
    """(n_out, n_in) one-pass resampling weights for the box edges [lo, hi]: each output pixel
    averages the input over its footprint (OpenCV's INTER_AREA when shrinking; when enlarging,
    a one-pixel footprint, i.e. linear interpolation), the border repeated."""
    step = (hi - lo) / n_out
    c = lo + (jnp.arange(n_out) + 0.5) * step
    w = jnp.maximum(step, 1.0)
    a, b = (c - 0.5 * w)[:, None], (c + 0.5 * w)[:, None]
    i = jnp.arange(n_in, dtype=c.dtype)
    left = jnp.where(i == 0, -jnp.inf, i - 0.5)[None]  # the first and last pixels extend to infinity:
    right = jnp.where(i == n_in - 1, jnp.inf, i + 0.5)[None]  # the border is repeated
    return jnp.clip(jnp.minimum(b, right) - jnp.maximum(a, left), 0.0, None) / w


def _separable(image, wy, wx):
    rows = jnp.einsum("yh,hwc->ywc", wy, jnp.asarray(image, jnp.float32))  # rows first: the smaller intermediate
    return jnp.einsum("xw,ywc->yxc", wx, rows)


def resample(image, box, out_w: int, out_h: int):
    """(H, W, C) image -> (out_h, out_w, C) float32 image of `box` (4,) in one area-filtered
    pass (what `cv2.resize(..., INTER_AREA)` does for the whole image): AMLNet's input. Pure
    JAX and linear in the image; vmap it for a batch."""
    box = jnp.asarray(box, jnp.float32)
    H, W = image.shape[:2]
    return _separable(image, _area_weights(box[1], box[3], out_h, H), _area_weights(box[0], box[2], out_w, W))


def crop_image(image, box, out_w: int, out_h: int):
    """(H, W, C) image -> (out_h, out_w, C) float32 crop of `box` (4,), computed as
    `crop_image_host` does (an area resize by the crop's horizontal scale when it shrinks, then
    linear interpolation), so that networks trained on host crops see the same pixels (up to
    OpenCV's 8-bit rounding). Pure JAX and linear in the image; vmap it for a batch."""
    box = jnp.asarray(box, jnp.float32)
    H, W = image.shape[:2]
    f = out_w / jnp.maximum(box[2] - box[0], 1e-6)

    def weights(shrink):
        return (_axis_weights(box[1], box[3], out_h, H, shrink), _axis_weights(box[0], box[2], out_w, W, shrink))

    wy, wx = jax.tree.map(lambda a, b: jnp.where(f < 1.0, a, b), weights(f), weights(None))
    return _separable(image, wy, wx)


def crop_image_host(img: np.ndarray, box, out_w: int, out_h: int) -> np.ndarray:
    """The host (OpenCV) crop of `box`: (H, W, 3) uint8 -> (out_h, out_w, 3) uint8, area-averaged
    when shrinking, the border repeated. What the zoom stage's training crops are made with."""
    if img.ndim != 3 or img.shape[2] != 3:
        raise RhamlError(f"image: expected (H, W, 3) RGB, got shape {img.shape}")
    box = np.asarray(box, np.float64)
    if box.shape != (4,) or not np.all(np.isfinite(box)):
        raise RhamlError(f"crop box: expected 4 finite numbers (x0, y0, x1, y1), got {box.tolist()}")
    A = box_affine(box, out_w, out_h)
    if A[0, 0] < 1.0:  # area filter first, so that a far-range crop does not alias (what INTER_AREA is for)
        f = A[0, 0]
        small = cv2.resize(img, (max(1, round(img.shape[1] * f)), max(1, round(img.shape[0] * f))),
                           interpolation=cv2.INTER_AREA)
        fx_, fy_ = small.shape[1] / img.shape[1], small.shape[0] / img.shape[0]
        # pixel centres: small pixel j covers image pixels around (j + 0.5) / f - 0.5
        to_small = np.array([[fx_, 0.0, 0.5 * fx_ - 0.5], [0.0, fy_, 0.5 * fy_ - 0.5]])
        A = A @ np.linalg.inv(np.vstack([to_small, [0, 0, 1]]))
        img = small
    return cv2.warpAffine(img, A, (out_w, out_h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
