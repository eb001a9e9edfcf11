"""Training input: batches as a pure function of (seed, step), from disk or generated on the fly.

`make_batch_fn(source, batch, seed)` returns `batch_fn(step) -> Batch`; the same step always
gives the same batch, so a resumed run sees exactly the data an uninterrupted run would.
A background thread prepares the next steps while the current one trains.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
from pathlib import Path
from typing import NamedTuple, Protocol

import cv2
import jax
import numpy as np

from rhaml_jax.camera import DEFAULT_CAMERA, resize_intrinsics
from rhaml_jax.data._augment import AugmentConfig, augment
from rhaml_jax.data._bop import read_bop, load_rgb
from rhaml_jax.data._cache import ImageCache
from rhaml_jax.data._synth import SynthConfig, training_sample
from rhaml_jax.errors import RhamlError


class Batch(NamedTuple):
    images: np.ndarray  # (B, H, W, 3) float32 in [0, 1]
    observed: np.ndarray  # (B,) float32, 1 when the robot is in view
    pose: np.ndarray  # (B, 3) float32 (x, y, psi) in the observer's frame, zeros for negatives


class Source(Protocol):
    """Examples by index: `len(source)` of them (or unbounded: None), each (image, observed, pose)."""

    size: int | None

    def example(self, index: int) -> tuple[np.ndarray, float, np.ndarray]: ...


@dataclasses.dataclass
class OnTheFly:
    """Renders example `index` of the infinite synthetic stream `seed` at width x height.

    `supersample` renders at that many times the size and downsamples (area filter), as the
    full-resolution camera image is downsampled to the network's input at evaluation.
    """

    robot: str
    width: int
    height: int
    seed: int = 0
    cfg: SynthConfig = SynthConfig()
    max_faces: int | None = None
    supersample: int = 1
    size: int | None = None

    def __post_init__(self):
        from rhaml_jax.render import as_mesh
        from rhaml_jax.robots import load_robot

        self._mesh = as_mesh(load_robot(self.robot, self.max_faces))
        self._camera = DEFAULT_CAMERA.resized(self.width * self.supersample, self.height * self.supersample)

    def example(self, index: int):
        s = training_sample(self._mesh, self._camera, self.seed, index, cfg=self.cfg)
        img = s.rgb
        if self.supersample > 1:
            img = cv2.resize(img, (self.width, self.height), interpolation=cv2.INTER_AREA)
        return img, float(s.observed), s.xypsi.astype(np.float32)


@dataclasses.dataclass
class FromDisk:
    """Examples of a BOP data set's `split` at width x height through the network's camera
    (any image size and intrinsics on disk, see `network_image`).

    Images are kept in memory at the network's size once decoded, while they fit in
    `cache_bytes` (18 k images at 128 x 160 take 1.1 GB): decoding and resampling a PNG took
    20 ms, about a third of a `cpu` training step's time per image."""

    root: Path
    width: int
    height: int
    split: str | None = "train"
    cache_bytes: int = 4 << 30

    def __post_init__(self):
        self._frames = read_bop(self.root, self.split)
        self.size = len(self._frames)
        if self.size == 0:
            raise RhamlError(f"{self.root}: split {self.split!r} has no images")
        self._cache = ImageCache(self.cache_bytes)

    def example(self, index: int):
        f = self._frames[index]
        img = self._cache.get(index, lambda: network_image(load_rgb(f.rgb), f.K, (self.height, self.width)))
        pose = f.xypsi
        return img, float(f.observed), (np.zeros(3, np.float32) if pose is None else pose.astype(np.float32))


def network_image(img: np.ndarray, K: np.ndarray, input_hw: tuple[int, int]) -> np.ndarray:
    """An (H, W, 3) uint8 image taken through intrinsics K, as the network's camera sees it:
    DEFAULT_CAMERA resized to input_hw (the camera every training image is rendered with).

    Resized with an area filter (what the training images went through); when K, resized,
    differs from the network's camera (another tool's data, another lens), the residual
    homography K_net K^-1 is applied too, so pixel columns keep meaning the same bearing.
    The camera's mounting (height, pitch) is not changed: it must be the one of DESIGN.md."""
    h, w = input_hw
    if img.ndim != 3 or img.shape[2] != 3:
        raise RhamlError(f"image: expected (H, W, 3) RGB, got shape {img.shape}")
    K_net = DEFAULT_CAMERA.resized(w, h).K
    K_img = np.asarray(resize_intrinsics(K, (img.shape[1], img.shape[0]), (w, h)))
    if img.shape[:2] != (h, w):
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    if not np.allclose(K_img, K_net, rtol=1e-6, atol=1e-6 * max(w, h)):
        H = K_net @ np.linalg.inv(K_img)
        img = cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return img


def indices_for_step(step: int, batch: int, size: int | None, seed: int) -> np.ndarray:
    """Example indices of a step: a fresh permutation per epoch of a finite source."""
    flat = np.arange(step * batch, (step + 1) * batch)
    if size is None:
        return flat
    epoch, pos = flat // size, flat % size
    out = np.empty(batch, np.int64)
    for e in np.unique(epoch):
        perm = np.random.default_rng(np.random.SeedSequence([seed, int(e)])).permutation(size)
        out[epoch == e] = perm[pos[epoch == e]]
    return out


def make_batch_fn(source: Source, batch: int, seed: int = 0, augment_cfg: AugmentConfig | None = AugmentConfig(),
                  prefetch: int = 2, workers: int = 1):
    """batch_fn(step) -> Batch, deterministic in (seed, step); prefetches the next steps."""
    if batch <= 0:
        raise RhamlError(f"--batch must be positive, got {batch}")
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=max(1, workers))
    pending: dict[int, concurrent.futures.Future] = {}

    def build(step: int) -> Batch:
        idx = indices_for_step(step, batch, source.size, seed)
        ex = [source.example(int(i)) for i in idx]
        images = np.stack([e[0] for e in ex]).astype(np.float32) / 255.0
        if augment_cfg is not None:
            key = jax.random.fold_in(jax.random.PRNGKey(seed), step)
            images = np.asarray(augment(key, images, augment_cfg))
        return Batch(images, np.array([e[1] for e in ex], np.float32), np.stack([e[2] for e in ex]).astype(np.float32))

    def batch_fn(step: int) -> Batch:
        fut = pending.pop(step, None)
        for s in range(step + 1, step + 1 + prefetch):
            if s not in pending:
                pending[s] = pool.submit(build, s)
        for s in [s for s in pending if s < step]:
            pending.pop(s).cancel()
        return fut.result() if fut is not None else build(step)

    return batch_fn


def amlnet_batch_source(input_hw: tuple[int, int], batch: int, seed: int, robot: str, data_dir: Path | None,
                        split: str = "train"):
    """The AMLNet trainer's data: batch_fn(step) at the network's input (H, W).

    From the BOP set `data_dir` (its `split`), or generated on the fly (2x supersampled) when
    None. Training batches are augmented; validation batches are not.
    """
    h, w = input_hw
    if data_dir is None:
        source = OnTheFly(robot, w, h, seed=seed, supersample=2)
    else:
        source = FromDisk(Path(data_dir), w, h, split)
    return make_batch_fn(source, batch, seed, augment_cfg=AugmentConfig() if split == "train" else None)
