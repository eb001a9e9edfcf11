"""The trainer's data interface, and a toy source for tests.

A data source is any callable `source(step: int) -> Batch`, a pure function of its own seed
and `step` (so that a resumed run sees exactly the batches an uninterrupted one would).
Real sources (rendered robot images, BOP folders) come from `rhaml_jax.data`.

`ToyRectangles` is NOT training data for the robot: it draws one coloured rectangle whose
column, size and colour encode (x, y, psi) of a fictitious object, for tests and smoke runs of
the trainer only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from rhaml_jax.amlnet.config import ModelConfig
from rhaml_jax.amlnet.functional import check_images
from rhaml_jax.errors import RhamlError

__all__ = ["Batch", "BatchSource", "ToyRectangles", "check_batch"]


class Batch(NamedTuple):
    """One training batch. `pose` is the regression target: for AMLNet the robot's (x, y, psi)
    in the observer's frame; for a zoom network (config task "zoom") not a pose but the
    correction t = (log(r / r^), b - b^, psi - b^) relative to the estimate the crop was taken
    around (`rhaml_jax.zoom.correction_targets`)."""

    images: np.ndarray  # (B, H, W, 3) float32 in [0, 1]
    observed: np.ndarray  # (B,) float32, 1 = robot in view
    pose: np.ndarray  # (B, 3) float32 regression target (see above); any value when unobserved


class BatchSource(Protocol):
    def __call__(self, step: int) -> Batch: ...


def check_batch(cfg: ModelConfig, batch: Batch, size: int, where: str = "batch") -> None:
    """Raises RhamlError naming the field at fault."""
    if not isinstance(batch, tuple) or len(batch) != 3:
        raise RhamlError(f"{where}: expected Batch(images, observed, pose), got {type(batch).__name__}")
    images, observed, pose = batch
    check_images(cfg, images, f"{where}.images")
    if images.shape[0] != size:
        raise RhamlError(f"{where}.images: expected batch size {size}, got {images.shape[0]}")
    if np.shape(observed) != (size,):
        raise RhamlError(f"{where}.observed: expected shape ({size},), got {np.shape(observed)}")
    if np.shape(pose) != (size, 3):
        raise RhamlError(f"{where}.pose: expected shape ({size}, 3), got {np.shape(pose)}")


@dataclass(frozen=True)
class ToyRectangles:
    """Toy batches (tests only): an object at depth x in [2, 7] m, lateral y, heading psi,
    drawn as a rectangle at the pinhole column of (x, y), of size ~ 1/x, coloured by psi, on
    a noisy grey background; a fraction `negatives` of the images holds no object."""

    input_hw: tuple[int, int]
    batch: int
    seed: int = 0
    negatives: float = 0.125

    def __call__(self, step: int) -> Batch:
        rng = np.random.default_rng([self.seed, int(step)])
        h, w = self.input_hw
        b = self.batch
        observed = (rng.random(b) >= self.negatives).astype(np.float32)
        x = rng.uniform(2.0, 7.0, b)
        y = rng.uniform(-0.4, 0.4, b) * x
        psi = rng.uniform(-np.pi, np.pi, b)
        images = 0.4 + 0.05 * rng.standard_normal((b, h, w, 3))
        f = 0.625 * w  # fx = 400 px at 640 px width
        for i in range(b):
            if not observed[i]:
                continue
            u = w / 2 - f * y[i] / x[i]
            v = h / 2 + f * 0.3 / x[i]
            half_w, height = max(1.0, f * 0.23 / x[i]), max(1.0, f * 0.24 / x[i])
            c0, c1 = int(max(0, round(u - half_w))), int(min(w, round(u + half_w) + 1))
            r0, r1 = int(max(0, round(v - height))), int(min(h, round(v) + 1))
            images[i, r0:r1, c0:c1] = (0.5 + 0.5 * np.cos(psi[i]), 0.5 + 0.5 * np.sin(psi[i]), 0.1)
        pose = np.stack([x, y, psi], 1).astype(np.float32)
        return Batch(np.clip(images, 0, 1).astype(np.float32), observed, pose)
