"""Colour constancy for the networks' input: the grey-world white balance.

A light of a colour training never sampled (the held-out set's tinted hemisphere, the OOD
validation look's saturated lamps) shifts every pixel's colour, and with it the luminance the
networks see: a teal robot under green light is nearly as bright as a green floor. The grey
world assumption (the scene's mean reflectance is grey; Buchsbaum 1980) undoes a global tint:
each channel is scaled so that the three channel means are equal, at the image's mean
luminance, so a neutral image is left as it is and a tinted one is moved towards neutral.

    grey_world(images) -> images

Pure and batched (one balance per image), so it jits and differentiates with the rest of IML.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["MAX_GAIN", "grey_world", "grey_world_gains"]

MAX_GAIN = 4.0  # a channel is scaled by at most 4x up or down: a nearly absent channel (a black image,
# a monochrome light) would otherwise be scaled by its noise
_LUMA = (0.299, 0.587, 0.114)  # ITU-R BT.601, as amlnet.model.LUMA


def grey_world_gains(images):
    """(B, 3) per-channel gains of `images` (B, H, W, 3) in [0, 255]: the image's mean luminance
    over each channel's mean, clipped to [1 / MAX_GAIN, MAX_GAIN]."""
    means = jnp.mean(images, axis=(1, 2))  # (B, 3)
    luma = means @ jnp.asarray(_LUMA, images.dtype)  # (B,)
    # guard: a black channel (mean 0) has no defined gain; a floor of one level keeps it finite
    # (and its gradient too) and the clip then caps it at MAX_GAIN
    gains = luma[:, None] / jnp.maximum(means, 1.0)
    return jnp.clip(gains, 1.0 / MAX_GAIN, MAX_GAIN)


def grey_world(images):
    """images (B, H, W, 3) in [0, 255], white balanced per image (grey world), clipped to
    [0, 255]."""
    g = grey_world_gains(images)
    return jnp.clip(images * g[:, None, None, :], 0.0, 255.0)
