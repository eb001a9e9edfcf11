"""Training examples of the zoom stage: crops of a BOP set around estimates jittered from the truth."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from rhaml_jax.amlnet.config import AMLNetConfig
from rhaml_jax.crop import min_range_m
from rhaml_jax.data import ImageCache
from rhaml_jax.errors import RhamlError
from rhaml_jax.zoom._correction import _range_bearing, correction_targets, zoom_crop


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
        r, b = _range_bearing(f.xypsi[:2], min_range_m(self.cfg.zoom_length_m))
        r, b = r * np.exp(dr), b + db
        return np.array([r * np.cos(b), r * np.sin(b)])

    def example(self, index: int):
        i = index % len(self.frames)
        f = self.frames[i]
        g = self.guess(index)
        crop = zoom_crop(self._image(i), f.K, g, self.cfg)
        return crop, 1.0, correction_targets(f.xypsi, g, min_range_m(self.cfg.zoom_length_m)).astype(np.float32)


def zoom_batch_sources(root: Path, cfg: AMLNetConfig, batch: int, seed: int = 0):
    """(train, validation) batch functions of the zoom stage over the BOP set `root`: jittered
    crops of its train split (augmented, loaded by two threads: a cold example is a PNG decode
    of ~20 ms, the network step is cheap) and one fixed draw per val image."""
    from rhaml_jax.data import AugmentConfig, make_batch_fn

    train = ZoomSource(root, "train", cfg, seed=seed)
    val = ZoomSource(root, "val", cfg, seed=seed + 10_000, draws=1)
    return (make_batch_fn(train, batch, seed, AugmentConfig(), workers=2),
            make_batch_fn(val, batch, seed + 10_000, None))
