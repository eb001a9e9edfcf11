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

import cv2
import numpy as np

from rhaml_jax.amlnet.config import AMLNetConfig
from rhaml_jax.camera import NOMINAL_HEIGHT_M
from rhaml_jax.data._cache import ImageCache
from rhaml_jax.errors import RhamlError

__all__ = ["ZoomJitter", "ZoomSource", "apply_correction", "correction_targets", "crop_transform", "mirror_average",
           "zoom_crop", "MIN_RANGE_M"]

MIN_RANGE_M = 0.5  # estimates nearer than this (or behind the camera) are cropped as if at 0.5 m


def _range_bearing(xy) -> tuple[np.ndarray, np.ndarray]:
    xy = np.asarray(xy, np.float64)
    x = np.maximum(xy[..., 0], MIN_RANGE_M)
    return np.hypot(x, xy[..., 1]), np.arctan2(xy[..., 1], x)


def _wrap(a):
    return np.arctan2(np.sin(a), np.cos(a))


def crop_transform(K: np.ndarray, guess_xy, cfg: AMLNetConfig, h: float = NOMINAL_HEIGHT_M) -> np.ndarray:
    """(2, 3) affine map from image pixels to crop pixels for the estimate (x^, y^)."""
    if not np.all(np.isfinite(np.asarray(guess_xy, np.float64)[:2])):
        raise RhamlError(f"zoom crop: the estimate (x, y) = {tuple(np.asarray(guess_xy)[:2])} is not finite")
    x, y = float(max(guess_xy[0], MIN_RANGE_M)), float(guess_xy[1])
    u = K[0, 2] + K[0, 0] * (-y) / x  # optical frame: (-y, h - z, x)
    v = K[1, 2] + K[1, 1] * (h - cfg.zoom_centre_z_m) / x
    side = cfg.zoom_factor * cfg.zoom_length_m * K[0, 0] / x
    S = cfg.input_hw[0]
    s = S / side
    # pixel centres at integer coordinates: crop pixel (S - 1) / 2 is the image point (u, v)
    sv = s * K[0, 0] / K[1, 1]  # the same metric scale vertically (fy may differ from fx)
    return np.array([[s, 0.0, (S - 1) / 2 - s * u], [0.0, sv, (S - 1) / 2 - sv * v]])


def zoom_crop(img: np.ndarray, K: np.ndarray, guess_xy, cfg: AMLNetConfig) -> np.ndarray:
    """(H, W, 3) uint8 image taken through K -> (S, S, 3) uint8 crop around the estimate
    (area-averaged when shrinking; the border repeated where the crop leaves the image)."""
    if img.ndim != 3 or img.shape[2] != 3:
        raise RhamlError(f"image: expected (H, W, 3) RGB, got shape {img.shape}")
    A = crop_transform(K, guess_xy, cfg)
    S = cfg.input_hw[0]
    shrink = A[0, 0] < 1.0
    if shrink:  # area filter first, so that a far-range crop does not alias (what INTER_AREA is for)
        f = A[0, 0]
        small = cv2.resize(img, (max(1, round(img.shape[1] * f)), max(1, round(img.shape[0] * f))),
                           interpolation=cv2.INTER_AREA)
        fx_, fy_ = small.shape[1] / img.shape[1], small.shape[0] / img.shape[0]
        # pixel centres: small pixel j covers image pixels around (j + 0.5) / f - 0.5
        to_small = np.array([[fx_, 0.0, 0.5 * fx_ - 0.5], [0.0, fy_, 0.5 * fy_ - 0.5]])
        A = A @ np.linalg.inv(np.vstack([to_small, [0, 0, 1]]))
        img = small
    return cv2.warpAffine(img, A, (S, S), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def correction_targets(true_xypsi, guess_xy) -> np.ndarray:
    """(..., 3) t = (log r / r^, b - b^, psi - b^) of the true pose against the estimate."""
    true_xypsi = np.asarray(true_xypsi, np.float64)
    r, b = _range_bearing(true_xypsi[..., :2])
    rg, bg = _range_bearing(guess_xy)
    return np.stack([np.log(r / rg), _wrap(b - bg), _wrap(true_xypsi[..., 2] - bg)], -1)


def apply_correction(guess_xy, t) -> np.ndarray:
    """The inverse of `correction_targets`: (x, y, psi) from the estimate and t (..., 3)."""
    t = np.asarray(t, np.float64)
    rg, bg = _range_bearing(guess_xy)
    r, b = rg * np.exp(t[..., 0]), bg + t[..., 1]
    return np.stack([r * np.cos(b), r * np.sin(b), _wrap(bg + t[..., 2])], -1)


def mirror_average(t, t_mirrored) -> np.ndarray:
    """(..., 3) corrections from a crop and from the same crop mirrored left-right, averaged.

    Mirroring the crop about its centre column reflects the scene about the vertical plane
    through the camera and the estimate (exactly for an estimate on the optical axis, nearly
    elsewhere), under which log(r / r^) stays and b - b^, psi - b^ change sign. For a
    left-right symmetric robot the mirrored crop is as likely as the original, so the two
    answers are two looks at one pose: positions averaged, headings averaged as unit vectors.
    Measured with the shipped stages (BENCHMARKS.md): ATE 0.31 -> 0.28 on the circle."""
    t = np.asarray(t, np.float64)
    tm = np.asarray(t_mirrored, np.float64) * np.array([1.0, -1.0, -1.0])
    psi = np.arctan2(np.sin(t[..., 2]) + np.sin(tm[..., 2]), np.cos(t[..., 2]) + np.cos(tm[..., 2]))
    return np.stack([(t[..., 0] + tm[..., 0]) / 2, (t[..., 1] + tm[..., 1]) / 2, psi], -1)


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
