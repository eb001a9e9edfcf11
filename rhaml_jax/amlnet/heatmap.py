"""AMLNet's dense head (config head="heatmap"): where the robot is in the image, then how far.

The global head regresses (x, y) from pooled features, so it must learn the camera's geometry
and, from few pixels, everything else; on the v2 images it stayed a metre off (BENCHMARKS.md,
"Retraining on v2 data"). The dense head instead predicts, for every cell of a stride-8 grid
(B, Gh, Gw, 6):

    0  logit that the robot's reference point (`cfg.zoom_centre_z_m` above the ground under its
       origin) projects into this cell (CenterNet's object centre, Zhou et al. 2019)
    1-2  where in the cell, (du, dv) in cells from its top-left corner
    3  log range (m) of the robot's origin
    4-5  (cos, sin) of psi - bearing: the heading as the image shows it (relative to the ray)

Decoding takes the peak cell: its column gives the bearing through the network camera (exact
pinhole geometry, the same for every robot paint), the range head the distance, and
o = sigmoid(peak logit) the detection. Translation-equivariant, so a robot seen in one part of
the image during training is found anywhere.

Targets come from the pose alone (the camera is the network's own, `DEFAULT_CAMERA.resized`,
at the nominal height), so any AMLNet data source trains it unchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.camera import DEFAULT_CAMERA, NOMINAL_HEIGHT_M
from rhaml_jax.planar import range_bearing, wrap_angle

__all__ = ["STRIDE", "CHANNELS", "net_intrinsics", "reference_pixels", "heatmap_loss", "decode_heatmap"]

STRIDE = 8
CHANNELS = 6
HEAT_PRIOR = -4.6  # logit of p = 0.01 at initialisation (CenterNet's focal-loss prior)
LOG_RANGE_OFFSET, LOG_RANGE_SCALE = float(np.log(4.5)), 0.5  # raw 0 = 4.5 m, raw +-1 = x1.65
SIGMA_CELLS = 1.0  # the target Gaussian's width (cells)
W_RANGE = 10.0  # a 10 % range error weighs as much as a whole cell of offset


def net_intrinsics(grid_hw) -> np.ndarray:
    """(3, 3) the network camera of a (Gh, Gw) grid: DEFAULT_CAMERA resized to its input."""
    gh, gw = grid_hw
    with jax.ensure_compile_time_eval():  # a constant of the grid, also inside a trace
        return np.asarray(DEFAULT_CAMERA.resized(gw * STRIDE, gh * STRIDE).K, np.float32)


def reference_pixels(pose, K, centre_z_m: float, h: float = NOMINAL_HEIGHT_M):
    """(B, 2) network-image pixels (u, v) of the robot's reference point for poses (B, 3); x is
    clamped to 0.1 m (guard: a pose behind the camera has no projection; such frames are not
    observed and carry no weight)."""
    x = jnp.maximum(pose[:, 0], 0.1)
    u = K[0, 2] + K[0, 0] * (-pose[:, 1]) / x
    v = K[1, 2] + K[1, 1] * (h - centre_z_m) / x
    return jnp.stack([u, v], -1)


def transform_head(raw):
    """(B, Gh, Gw, 6) raw dense outputs -> (logit, du, dv, log range, cos, sin) in their units."""
    scale = jnp.asarray([1.0, 1.0, 1.0, LOG_RANGE_SCALE, 1.0, 1.0], raw.dtype)
    offset = jnp.asarray([HEAT_PRIOR, 0.5, 0.5, LOG_RANGE_OFFSET, 0.0, 0.0], raw.dtype)
    return raw * scale + offset


def _targets(pose, grid_hw, centre_z_m):
    """Continuous cell coordinates q (B, 2) of the reference point (clamped into the grid: a
    robot cut by the image border peaks at the border), and the range and bearing (B,) (x
    clamped to 0.1 m as in `reference_pixels`)."""
    gh, gw = grid_hw
    K = jnp.asarray(net_intrinsics(grid_hw))
    uv = reference_pixels(pose, K, centre_z_m)
    q = (uv + 0.5) / STRIDE  # pixel centres at integers, cell j spans [j, j + 1)
    q = jnp.clip(q, 0.0, jnp.asarray([gw, gh], q.dtype) - 1e-3)
    return (q, *range_bearing(pose[:, :2], min_x=0.1))


def heatmap_loss(out, observed, pose, centre_z_m: float, w_psi: float = 3.0, w_p: float = 2.0):
    """Returns (loss, parts) like `amlnet_loss`: out (B, Gh, Gw, 6) from the model (transformed
    head), observed (B,), pose (B, 3). loss = L_o (BCE of the peak logit) + focal heat loss +
    w_p L_p, L_p the offset, range and w_psi-weighted heading errors over the cells near the
    target (weighted by the target Gaussian)."""
    B, gh, gw, _ = out.shape
    q, r, bearing = _targets(pose, (gh, gw), centre_z_m)
    jx, jy = jnp.arange(gw, dtype=out.dtype), jnp.arange(gh, dtype=out.dtype)
    cx, cy = jnp.floor(q[:, 0]), jnp.floor(q[:, 1])
    d2 = (jx[None, None, :] + 0.5 - q[:, 0, None, None]) ** 2 + (jy[None, :, None] + 0.5 - q[:, 1, None, None]) ** 2
    Y = jnp.exp(-0.5 * d2 / SIGMA_CELLS**2)
    near_x = jnp.abs(jx[None, None, :] - cx[:, None, None]) <= 1
    near_y = jnp.abs(jy[None, :, None] - cy[:, None, None]) <= 1
    peak = (jx[None, None, :] == cx[:, None, None]) & (jy[None, :, None] == cy[:, None, None])
    obs = observed[:, None, None]
    Y = jnp.where(peak, 1.0, Y) * obs  # negatives: all zero
    logit = out[..., 0]
    # focal loss (CenterNet eq. 1), softplus forms of log p and log(1 - p): no log(0)
    p = jax.nn.sigmoid(logit)
    pos = jnp.where(peak & (obs > 0), (1 - p) ** 2 * jax.nn.softplus(-logit), 0.0)
    neg = jnp.where(peak & (obs > 0), 0.0, (1 - Y) ** 4 * p**2 * jax.nn.softplus(logit))
    n_pos = jnp.maximum(jnp.sum(observed), 1.0)
    loss_heat = (jnp.sum(pos) + jnp.sum(neg)) / n_pos
    top = jnp.max(logit.reshape(B, -1), axis=1)
    loss_o = jnp.mean(jax.nn.softplus(top) - observed * top)
    w = Y * (near_x & near_y)  # regression weights: the target cell and its 8 neighbours
    off_t = jnp.stack(jnp.broadcast_arrays(q[:, 0, None, None] - jx[None, None, :], q[:, 1, None, None] - jy[None, :, None]), -1)
    err_off = jnp.sum(jnp.abs(out[..., 1:3] - off_t), -1)
    err_r = W_RANGE * jnp.abs(out[..., 3] - jnp.log(r)[:, None, None])
    rel = pose[:, 2] - bearing
    ang = (out[..., 4] - jnp.cos(rel)[:, None, None]) ** 2 + (out[..., 5] - jnp.sin(rel)[:, None, None]) ** 2
    wsum = jnp.maximum(jnp.sum(w), 1e-6)
    loss_p = jnp.sum(w * (err_off + err_r + w_psi * ang)) / wsum
    loss_psi = jnp.sum(w * ang) / wsum
    loss = loss_o + loss_heat + w_p * loss_p
    return loss, {"loss": loss, "loss_o": loss_o, "loss_p": loss_p, "loss_psi": loss_psi, "loss_heat": loss_heat}


def decode_heatmap(out) -> dict:
    """(B, Gh, Gw, 6) transformed head -> dict(o, x, y, psi) at the peak cell (as `decode`).
    Differentiable in the peak cell's outputs (the choice of cell is not)."""
    B, gh, gw, C = out.shape
    K = net_intrinsics((gh, gw))
    flat = out.reshape(B, gh * gw, C)
    idx = jnp.argmax(flat[..., 0], axis=1)
    at = jnp.take_along_axis(flat, idx[:, None, None], axis=1)[:, 0]  # (B, 6)
    jx = idx % gw
    u = STRIDE * (jx + at[:, 1]) - 0.5
    bearing = jnp.arctan2(-(u - K[0, 2]) / K[0, 0], 1.0)
    r = jnp.exp(at[:, 3])
    psi = wrap_angle(bearing + jnp.arctan2(at[:, 5], at[:, 4]))
    return {"o": jax.nn.sigmoid(at[:, 0]), "x": r * jnp.cos(bearing), "y": r * jnp.sin(bearing), "psi": psi}
