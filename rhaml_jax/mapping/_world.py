"""Simulated fields: a walled rectangle with random obstacles, as polygons and wall segments."""

from __future__ import annotations

import dataclasses

import numpy as np

from rhaml_jax import planar
from rhaml_jax.mapping._mapfile import OccupancyMap

__all__ = ["Field", "random_field", "true_map"]


@dataclasses.dataclass(frozen=True)
class Field:
    """A field [0, width] x [0, height] (m) with walls around it and convex polygonal obstacles."""

    width: float
    height: float
    obstacles: tuple[np.ndarray, ...]  # each (V, 2), counter-clockwise

    @property
    def segments(self) -> np.ndarray:
        """(S, 2, 2) every wall and obstacle edge."""
        w, h = self.width, self.height
        walls = np.array([[[0, 0], [w, 0]], [[w, 0], [w, h]], [[w, h], [0, h]], [[0, h], [0, 0]]], np.float64)
        edges = [np.stack([p, np.roll(p, -1, 0)], 1) for p in self.obstacles]
        return np.concatenate([walls] + edges, 0)

    def occupied(self, pts: np.ndarray, inflate: float = 0.0) -> np.ndarray:
        """(...) bool: points (..., 2) outside the field (less `inflate` from its walls) or
        within `inflate` of an obstacle."""
        x, y = pts[..., 0], pts[..., 1]
        out = (x < inflate) | (x > self.width - inflate) | (y < inflate) | (y > self.height - inflate)
        for p in self.obstacles:
            out |= _inside_convex(p, pts, inflate)
        return out


def _inside_convex(poly: np.ndarray, pts: np.ndarray, inflate: float) -> np.ndarray:
    """Points within `inflate` of a convex counter-clockwise polygon (inside included)."""
    a, b = poly, np.roll(poly, -1, 0)
    e = b - a  # (V, 2)
    rel = pts[..., None, :] - a  # (..., V, 2)
    side = e[:, 0] * rel[..., 1] - e[:, 1] * rel[..., 0]  # > 0: left of the edge (inside)
    inside = np.all(side >= 0, -1)
    if inflate <= 0:
        return inside
    u = np.clip((rel * e).sum(-1) / (e * e).sum(-1), 0, 1)
    d = np.linalg.norm(rel - u[..., None] * e, axis=-1).min(-1)
    return inside | (d < inflate)


def random_field(seed: int, width: float = 10.0, height: float = 7.0, obstacles: int = 9,
                 keep_clear: tuple[tuple[float, float, float], ...] = ()) -> Field:
    """Random boxes (0.3-1.2 m, any rotation) and cylinders (12-gons, radius 0.15-0.4 m) inside the
    field, at least 0.7 m from each other and from the walls (so a robot can pass), none within
    the discs `keep_clear` = ((x, y, r), ...). Deterministic in `seed`."""
    rng = np.random.default_rng(seed)
    polys, discs = [], []
    tries = 0
    while len(polys) < obstacles and tries < 2000:
        tries += 1
        if rng.uniform() < 0.65:
            sx, sy = rng.uniform(0.3, 1.2, 2)
            local = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]]) / 2
        else:
            r = rng.uniform(0.15, 0.4)
            a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
            local = r * np.stack([np.cos(a), np.sin(a)], 1)
        radius = np.linalg.norm(local, axis=1).max()
        c = np.array([rng.uniform(0, width), rng.uniform(0, height)])
        if min(c[0], width - c[0], c[1], height - c[1]) < radius + 0.7:
            continue
        if any(np.hypot(*(c - np.array(k[:2]))) < radius + k[2] for k in keep_clear):
            continue
        if any(np.hypot(*(c - d[:2])) < radius + d[2] + 0.7 for d in discs):
            continue
        pose = np.array([c[0], c[1], rng.uniform(-np.pi, np.pi)])
        pts = planar.compose(np.broadcast_to(pose, (len(local), 3)), np.concatenate([local, np.zeros((len(local), 1))], 1))
        polys.append(pts[:, :2])
        discs.append(np.array([c[0], c[1], radius]))
    return Field(width, height, tuple(polys))


def true_map(field: Field, resolution: float, frame=(0.0, 0.0, 0.0), extent=None, supersample: int = 3) -> OccupancyMap:
    """The field as a map in the frame whose pose in the field is `frame`: a cell is occupied
    when any part of it (sampled on a supersample^2 sub-grid) is inside an obstacle or outside the
    walls, free otherwise. `extent` = (x0, y0, x1, y1) of the grid in that frame (default: the
    field's bounding box there, plus 2 cells)."""
    frame = np.asarray(frame, np.float64)
    if extent is None:
        corners = np.array([[0, 0], [field.width, 0], [0, field.height], [field.width, field.height]], np.float64)
        local = planar.between(np.broadcast_to(frame, (4, 3)), np.concatenate([corners, np.zeros((4, 1))], 1))[:, :2]
        extent = (*(local.min(0) - 2 * resolution), *(local.max(0) + 2 * resolution))
    x0, y0, x1, y1 = extent
    W, H = int(np.ceil((x1 - x0) / resolution)), int(np.ceil((y1 - y0) / resolution))
    sub = (np.arange(supersample) + 0.5) / supersample
    gx = x0 + (np.arange(W)[:, None] + sub[None]).reshape(-1) * resolution
    gy = y0 + (np.arange(H)[:, None] + sub[None]).reshape(-1) * resolution
    X, Y = np.meshgrid(gx, gy)
    p = np.stack([X, Y, np.zeros_like(X)], -1)
    world = planar.compose(np.broadcast_to(frame, p.shape), p)[..., :2]
    occ = field.occupied(world).reshape(H, supersample, W, supersample).any((1, 3))
    return OccupancyMap(occ.astype(np.float32), resolution, (x0, y0, 0.0))


def map_scores(m: OccupancyMap, field: Field, frame=(0.0, 0.0, 0.0), supersample: int = 3) -> dict:
    """A map (in the frame whose pose in the field is `frame`) against the truth, on the cells the
    map knows: occupied-cell IoU, the fraction of truly free cells it calls occupied, and the
    fraction of the field's area it knows (coverage)."""
    H, W = m.shape
    if abs(m.origin[2]) > 1e-12:
        raise ValueError("map_scores: maps with a rotated origin are not supported")
    x0, y0 = m.origin[0], m.origin[1]
    truth = true_map(field, m.resolution, frame, (x0, y0, x0 + W * m.resolution, y0 + H * m.resolution), supersample)
    t = truth.occupied[:H, :W]
    known = m.known
    occ = m.occupied
    inter, union = (occ & t & known).sum(), ((occ | t) & known).sum()
    free_true = known & ~t
    return {"iou": float(inter / max(union, 1)), "false_occupied": float((occ & free_true).sum() / max(free_true.sum(), 1)),
            "known_m2": float(known.sum() * m.resolution**2)}
