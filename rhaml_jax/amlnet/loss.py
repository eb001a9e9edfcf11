"""The AMLNet loss (paper eqs. 3-5) and the decoding of the network's raw head.

L_A = L_o + w_p L_p
L_o = BCE(o, sigmoid(logit))                              over all N samples
L_p = sum_i o_i [(x_i - x^_i)^2 + (y_i - y^_i)^2 + w_psi d_i^2] / max(sum_i o_i, 1)

Negatives (o_i = 0, no robot in view) carry no pose, so they are masked out of L_p and L_p is
the mean over the positives of the batch (eq. 4 with N = the number of positives).  d_i is the
heading error wrapped to (-pi, pi] (eq. 4 on the circle: psi and psi + 2 pi are the same
heading).  With the documented "cossin" head, d_i^2 is replaced by
(cos psi - c^)^2 + (sin psi - s^)^2, which equals d_i^2 to second order.
Defaults w_psi = 3, w_p = 2 (DESIGN.md section 6).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["amlnet_loss", "decode", "wrap_angle"]


def wrap_angle(a):
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))


def decode(out, angle_head: str = "psi") -> dict:
    """Raw head (B, 4|5) -> dict(o probability, x, y, psi) (psi in (-pi, pi])."""
    if angle_head == "cossin":
        psi = jnp.arctan2(out[:, 4], out[:, 3])
    else:
        psi = wrap_angle(out[:, 3])
    return {"o": jax.nn.sigmoid(out[:, 0]), "x": out[:, 1], "y": out[:, 2], "psi": psi}


def amlnet_loss(out, observed, pose, angle_head: str = "psi", w_psi: float = 3.0, w_p: float = 2.0):
    """Returns (L_A, {"loss", "loss_o", "loss_p"}); out: raw head, observed: (B,) in {0, 1},
    pose: (B, 3) = (x, y, psi) (ignored where observed = 0)."""
    logit = out[:, 0]
    loss_o = jnp.mean(jax.nn.softplus(logit) - observed * logit)
    err = jnp.square(out[:, 1] - pose[:, 0]) + jnp.square(out[:, 2] - pose[:, 1])
    if angle_head == "cossin":
        ang = jnp.square(out[:, 3] - jnp.cos(pose[:, 2])) + jnp.square(out[:, 4] - jnp.sin(pose[:, 2]))
    else:
        ang = jnp.square(wrap_angle(out[:, 3] - pose[:, 2]))
    err = err + w_psi * ang
    loss_p = jnp.sum(observed * err) / jnp.maximum(jnp.sum(observed), 1.0)
    loss = loss_o + w_p * loss_p
    return loss, {"loss": loss, "loss_o": loss_o, "loss_p": loss_p}
