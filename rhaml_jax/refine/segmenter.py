"""The observed-mask network: a small U-Net that segments the robot in a crop of the camera
image, the target the silhouette alignment matches our render to.

Why its own network: the learned refiner's mask head sees the render at the current pose beside
the image, so its mask leans towards the hypothesis it should judge, and at 16 x 16 it is too
coarse to fix the range (BENCHMARKS.md, "Refinement"). This one sees only the observed crop,
at the alignment's resolution, in luminance by default (a repainted robot has the same
luminance edges more often than the same hues). It decides between the alignment's heading
hypotheses through the robot's outline (the Pioneer's wheels sit 4 cm ahead of its body's
centre, its caster at the back), which repainting does not change.

Crop: `crop.object_box` of the model at an estimate, times a margin; trained with margins drawn
from `SegmenterConfig.margin_range` around initial poses drawn as `refine.train.initial_pose`
(the paper's noise or our IML's errors, flips included), so the same network serves the
alignment's wide coarse pass and its 1.4x fine pass.

Shipped: `segmenter_fine_cpu` (RGB, trained around the residuals a refiner cascade leaves), for
the alignment after the cascade (`refine.SEGMENTER_ALIGN`; BENCHMARKS.md, "A segmenter for the
cascade's end"). Session 10's `segmenter_cpu`, aligned to from the IML's estimates, diverged (its
coarse pass followed a band the network painted along the floor-wall line; BENCHMARKS.md,
"Refinement").

Pure functions over a params pytree: `init_params(cfg, key)`, `apply(cfg, params, crop)`; the
`Segmenter` pytree (params + static cfg) passes through jit / vmap like `refine.Refiner`.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import crop as _crop
from rhaml_jax.errors import RhamlError
from rhaml_jax.refine.net import _conv, _conv_init, config_to_dict, dataclass_from_dict, luminance, mask_loss, named_config
from rhaml_jax.refine.train import CropSource

__all__ = ["SegmenterConfig", "SEGMENTER_CONFIGS", "get_segmenter_config", "Segmenter", "init_params", "apply",
           "observed_mask", "alignment_target", "segmenter_loss", "SegmenterBatch", "SegmenterSource", "segmenter_task", "load_segmenter",
           "export_segmenter"]


@dataclasses.dataclass(frozen=True)
class SegmenterConfig:
    name: str = "segmenter_cpu"
    crop: int = 64
    """input and output side (px): the alignment's crop (`AlignConfig.crop`)"""
    widths: tuple[int, ...] = (24, 48, 96)
    """channels of the stride-2 encoder stages; the decoder mirrors them with skip connections"""
    stem: int = 16
    """channels of the full-resolution stem (kept as the last skip: edges at pixel precision)"""
    luma: bool = True
    """input BT.601 luminance (one channel) instead of RGB"""
    margin_range: tuple[float, float] = (1.3, 2.6)
    """training crop margins (the alignment uses 1.4 and, in its coarse pass, 2.5)"""
    w_dice: float = 0.5
    """weight of the soft-Dice term beside the per-pixel cross-entropy (small robots: few pixels)"""
    starts: str = "coarse"
    """where the training crops are centred (`refine.train.initial_pose`): "coarse", the paper's noise
    or our IML's errors; "fine", the residuals a refiner cascade leaves (the alignment after it)"""

    def __post_init__(self):
        if self.starts not in ("coarse", "fine"):
            raise RhamlError(f"SegmenterConfig.starts {self.starts!r}: expected 'coarse' or 'fine'")


SEGMENTER_CONFIGS = {"segmenter_cpu": SegmenterConfig(),
                     # after the refiner cascade: RGB (one-paint robots of any hue in training), its
                     # 1.4x crop around the cascade's residuals
                     "segmenter_fine_cpu": SegmenterConfig(name="segmenter_fine_cpu", luma=False, margin_range=(1.25, 1.6),
                                                           starts="fine"),
                     "segmenter_micro": SegmenterConfig(name="segmenter_micro", crop=32, widths=(8, 16), stem=8)}


def get_segmenter_config(name: str) -> SegmenterConfig:
    return named_config(SEGMENTER_CONFIGS, name, "segmenter")


def config_from_dict(d: dict) -> SegmenterConfig:
    return dataclass_from_dict(SegmenterConfig, d)


@functools.partial(jax.tree_util.register_dataclass, data_fields=["params"], meta_fields=["cfg"])
@dataclasses.dataclass(frozen=True)
class Segmenter:
    """A trained segmenter: params (pytree leaves) and its static config (pytree metadata)."""

    params: dict
    cfg: SegmenterConfig


# ------------------------------------------------------------------------------ the network


def _in_channels(cfg: SegmenterConfig) -> int:
    return 1 if cfg.luma else 3


def init_params(cfg: SegmenterConfig, key) -> dict:
    n = len(cfg.widths)
    keys = iter(jax.random.split(key, 2 * n + 4))
    stem = [_conv_init(next(keys), 3, _in_channels(cfg), cfg.stem)]
    enc, cin = [], cfg.stem
    for c in cfg.widths:
        enc.append(_conv_init(next(keys), 3, cin, c))
        cin = c
    ctx = _conv_init(next(keys), 3, cin, cin)
    dec, skips = [], [cfg.stem, *cfg.widths[:-1]][::-1]
    for s in skips:  # upsample, concatenate the skip, conv to the skip's width
        dec.append(_conv_init(next(keys), 3, cin + s, s))
        cin = s
    out = {"w": jnp.zeros((1, 1, cin, 1), jnp.float32), "b": jnp.zeros((1,), jnp.float32)}
    return {"stem": stem, "enc": enc, "ctx": ctx, "dec": dec, "out": out}


def _prepare(cfg: SegmenterConfig, crop):
    """(B, S, S, 3) RGB in [0, 1] -> the network's input in [-1, 1]."""
    if cfg.luma:
        crop = luminance(crop)[..., None]
    return crop * 2.0 - 1.0


def apply(cfg: SegmenterConfig, params: dict, crop):
    """crop (B, S, S, 3) RGB in [0, 1] -> mask logits (B, S, S)."""
    h = jax.nn.gelu(_conv(_prepare(cfg, crop), params["stem"][0], 1))
    skips = [h]
    for p in params["enc"]:
        h = jax.nn.gelu(_conv(h, p, 2))
        skips.append(h)
    skips.pop()  # the deepest stage is the decoder's input, not a skip
    h = jax.nn.gelu(_conv(h, params["ctx"], 1))
    for p, s in zip(params["dec"], skips[::-1]):
        B, H, W, C = s.shape
        h = jax.image.resize(h, (B, H, W, h.shape[-1]), "bilinear")
        h = jax.nn.gelu(_conv(jnp.concatenate([h, s], -1), p, 1))
    return _conv(h, params["out"], 1)[..., 0]


def observed_mask(seg: Segmenter, image, box):
    """The robot's mask in [0, 1] (S, S) in `box` (4,) of `image` (H, W, 3) in [0, 1] (jit-able)."""
    S = seg.cfg.crop
    crop = _crop.crop_image(jnp.asarray(image, jnp.float32), box, S, S)
    return jax.nn.sigmoid(apply(seg.cfg, seg.params, crop[None])[0])


def alignment_target(seg: Segmenter, image, box, size: int, threshold: float):
    """The alignment's target (size, size) in {0, 1}: the mask thresholded. A hard target, since
    matching a soft silhouette to a soft probability map rewards rendering nothing where the
    network is unsure (measured: alignments ran off to 10x the range on validation crops)."""
    p = jax.image.resize(observed_mask(seg, image, box), (size, size), "bilinear")
    return (p > threshold).astype(jnp.float32)


def dice_loss(logits, target):
    """(B,) 1 - soft Dice of sigmoid(logits) against target (B, S, S); +1 guards an empty pair."""
    p = jax.nn.sigmoid(logits)
    inter = jnp.sum(p * target, (-2, -1))
    return 1 - (2 * inter + 1) / (jnp.sum(p, (-2, -1)) + jnp.sum(target, (-2, -1)) + 1)


def segmenter_loss(cfg: SegmenterConfig, params, crop, target):
    logits = apply(cfg, params, crop)
    ce = jnp.mean(mask_loss(logits, target))
    dice = jnp.mean(dice_loss(logits, target))
    iou = jnp.mean(_iou(logits > 0, target > 0.5))
    loss = ce + cfg.w_dice * dice
    return loss, {"loss": loss, "loss_ce": ce, "loss_dice": dice, "iou": iou}


def _iou(a, b):
    inter = jnp.sum(a & b, (-2, -1))
    union = jnp.sum(a | b, (-2, -1))
    return jnp.where(union > 0, inter / jnp.maximum(union, 1), 1.0)  # guard: both empty is a perfect match


# ------------------------------------------------------------------------------ training data


class SegmenterBatch(NamedTuple):
    crop: np.ndarray  # (B, S, S, 3) float32 [0, 1] observed crop
    mask: np.ndarray  # (B, S, S) float32 [0, 1] visible mask, cropped (area-averaged) by the same box


class SegmenterSource(CropSource):
    """batch(step) of B crops number step * B ... (step + 1) * B - 1 (a pure function of (seed,
    step)): `refine.train.CropSource` crops with margins drawn from `cfg.margin_range`."""

    cache_bytes = 6 << 30

    def margin(self, rng: np.random.Generator) -> float:
        return rng.uniform(*self.cfg.margin_range)

    def example(self, index: int):
        _, _, _, obs, m = self.drawn(index)
        return obs, m

    def __call__(self, step: int) -> SegmenterBatch:
        ex = [self.example(step * self.batch + j) for j in range(self.batch)]
        return SegmenterBatch(np.stack([e[0] for e in ex]), np.stack([e[1] for e in ex]))


def check_segmenter_batch(cfg: SegmenterConfig, b, size: int, where: str) -> None:
    from rhaml_jax.refine._task import check_fields

    S = cfg.crop
    check_fields(b, {"crop": (size, S, S, 3), "mask": (size, S, S)}, "SegmenterBatch", where)


def segmenter_task(cfg: SegmenterConfig, tc, model, val_source=None, num_devices=None):
    """(the `rhaml_jax.training.Task` of the segmenter, its shardings); `model`: the RobotModel
    whose fingerprint the checkpoints store."""
    from rhaml_jax.refine._task import network_task

    return network_task("segmenter", cfg, tc, model, init_params=init_params, config_to_dict=config_to_dict,
                        config_from_dict=config_from_dict,
                        loss=lambda params, crop, target: segmenter_loss(cfg, params, crop, target), n_fields=2,
                        check_batch=lambda b, size, where: check_segmenter_batch(cfg, b, size, where),
                        val_source=val_source, num_devices=num_devices)


# ------------------------------------------------------------------------------ checkpoints


def load_segmenter(ckpt_dir: str | Path, model=None) -> Segmenter:
    """The segmenter in an Orbax run folder; with `model` (a RobotModel) a checkpoint made for
    another robot is refused (RhamlError)."""
    from rhaml_jax.refine._checkpoint import load_params

    return Segmenter(*load_params(ckpt_dir, "segmenter", model, config_from_dict, init_params))


def export_segmenter(run_dir: str | Path, out_dir: str | Path) -> Path:
    """Writes the latest weights of a segmenter run (no optimizer state) as a checkpoint folder."""
    from rhaml_jax.refine._checkpoint import export_params

    return export_params(run_dir, out_dir, load_segmenter(run_dir).params)
