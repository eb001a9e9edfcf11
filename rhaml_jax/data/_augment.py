"""Photometric augmentation for training images, in JAX (jit, on the training device).

Colour jitter (brightness, contrast, saturation, per-channel gain), Gaussian blur, JPEG-like
8 x 8 block-DCT quantisation artefacts and sensor noise, each with its own strength per image;
blur and JPEG on a random fraction of each batch, as many images as their chance times the batch
size. A pure function of the key.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Strengths (0 disables each): brightness/contrast/saturation/gain are +- fractions;
    blur on blur_prob B images of a batch of B (rounded down or up at random), sigma up to
    blur_sigma px; JPEG on jpeg_prob B, quantisation step up to `jpeg_step` (DCT units of the
    [0, 1] image);
    noise standard deviation up to `noise` (in [0, 1] units)."""

    brightness: float = 0.25
    contrast: float = 0.3
    saturation: float = 0.4
    gain: float = 0.1
    blur_prob: float = 0.3
    blur_sigma: float = 1.5
    noise: float = 0.03
    jpeg_prob: float = 0.3
    jpeg_step: float = 0.08


def _dct_matrix(n: int = 8) -> np.ndarray:
    k = np.arange(n)[:, None]
    i = np.arange(n)[None, :]
    m = np.cos(np.pi * (2 * i + 1) * k / (2 * n)) * np.sqrt(2.0 / n)
    m[0] /= np.sqrt(2.0)
    return m.astype(np.float32)  # orthonormal: m @ m.T = I


def _blur(img, sigma):
    """Separable Gaussian blur with a fixed 7-tap kernel of the given sigma: (H, W, 3)."""
    x = jnp.arange(-3, 4, dtype=img.dtype)
    k = jnp.exp(-0.5 * (x / jnp.maximum(sigma, 1e-3)) ** 2)  # guard: sigma 0 -> a delta kernel
    k = k / k.sum()
    pad = jnp.pad(img, ((3, 3), (3, 3), (0, 0)), mode="edge")
    h = sum(k[i] * pad[:, i : i + img.shape[1]] for i in range(7))
    return sum(k[i] * h[i : i + img.shape[0]] for i in range(7))


def _jpeg_like(img, step):
    """Quantises 8 x 8 block DCT coefficients (crops to a multiple of 8, pads back)."""
    H, W, C = img.shape
    h8, w8 = H - H % 8, W - W % 8
    D = jnp.asarray(_dct_matrix())
    blocks = img[:h8, :w8].reshape(h8 // 8, 8, w8 // 8, 8, C).transpose(0, 2, 4, 1, 3)
    coef = D @ blocks @ D.T
    # Higher frequencies get coarser steps, as JPEG's tables do.
    f = jnp.arange(8, dtype=img.dtype)
    q = step * (1.0 + 0.5 * (f[:, None] + f[None, :]))
    coef = jnp.round(coef / q) * q
    out = (D.T @ coef @ D).transpose(0, 3, 1, 4, 2).reshape(h8, w8, C)
    return img.at[:h8, :w8].set(out)


def _colour(key, img, cfg: AugmentConfig):
    """Brightness, per-channel gain, contrast and saturation of one (H, W, 3) image."""
    ks = jax.random.split(key, 4)
    u = lambda k, shape=(): jax.random.uniform(k, shape, img.dtype, -1.0, 1.0)  # noqa: E731
    img = img * (1.0 + cfg.brightness * u(ks[0])) * (1.0 + cfg.gain * u(ks[1], (3,)))
    mean = img.mean()
    img = (img - mean) * (1.0 + cfg.contrast * u(ks[2])) + mean
    grey = img.mean(axis=-1, keepdims=True)
    img = (img - grey) * (1.0 + cfg.saturation * u(ks[3])) + grey
    return jnp.clip(img, 0.0, 1.0)


def _on_some(key, images, prob: float, effect, strength_max: float):
    """`effect(img, strength)` on a random prob B of the B images (round down or up at random, so
    that each image's chance is `prob` for any B), each with strength U(0, strength_max); the
    others unchanged.

    A count per batch (not a coin per image) so that only the chosen images are computed: under
    vmap a per-image choice computes the effect on every image and selects (a third of the
    augmentation's time went to blur and JPEG results thrown away)."""
    images = jnp.asarray(images)
    b = images.shape[0]
    lo, hi = math.floor(prob * b), min(b, math.ceil(prob * b))
    if hi == 0 or strength_max <= 0:
        return images
    kc, ks, ku = jax.random.split(key, 3)
    chosen = jax.random.permutation(kc, b)[:hi]
    strength = strength_max * jax.random.uniform(ks, (hi,), images.dtype)
    # the first `lo` chosen always; the last of `hi` with the chance that makes the mean prob B
    keep = (jnp.arange(hi) < lo) | (jax.random.uniform(ku) < prob * b - lo)
    picked = images[chosen]
    return images.at[chosen].set(jnp.where(keep[:, None, None, None], jax.vmap(effect)(picked, strength), picked))


def _noise(key, images, sigma_max: float):
    """Per-image sensor noise, uniform with standard deviation U(0, sigma_max) per image.

    One random 32-bit word per pixel, its bytes the three channels' noise (256 levels: at
    sigma 0.03 a level is 0.0004): drawing Gaussians took 108 of the 269 ms a batch of 32
    images at 320 x 256 cost, these bits about a third of that."""
    b, h, w, _ = images.shape
    ks, kn = jax.random.split(key)
    sigma = sigma_max * jax.random.uniform(ks, (b, 1, 1, 1), images.dtype)
    bits = jax.random.bits(kn, (b, h, w, 1), jnp.uint32)
    byte = (bits >> jnp.arange(0, 24, 8, dtype=jnp.uint32)) & 0xFF  # (B, H, W, 3)
    unit = (byte.astype(images.dtype) + 0.5) / 256.0 - 0.5  # uniform on (-1/2, 1/2): std 12^-1/2
    return images + sigma * (12.0**0.5) * unit


@functools.partial(jax.jit, static_argnames="cfg")
def augment(key: jax.Array, images: jnp.ndarray, cfg: AugmentConfig = AugmentConfig()) -> jnp.ndarray:
    """(B, H, W, 3) float in [0, 1] -> augmented images of the same shape and range: colour
    jitter on every image, blur on blur_prob B of them and JPEG artefacts on jpeg_prob B, then
    noise on every image."""
    kc, kb, kj, kn = jax.random.split(key, 4)
    images = jax.vmap(_colour, in_axes=(0, 0, None))(jax.random.split(kc, images.shape[0]), images, cfg)
    images = _on_some(kb, images, cfg.blur_prob, _blur, cfg.blur_sigma)
    images = _on_some(kj, images, cfg.jpeg_prob, _jpeg_like, cfg.jpeg_step)
    if cfg.noise > 0:
        images = _noise(kn, images, cfg.noise)
    return jnp.clip(images, 0.0, 1.0)
