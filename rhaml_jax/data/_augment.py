"""Photometric augmentation for training images, in JAX (jit, on the training device).

Colour jitter (brightness, contrast, saturation, per-channel gain), Gaussian blur, sensor noise
and JPEG-like 8 x 8 block-DCT quantisation artefacts; each applied per image with its own
probability and strength, a pure function of the key.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Strengths (0 disables each): brightness/contrast/saturation/gain are +- fractions;
    blur_prob with sigma up to blur_sigma px; noise sigma up to `noise` (in [0, 1] units);
    jpeg_prob with quantisation step up to `jpeg_step` (DCT units of the [0, 1] image)."""

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


def augment_one(key, img, cfg: AugmentConfig):
    ks = jax.random.split(key, 9)
    u = lambda k, shape=(): jax.random.uniform(k, shape, img.dtype, -1.0, 1.0)  # noqa: E731
    img = img * (1.0 + cfg.brightness * u(ks[0])) * (1.0 + cfg.gain * u(ks[1], (3,)))
    mean = img.mean()
    img = (img - mean) * (1.0 + cfg.contrast * u(ks[2])) + mean
    grey = img.mean(axis=-1, keepdims=True)
    img = (img - grey) * (1.0 + cfg.saturation * u(ks[3])) + grey
    img = jnp.clip(img, 0.0, 1.0)
    sigma = cfg.blur_sigma * jax.random.uniform(ks[4], (), img.dtype)
    img = jnp.where(jax.random.uniform(ks[5]) < cfg.blur_prob, _blur(img, sigma), img)
    step = cfg.jpeg_step * jax.random.uniform(ks[6], (), img.dtype)
    img = jnp.where(jax.random.uniform(ks[7]) < cfg.jpeg_prob, _jpeg_like(img, step), img)
    noise = cfg.noise * jax.random.uniform(ks[8], (), img.dtype)
    img = img + noise * jax.random.normal(jax.random.fold_in(key, 1), img.shape, img.dtype)
    return jnp.clip(img, 0.0, 1.0)


@functools.partial(jax.jit, static_argnames="cfg")
def augment(key: jax.Array, images: jnp.ndarray, cfg: AugmentConfig = AugmentConfig()) -> jnp.ndarray:
    """(B, H, W, 3) float in [0, 1] -> augmented images of the same shape and range."""
    keys = jax.random.split(key, images.shape[0])
    return jax.vmap(augment_one, in_axes=(0, 0, None))(keys, images, cfg)
