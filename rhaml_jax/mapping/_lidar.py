"""Simulated 2D lidar and log-odds occupancy grid mapping, vectorised in JAX.

`cast_rays` intersects every beam of every scan with every wall segment at once (no loop);
`integrate_scans` adds scans to a log-odds grid with `lax.scan`, each scan's free and hit cells
found for all beams and all samples along them at once. Pure functions; the grid's geometry
(`GridSpec`) is static.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.mapping._mapfile import OccupancyMap

__all__ = ["LidarConfig", "GridSpec", "cast_rays", "beam_angles", "integrate_scans", "occupancy_from_log_odds",
           "empty_log_odds"]


@dataclasses.dataclass(frozen=True)
class LidarConfig:
    """A planar lidar on the robot's base (beams evenly over 360 deg) and its inverse sensor model."""

    beams: int = 360
    max_range: float = 3.5  # m; a beam that hits nothing reports max_range (no hit)
    range_sigma: float = 0.01  # m, Gaussian range noise
    l_occ: float = 1.2  # log-odds added at a beam's end cell
    l_free: float = -0.6  # log-odds added along a beam, before its end cell
    l_min: float = -4.0  # clamp (keeps the grid able to change its mind)
    l_max: float = 4.0


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """An axis-aligned grid in a map frame: origin (x, y) of cell (0, 0)'s corner, size, resolution."""

    x0: float
    y0: float
    width: int  # cells along x
    height: int  # cells along y
    resolution: float


def beam_angles(cfg: LidarConfig) -> np.ndarray:
    """(beams,) beam directions in the robot frame (rad)."""
    return np.linspace(-np.pi, np.pi, cfg.beams, endpoint=False)


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


@jax.jit
def cast_rays(segments: jax.Array, origins: jax.Array, directions: jax.Array, max_range: float) -> jax.Array:
    """Ranges (N, B) of rays from origins (N, 2) along unit directions (N, B, 2) to the nearest
    of segments (S, 2, 2); max_range where a ray hits nothing closer.

    Ray p + t d meets segment a + u (b - a) where t = (q x e) / (d x e), u = (q x d) / (d x e),
    q = a - p, e = b - a; it counts when t > 0 and 0 <= u <= 1."""
    a, e = segments[:, 0], segments[:, 1] - segments[:, 0]  # (S, 2)
    q = a[None, None] - origins[:, None, None]  # (N, 1, S, 2)
    d = directions[:, :, None]  # (N, B, 1, 2)
    denom = _cross(d, e[None, None])  # (N, B, S)
    parallel = jnp.abs(denom) < 1e-12
    safe = jnp.where(parallel, 1.0, denom)  # guard: a ray parallel to a segment never meets it
    t = _cross(q, e[None, None]) / safe
    u = _cross(q, d) / safe
    hit = ~parallel & (t > 0) & (u >= 0) & (u <= 1)
    return jnp.minimum(jnp.min(jnp.where(hit, t, jnp.inf), axis=-1), max_range)


def empty_log_odds(spec: GridSpec) -> jax.Array:
    return jnp.zeros((spec.height, spec.width), jnp.float32)


@functools.partial(jax.jit, static_argnames=("spec", "cfg"))
def integrate_scans(log_odds: jax.Array, poses: jax.Array, ranges: jax.Array, spec: GridSpec,
                    cfg: LidarConfig) -> tuple[jax.Array, jax.Array]:
    """Adds scans (T, B) taken at poses (T, 3) (the map frame) to a log-odds grid (H, W).

    Per scan, every cell that a beam crosses before its end gets l_free once and every end cell
    of a beam that hit something (range < max_range) gets l_occ once (the standard inverse
    sensor model; a cell is updated at most once per scan, however many samples fall in it).
    Returns (log-odds (H, W), observed (H, W) bool: cells some beam reached)."""
    angles = jnp.asarray(beam_angles(cfg), jnp.float32)
    step = spec.resolution / 2
    n = int(np.ceil(cfg.max_range / step))
    ts = (jnp.arange(n, dtype=jnp.float32) + 0.5) * step  # (n,) samples along a beam

    def cells(pts):  # (..., 2) map frame -> flat cell index, -1 outside
        j = jnp.floor((pts[..., 0] - spec.x0) / spec.resolution).astype(jnp.int32)
        i = jnp.floor((pts[..., 1] - spec.y0) / spec.resolution).astype(jnp.int32)
        inside = (i >= 0) & (i < spec.height) & (j >= 0) & (j < spec.width)
        return jnp.where(inside, i * spec.width + j, spec.height * spec.width)  # out of range: dropped

    def one(carry, scan):
        lo, seen = carry
        pose, r = scan
        th = pose[2] + angles  # (B,)
        d = jnp.stack([jnp.cos(th), jnp.sin(th)], -1)  # (B, 2)
        free_pts = pose[None, None, :2] + ts[None, :, None] * d[:, None, :]  # (B, n, 2)
        free_ok = ts[None, :] < (r[:, None] - spec.resolution / 2)  # stop short of the end cell
        free_idx = jnp.where(free_ok, cells(free_pts), spec.height * spec.width)
        hit_idx = jnp.where(r < cfg.max_range, cells(pose[None, :2] + r[:, None] * d), spec.height * spec.width)
        size = spec.height * spec.width
        free = jnp.zeros(size, bool).at[free_idx.reshape(-1)].set(True, mode="drop")
        hit = jnp.zeros(size, bool).at[hit_idx].set(True, mode="drop")
        delta = jnp.where(hit, cfg.l_occ, jnp.where(free, cfg.l_free, 0.0)).reshape(spec.height, spec.width)
        lo = jnp.clip(lo + delta, cfg.l_min, cfg.l_max)
        return (lo, seen | (free | hit).reshape(spec.height, spec.width)), None

    seen0 = jnp.zeros(log_odds.shape, bool)
    (lo, seen), _ = jax.lax.scan(one, (log_odds, seen0), (poses.astype(jnp.float32), ranges.astype(jnp.float32)))
    return lo, seen


def occupancy_from_log_odds(log_odds, observed, spec: GridSpec, crop: bool = True, margin: int = 2) -> OccupancyMap:
    """The map: P(occupied) = sigmoid(log-odds) where observed, unknown elsewhere; cropped to the
    observed cells' bounding box (+ margin) when `crop`."""
    lo, seen = np.asarray(log_odds, np.float64), np.asarray(observed)
    occ = np.where(seen, 1.0 / (1.0 + np.exp(-lo)), np.nan).astype(np.float32)
    x0, y0 = spec.x0, spec.y0
    if crop and seen.any():
        rows, cols = np.nonzero(seen)
        r0, r1 = max(rows.min() - margin, 0), min(rows.max() + 1 + margin, seen.shape[0])
        c0, c1 = max(cols.min() - margin, 0), min(cols.max() + 1 + margin, seen.shape[1])
        occ = occ[r0:r1, c0:c1]
        x0, y0 = x0 + c0 * spec.resolution, y0 + r0 * spec.resolution
    return OccupancyMap(occ, spec.resolution, (x0, y0, 0.0))
