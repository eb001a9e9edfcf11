"""AMLNet (DESIGN.md section 7): stem 4x4/4 + BN; stages of AIncep blocks with BN + conv
2x2/2 downsampling before stages 2-4; global average pooling (or, with pool="flatten", the
whole final grid); FC neck (GELU); linear head, scaled by `scale_head`.

Input: images (B, H, W, 3) float32 in [0, 1] (normalised inside with the ImageNet mean/std;
with luma=True first replaced by their luminance in all three channels).
Output: raw head (B, 4) = (o logit, x, y, psi), or (B, 5) = (o logit, x, y, cos, sin) with
angle_head = "cossin", or (B, 7) = (o logit, x, y, cos, sin, cos 2psi, sin 2psi) with
angle_head = "axis"; with head="heatmap" the dense map (B, H/8, W/8, 6) of `amlnet.heatmap`;
`loss.decode` turns each into (o probability, x, y, psi).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from rhaml_jax.amlnet import heatmap, ops
from rhaml_jax.amlnet.block import AIncepBlock
from rhaml_jax.amlnet.init import HostInit
from rhaml_jax.amlnet.config import AMLNetConfig, num_outputs
from rhaml_jax.amlnet.norm import BatchNorm

__all__ = ["AMLNet", "normalize_images", "scale_head"]

# The head's outputs in metres are offset and scale * raw, with the scenarios' typical
# depth (4.5 m, the middle of 1-8 m) and spread (about 2 m in x and y): the raw outputs are
# then standardised targets of order 1, so neither the first steps nor Adam's per-parameter
# step size are spent on bridging a 4.5 m offset or a factor 2 in scale.
OUT_OFFSET = (0.0, 4.5, 0.0, 0.0, 0.0, 0.0, 0.0)
OUT_SCALE = (1.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0)
# The zoom stage's (log range ratio, bearing correction) have spreads of about 0.15 and
# 0.05 rad (its training jitter, `zoom.ZoomJitter`), and no offset.
ZOOM_OFFSET = (0.0,) * 7
ZOOM_SCALE = (1.0, 0.15, 0.05, 1.0, 1.0, 1.0, 1.0)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
LUMA = (0.299, 0.587, 0.114)  # ITU-R BT.601 luminance weights (config luma=True)


def scale_head(raw, task: str = "localize"):
    """(B, 4|5|7) standardised head -> head in its units (offset + scale * raw): metres for
    AMLNet (OUT_*), the zoom stage's corrections for task "zoom" (ZOOM_*)."""
    n = raw.shape[-1]
    offset, scale = (ZOOM_OFFSET, ZOOM_SCALE) if task == "zoom" else (OUT_OFFSET, OUT_SCALE)
    return raw * jnp.asarray(scale[:n], raw.dtype) + jnp.asarray(offset[:n], raw.dtype)


CHROMA_GAIN = 4.0  # the chroma contrast (at most about 0.7) scaled to the normalised luminance's range


def chroma_contrast(images, window: int):
    """(B, H, W) distance of each pixel's BT.601 chroma (Cb, Cr) of `images` (B, H, W, 3) in [0, 1]
    from its mean over a window x window box (edges: the mean over the pixels inside)."""
    cbcr = images @ jnp.asarray([[-0.168736, 0.5], [-0.331264, -0.418688], [0.5, -0.081312]], images.dtype)
    r = window // 2
    summed = cbcr
    for axis in (1, 2):  # a separable box sum: along rows, then columns
        dims = [1, 1, 1, 1]
        dims[axis] = window
        pad = [(0, 0)] * 4
        pad[axis] = (r, r)
        summed = jax.lax.reduce_window(summed, 0.0, jax.lax.add, tuple(dims), (1, 1, 1, 1), pad)
    H, W = images.shape[1:3]
    inside = lambda n: np.minimum(np.arange(n) + r, n - 1) - np.maximum(np.arange(n) - r, 0) + 1  # noqa: E731
    count = np.outer(inside(H), inside(W)).astype(np.float32)[None, :, :, None]  # host-side: a constant
    d2 = jnp.sum(jnp.square(cbcr - summed / count), -1)
    return jnp.sqrt(d2 + 1e-6)  # guard: sqrt's gradient is infinite at 0 (a flat region)


LOG_FLOOR = 0.02  # about 5 levels of 8 bits: below it the ratio of two pixels is camera noise and JPEG
LOG_OFFSET = 1.5  # log(luma + floor), in [-3.9, 0.02], moved onto the normalised luminance's range


def log_luminance(luma):
    """(B, H, W) log of the luminance `luma` (B, H, W) in [0, 1], floored and offset: equal
    brightness ratios give equal differences, in the dark as in the light."""
    return jnp.log(luma + LOG_FLOOR) + LOG_OFFSET


def normalize_images(images):
    return (images - jnp.asarray(IMAGENET_MEAN, images.dtype)) / jnp.asarray(IMAGENET_STD, images.dtype)


class Linear(nnx.Module):
    def __init__(self, a: int, b: int, *, init: HostInit):
        self.w = init.trunc_normal((a, b))
        self.b = init.zeros((b,))

    def __call__(self, x):
        return x @ self.w[...] + self.b[...]


class AMLNet(nnx.Module):
    def __init__(self, cfg: AMLNetConfig, *, init: HostInit):
        self.cfg = cfg
        d0 = cfg.dims[0]
        self.stem = init.trunc_normal((4, 4, 3, d0))
        self.stem_b = init.zeros((d0,))
        self.stem_norm = BatchNorm(d0)
        downs, stages = [], []
        for i, (depth, c, r) in enumerate(zip(cfg.depths, cfg.dims, cfg.mlp_ratios)):
            if i:
                prev = cfg.dims[i - 1]
                downs.append(nnx.Dict(norm=BatchNorm(prev), w=init.trunc_normal((2, 2, prev, c)), b=init.zeros((c,))))
            stages.append(nnx.List([AIncepBlock(c, r, cfg, init=init) for _ in range(depth)]))
        self.downs = nnx.List(downs)
        self.stages = nnx.List(stages)
        if cfg.head == "heatmap":
            # stride-8 features, the last stage upsampled onto them, and the cell's normalised
            # (u, v) (so the range can also use where on the floor the robot stands)
            width = cfg.dims[1] + cfg.dims[-1] + 2
            self.neck = nnx.List([Linear(width, cfg.dims[1], init=init)])
            self.head = Linear(cfg.dims[1], heatmap.CHANNELS, init=init)
            return
        gh, gw = cfg.final_grid
        widths = (cfg.dims[-1] * (gh * gw if cfg.pool == "flatten" else 1),) + tuple(cfg.neck)
        self.neck = nnx.List([Linear(a, b, init=init) for a, b in zip(widths[:-1], widths[1:])])
        self.head = Linear(widths[-1], num_outputs(cfg), init=init)

    def stage_outputs(self, images, train: bool = False, key=None, impl: str = "fast") -> list:
        """[(B, H / 4 / 2^i, W / 4 / 2^i, dims[i]) for each stage i]."""
        patch = ops.patchify if impl == "fast" else ops.patchify_ref
        x = images
        if self.cfg.luma:
            luma = images @ jnp.asarray(LUMA, images.dtype)
            x = normalize_images(jnp.repeat(luma[..., None], 3, axis=-1))
            if self.cfg.log_luma:
                x = x.at[..., 1].set(log_luminance(luma))
            if self.cfg.chroma:
                x = x.at[..., 2].set(CHROMA_GAIN * chroma_contrast(images, self.cfg.chroma_window))
        else:
            x = normalize_images(x)
        x = self.stem_norm(patch(x, self.stem[...], self.stem_b[...]), train)
        n, outs = 0, []
        for i, stage in enumerate(self.stages):
            if i:
                d = self.downs[i - 1]
                x = patch(d["norm"](x, train), d["w"][...], d["b"][...])
            for blk in stage:
                k = None if key is None else jax.random.fold_in(key, n)
                x = blk(x, train, k, impl)
                n += 1
            outs.append(x)
        return outs

    def features(self, images, train: bool = False, key=None, impl: str = "fast"):
        x = self.stage_outputs(images, train, key, impl)[-1]
        if self.cfg.pool == "flatten":
            return x.reshape(x.shape[0], -1)
        return jnp.mean(x, axis=(1, 2))

    def __call__(self, images, train: bool = False, key=None, impl: str = "fast"):
        act = ops.gelu if impl == "fast" else ops.gelu_ref
        if self.cfg.head == "heatmap":
            outs = self.stage_outputs(images, train, key, impl)
            f8, top = outs[1], outs[-1]
            up = 2 ** (len(outs) - 2)
            top = jnp.repeat(jnp.repeat(top, up, axis=1), up, axis=2)
            B, gh, gw, _ = f8.shape
            v, u = jnp.meshgrid((jnp.arange(gh) + 0.5) / gh * 2 - 1, (jnp.arange(gw) + 0.5) / gw * 2 - 1, indexing="ij")
            coords = jnp.broadcast_to(jnp.stack([u, v], -1).astype(f8.dtype), (B, gh, gw, 2))
            h = act(self.neck[0](jnp.concatenate([f8, top, coords], -1)))
            return heatmap.transform_head(self.head(h))
        h = self.features(images, train, key, impl)
        for fc in self.neck:
            h = act(fc(h))
        return scale_head(self.head(h), self.cfg.task)
