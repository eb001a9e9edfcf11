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
from rhaml_jax.robots._model import PIONEER_LENGTH_M

__all__ = ["MIN_RANGE_M", "min_range_m", "box_affine", "box_around", "crop_image", "crop_image_host", "network_box", "object_box",
           "resample", "zoom_box"]

MIN_RANGE_M = 0.5  # the Pioneer's (0.455 m long) `min_range_m`


def min_range_m(length_m: float) -> float:
    """Estimates nearer than this (or behind the camera) are cropped and corrected as if at this
    range, so that they stay finite: 0.5 m for the 0.455 m Pioneer, in proportion to another
    robot's length (its world is scaled alike: a TurtleBot3's training depths start at 0.39 m)."""
    return MIN_RANGE_M * (length_m / PIONEER_LENGTH_M)


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
    and as tall in metres (x^ clamped to `min_range_m(length_m)`: estimates behind the camera stay finite)."""
    xp = _xp(K, guess_xy)
    K, g = xp.asarray(K), xp.asarray(guess_xy)
    x = xp.maximum(g[..., 0], min_range_m(length_m))
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


# Resampling is separable and sparse: output pixel j of an axis reads T consecutive input pixels
# from start_j (a "tap window"), T fixed by the axis sizes so that shapes stay static under jit.
# T covers every footprint of a box no wider than the image; for a wider box (a robot nearer
# than the crop was sized for) the footprints are cut to T pixels and their weights renormalised,
# a slightly sharper average rather than garbage. Gathers of T pixels cost T / n_in of the
# dense matrix product (measured 20-30x less on this CPU for AMLNet's input and the zoom crops).


def _window(first, n_in: int, taps: int):
    """(n_out, taps) input indices from the first index of each footprint (clipped to the axis)."""
    s = jnp.clip(jnp.floor(first), 0, n_in - taps).astype(jnp.int32)
    return s[:, None] + jnp.arange(taps, dtype=jnp.int32)


def _area(n_small, n_in: int, k, i):
    """INTER_AREA's weight of small pixel k (n_out, 1) on input pixels i (n_out, T), for an
    n_in-pixel axis shrunk to n_small pixels (pixel-border coordinates: input pixel i spans
    [i, i + 1], small pixel k [k / f, (k + 1) / f])."""
    f = n_small / n_in
    i = i.astype(jnp.float32)
    return jnp.clip(jnp.minimum((k + 1) / f, i + 1) - jnp.maximum(k / f, i), 0.0, None) * f


def _linear(q, i, n: int):
    """Linear-interpolation weights at pixel-centre coordinates q (n_out,) on pixels i (n_out, T)
    of an n-pixel axis, the border repeated (OpenCV's BORDER_REPLICATE)."""
    k0 = jnp.floor(q)
    t = (q - k0)[:, None]
    lo = jnp.clip(k0, 0, n - 1).astype(jnp.int32)[:, None]
    hi = jnp.clip(k0 + 1, 0, n - 1).astype(jnp.int32)[:, None]
    return (1 - t) * (i == lo) + t * (i == hi)


def _crop_taps(lo, hi, n_out: int, n_in: int, f=None):
    """(indices, weights) (n_out, T) of `crop_image_host` along one axis for the box edges
    [lo, hi]: with a shrink factor f, an area resize of the whole axis to round(n_in f) pixels,
    then linear interpolation in it; with f None, linear interpolation in the input."""
    taps = min(n_in, 2 * -(-n_in // n_out) + 3)
    c = lo + (jnp.arange(n_out) + 0.5) * (hi - lo) / n_out  # crop pixel centres, input pixel coordinates
    if f is None:
        i = _window(c, n_in, taps)
        return i, _linear(c, i, n_in)
    n_small = jnp.maximum(1.0, jnp.round(n_in * f))
    q = n_small / n_in * (c + 0.5) - 0.5  # ... in the small image's pixel coordinates
    k0 = jnp.floor(q)
    k_lo, k_hi = jnp.clip(k0, 0, n_small - 1), jnp.clip(k0 + 1, 0, n_small - 1)
    i = _window(k_lo * n_in / n_small, n_in, taps)
    t = (q - k0)[:, None]
    return i, (1 - t) * _area(n_small, n_in, k_lo[:, None], i) + t * _area(n_small, n_in, k_hi[:, None], i)


def _area_taps(lo, hi, n_out: int, n_in: int):
    """(indices, weights) (n_out, T) of a one-pass resize of the box edges [lo, hi]: each
    output pixel averages the input over its footprint (OpenCV's INTER_AREA when shrinking;
    when enlarging, a one-pixel footprint, i.e. linear interpolation), the border repeated."""
    taps = min(n_in, -(-n_in // n_out) + 2)
    step = (hi - lo) / n_out
    c = lo + (jnp.arange(n_out) + 0.5) * step
    w = jnp.maximum(step, 1.0)
    a, b = c - 0.5 * w, c + 0.5 * w
    i = _window(a + 0.5, n_in, taps)
    left = jnp.where(i == 0, -jnp.inf, i - 0.5)  # the first and last pixels extend to infinity:
    right = jnp.where(i == n_in - 1, jnp.inf, i + 0.5)  # the border is repeated
    return i, jnp.clip(jnp.minimum(b[:, None], right) - jnp.maximum(a[:, None], left), 0.0, None) / w


def _separable(image, taps_y, taps_x):
    iy, wy = taps_y
    ix, wx = taps_x
    # guard: renormalise footprints cut by the tap window (sum 1 otherwise; never 0: the
    # window always holds the footprint's nearest pixel)
    wy = wy / jnp.maximum(wy.sum(-1, keepdims=True), 1e-12)
    wx = wx / jnp.maximum(wx.sum(-1, keepdims=True), 1e-12)
    H, W, C = image.shape
    # gathers along the leading axis only (whole contiguous rows), the image kept in its dtype
    rows = jnp.einsum("yt,ytk->yk", wy, image.reshape(H, W * C)[iy].astype(jnp.float32))  # (out_h, W C)
    cols = jnp.swapaxes(rows.reshape(-1, W, C), 0, 1).reshape(W, -1)  # (W, out_h C)
    out = jnp.einsum("xt,xtk->xk", wx, cols[ix])  # (out_w, out_h C)
    return jnp.swapaxes(out.reshape(-1, iy.shape[0], C), 0, 1)


def resample(image, box, out_w: int, out_h: int):
    """(H, W, C) image -> (out_h, out_w, C) float32 image of `box` (4,) in one area-filtered
    pass (what `cv2.resize(..., INTER_AREA)` does for the whole image): AMLNet's input. Pure
    JAX and linear in the image; vmap it for a batch."""
    box = jnp.asarray(box, jnp.float32)
    H, W = image.shape[:2]
    return _separable(image, _area_taps(box[1], box[3], out_h, H), _area_taps(box[0], box[2], out_w, W))


def crop_image(image, box, out_w: int, out_h: int):
    """(H, W, C) image -> (out_h, out_w, C) float32 crop of `box` (4,), computed as
    `crop_image_host` does (an area resize by the crop's horizontal scale when it shrinks, then
    linear interpolation), so that networks trained on host crops see the same pixels (up to
    OpenCV's 8-bit rounding). Pure JAX and linear in the image; vmap it for a batch."""
    box = jnp.asarray(box, jnp.float32)
    H, W = image.shape[:2]
    f = out_w / jnp.maximum(box[2] - box[0], 1e-6)  # the host shrinks both axes by the horizontal scale

    def taps(f):
        return _crop_taps(box[1], box[3], out_h, H, f), _crop_taps(box[0], box[2], out_w, W, f)

    ty, tx = jax.tree.map(lambda a, b: jnp.where(f < 1.0, a, b), taps(f), taps(None))
    return _separable(image, ty, tx)


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
