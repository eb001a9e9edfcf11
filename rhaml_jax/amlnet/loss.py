"""The AMLNet loss (paper eqs. 3-5) and the decoding of the network's raw head.

L_A = L_o + w_p L_p
L_o = BCE(o, sigmoid(logit))                              over all N samples
L_p = sum_i o_i [w_x (x_i - x^_i)^2 + w_y (y_i - y^_i)^2 + w_psi d_i^2] / max(sum_i o_i, 1)

Negatives (o_i = 0, no robot in view) carry no pose, so they are masked out of L_p and L_p is
the mean over the positives of the batch (eq. 4 with N = the number of positives).  d_i is the
heading error wrapped to (-pi, pi] (eq. 4 on the circle: psi and psi + 2 pi are the same
heading).  With the documented "cossin" head, d_i^2 is replaced by
(cos psi - c^)^2 + (sin psi - s^)^2, which equals d_i^2 to second order; the "axis" head adds
the same for the doubled angle, (cos 2 psi - c2^)^2 + (sin 2 psi - s2^)^2.

Why "axis": a robot that looks nearly the same from the front and from the back (the Pioneer
has sonar arrays at both ends) gives the regression targets psi and psi + pi for nearly the
same image; the least-squares optimum of (cos psi, sin psi) is then (0, 0) whatever the image
shows, and the heading is lost entirely (measured: the shipped flatten/cossin network's
outputs had median length 0.05).  The doubled angle is the same for psi and psi + pi, so the
axis is learned whatever the ambiguity, and the (cos psi, sin psi) outputs only have to lean
towards the right end.
Defaults w_psi = 3, w_p = 2 (DESIGN.md section 6), w_x = w_y = 1 (the paper's eq. 4). The zoom
stage's x, y are its log-range and bearing corrections, whose spreads are 0.12 and 0.044 rad:
with unit weights they count for little against the heading term. The shipped `zoom_cpu` was
trained with their inverse variances, `--w-xy 69.4 526` (BENCHMARKS.md: range error 8.1 -> 3.9 %).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from rhaml_jax.planar import wrap_angle

__all__ = ["amlnet_loss", "decode"]




def decode(out, angle_head: str = "psi") -> dict:
    """Raw head (B, 4|5|7) -> dict(o probability, x, y, psi) (psi in (-pi, pi]); a heatmap
    head's dense map (B, Gh, Gw, 6) is decoded at its peak (`heatmap.decode_heatmap`)."""
    if out.ndim == 4:
        from rhaml_jax.amlnet.heatmap import decode_heatmap

        return decode_heatmap(out)
    if angle_head == "cossin":
        psi = jnp.arctan2(out[:, 4], out[:, 3])
    elif angle_head == "axis":
        # the axis a (psi mod pi) from the doubled angle; of a and a + pi, the one the
        # direction outputs lean to (their sign survives even when their length is small)
        a = 0.5 * jnp.arctan2(out[:, 6], out[:, 5])
        lean = out[:, 3] * jnp.cos(a) + out[:, 4] * jnp.sin(a)
        psi = wrap_angle(jnp.where(lean >= 0, a, a + jnp.pi))
    else:
        psi = wrap_angle(out[:, 3])
    return {"o": jax.nn.sigmoid(out[:, 0]), "x": out[:, 1], "y": out[:, 2], "psi": psi}


def amlnet_loss(out, observed, pose, angle_head: str = "psi", w_psi: float = 3.0, w_p: float = 2.0,
                w_xy: tuple[float, float] = (1.0, 1.0)):
    """Returns (L_A, {"loss", "loss_o", "loss_p", "loss_psi"}); out: raw head, observed: (B,) in {0, 1},
    pose: (B, 3) = (x, y, psi) (ignored where observed = 0); w_xy weighs the x and y terms of
    L_p (the paper: 1, 1)."""
    logit = out[:, 0]
    loss_o = jnp.mean(jax.nn.softplus(logit) - observed * logit)
    err = w_xy[0] * jnp.square(out[:, 1] - pose[:, 0]) + w_xy[1] * jnp.square(out[:, 2] - pose[:, 1])
    if angle_head in ("cossin", "axis"):
        ang = jnp.square(out[:, 3] - jnp.cos(pose[:, 2])) + jnp.square(out[:, 4] - jnp.sin(pose[:, 2]))
        if angle_head == "axis":
            ang = ang + jnp.square(out[:, 5] - jnp.cos(2 * pose[:, 2])) + jnp.square(out[:, 6] - jnp.sin(2 * pose[:, 2]))
    else:
        ang = jnp.square(wrap_angle(out[:, 3] - pose[:, 2]))
    n_pos = jnp.maximum(jnp.sum(observed), 1.0)
    loss_p = jnp.sum(observed * (err + w_psi * ang)) / n_pos
    loss = loss_o + w_p * loss_p
    # loss_psi: the unweighted heading term alone, to tell a heading stuck at the mean
    # predictor (1 for the cossin head, 2 for axis, pi^2/3 for psi) from a slow position term.
    loss_psi = jnp.sum(observed * ang) / n_pos
    return loss, {"loss": loss, "loss_o": loss_o, "loss_p": loss_p, "loss_psi": loss_psi}
