"""The zoom-in stage: a small AMLNet (task "zoom") on a crop around AMLNet's estimate.

Why: at 128 x 160 the whole-image network sees the robot 5-40 px wide and learns its position
but not its heading (BENCHMARKS.md: the heading outputs stay at the mean predictor), while the
same kind of network learns the heading within minutes from a crop in which the robot fills
the input. The crop is taken where the first estimate puts the robot, at a scale set by its
range, from the full-resolution image (as DeepIM's zoom-in does for refinement).

Geometry (DESIGN.md section 2 frames; camera at height h looking along the robot's x axis):
the crop is centred on the projection of the point (x^, y^, zoom_centre_z_m) of the estimate
(x^, y^) and is zoom_factor * zoom_length_m * fx / x^ pixels wide, resampled to the network's
S x S input. The network regresses, relative to the estimate's range r^ and bearing b^:

    t = (log(r / r^), b - b^, psi - b^)     (angles wrapped)

which are what the crop shows whatever the range (the robot's size in the crop is r^ / r of
its nominal size, its offset from the centre is b - b^, and its look depends on psi - b).
`apply_correction` turns t back into (x, y, psi).

Host side (NumPy + OpenCV, like the data pipeline): `crop_transform`, `zoom_crop`,
`correction_targets`, `apply_correction`, `mirror_average` (test-time mirroring), and
`ZoomSource` (training examples, a pure function of (seed, index)). Pure JAX: the network itself.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.amlnet.config import AMLNetConfig
from rhaml_jax.camera import NOMINAL_HEIGHT_M
from rhaml_jax.crop import MIN_RANGE_M, box_affine, crop_image_host, zoom_box
from rhaml_jax.data import ImageCache
from rhaml_jax.errors import RhamlError
from rhaml_jax.planar import range_bearing, wrap_angle


def _xp(*arrays):
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np

__all__ = ["ZoomJitter", "ZoomSource", "apply_correction", "box", "correction_targets", "crop_transform", "mirror_average",
           "zoom_crop", "MIN_RANGE_M"]

def _range_bearing(xy):
    return range_bearing(xy, min_x=MIN_RANGE_M)


def box(K, guess_xy, cfg: AMLNetConfig, h: float = NOMINAL_HEIGHT_M):
    """(..., 4) the crop box (`rhaml_jax.crop`) for the estimates (..., 2) (x^, y^)."""
    return zoom_box(K, guess_xy, cfg.zoom_length_m, cfg.zoom_factor, cfg.zoom_centre_z_m, h)


def crop_transform(K: np.ndarray, guess_xy, cfg: AMLNetConfig, h: float = NOMINAL_HEIGHT_M) -> np.ndarray:
    """(2, 3) affine map from image pixels to crop pixels for the estimate (x^, y^)."""
    if not np.all(np.isfinite(np.asarray(guess_xy, np.float64)[:2])):
        raise RhamlError(f"zoom crop: the estimate (x, y) = {tuple(np.asarray(guess_xy)[:2])} is not finite")
    S = cfg.input_hw[0]
    return box_affine(box(np.asarray(K, np.float64), np.asarray(guess_xy, np.float64)[:2], cfg, h), S, S)


def zoom_crop(img: np.ndarray, K: np.ndarray, guess_xy, cfg: AMLNetConfig) -> np.ndarray:
    """(H, W, 3) uint8 image taken through K -> (S, S, 3) uint8 crop around the estimate
    (area-averaged when shrinking; the border repeated where the crop leaves the image)."""
    if img.ndim != 3 or img.shape[2] != 3:
        raise RhamlError(f"image: expected (H, W, 3) RGB, got shape {img.shape}")
    if not np.all(np.isfinite(np.asarray(guess_xy, np.float64)[:2])):
        raise RhamlError(f"zoom crop: the estimate (x, y) = {tuple(np.asarray(guess_xy)[:2])} is not finite")
    S = cfg.input_hw[0]
    return crop_image_host(img, box(np.asarray(K, np.float64), np.asarray(guess_xy, np.float64)[:2], cfg), S, S)


def correction_targets(true_xypsi, guess_xy):
    """(..., 3) t = (log r / r^, b - b^, psi - b^) of the true pose against the estimate."""
    xp = _xp(true_xypsi, guess_xy)
    true_xypsi = xp.asarray(true_xypsi, xp.float64 if xp is np else None)
    r, b = _range_bearing(true_xypsi[..., :2])
    rg, bg = _range_bearing(xp.asarray(guess_xy))
    return xp.stack([xp.log(r / rg), wrap_angle(b - bg), wrap_angle(true_xypsi[..., 2] - bg)], -1)


def apply_correction(guess_xy, t):
    """The inverse of `correction_targets`: (x, y, psi) from the estimate and t (..., 3).
    NumPy (float64) or JAX in, the same out."""
    xp = _xp(guess_xy, t)
    t = xp.asarray(t, xp.float64 if xp is np else None)
    rg, bg = _range_bearing(xp.asarray(guess_xy))
    r, b = rg * xp.exp(t[..., 0]), bg + t[..., 1]
    return xp.stack([r * xp.cos(b), r * xp.sin(b), wrap_angle(bg + t[..., 2])], -1)


def mirror_average(t, t_mirrored):
    """(..., 3) corrections from a crop and from the same crop mirrored left-right, averaged.

    Mirroring the crop about its centre column reflects the scene about the vertical plane
    through the camera and the estimate (exactly for an estimate on the optical axis, nearly
    elsewhere), under which log(r / r^) stays and b - b^, psi - b^ change sign. For a
    left-right symmetric robot the mirrored crop is as likely as the original, so the two
    answers are two looks at one pose: positions averaged, headings averaged as unit vectors.
    Measured with the shipped stages (BENCHMARKS.md): ATE 0.31 -> 0.28 on the circle."""
    xp = _xp(t, t_mirrored)
    t = xp.asarray(t, xp.float64 if xp is np else None)
    tm = xp.asarray(t_mirrored, t.dtype) * xp.asarray([1.0, -1.0, -1.0], t.dtype)
    psi = xp.arctan2(xp.sin(t[..., 2]) + xp.sin(tm[..., 2]), xp.cos(t[..., 2]) + xp.cos(tm[..., 2]))
    return xp.stack([(t[..., 0] + tm[..., 0]) / 2, (t[..., 1] + tm[..., 1]) / 2, psi], -1)


@dataclasses.dataclass(frozen=True)
class ZoomJitter:
    """How far a training crop's estimate is from the truth: log-range and bearing errors
    drawn from N(0, sigma^2), clipped at 3 sigma; about AMLNet-cpu's measured errors (median
    range error 8 %, bearing error 1.9 deg) with margin."""

    log_range_sigma: float = 0.12
    bearing_sigma_deg: float = 2.5


class ZoomSource:
    """Training examples of the zoom stage from a BOP set's observed frames: example(i) ->
    (crop, 1.0, t) for image i mod N with the estimate jittered from the truth by a draw that
    is a pure function of (seed, i); `size` = `draws` x N distinct examples.

    Decoded images are kept in memory while they fit in `cache_bytes`."""

    def __init__(self, root: Path, split: str, cfg: AMLNetConfig, seed: int = 0, jitter: ZoomJitter = ZoomJitter(),
                 draws: int = 8, limit: int | None = None, cache_bytes: int = 6 << 30):
        from rhaml_jax.data import read_bop

        if cfg.task != "zoom":
            raise RhamlError(f"config {cfg.name}: the zoom stage needs a config with task='zoom'")
        self.frames = [f for f in read_bop(root, split) if f.observed][:limit]
        if not self.frames:
            raise RhamlError(f"{root}: split {split!r} has no image with the robot in view")
        self.cfg, self.seed, self.jitter = cfg, seed, jitter
        self.size = draws * len(self.frames)
        self._cache = ImageCache(cache_bytes)

    def _image(self, i: int) -> np.ndarray:
        from rhaml_jax.data import load_rgb

        return self._cache.get(i, lambda: load_rgb(self.frames[i].rgb))

    def guess(self, index: int) -> np.ndarray:
        """The jittered estimate (x^, y^) of example `index`."""
        f = self.frames[index % len(self.frames)]
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, index]))
        dr, db = np.clip(rng.normal(size=2), -3, 3) * [self.jitter.log_range_sigma, np.deg2rad(self.jitter.bearing_sigma_deg)]
        r, b = _range_bearing(f.xypsi[:2])
        r, b = r * np.exp(dr), b + db
        return np.array([r * np.cos(b), r * np.sin(b)])

    def example(self, index: int):
        i = index % len(self.frames)
        f = self.frames[i]
        g = self.guess(index)
        crop = zoom_crop(self._image(i), f.K, g, self.cfg)
        return crop, 1.0, correction_targets(f.xypsi, g).astype(np.float32)
