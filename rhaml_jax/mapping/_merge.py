"""Placing map B in map A's frame by an SE(2) transform, and their union.

The transform is A_0 T B_0 (x, y, psi): the pose of B's map frame in A's map frame, so a point
p_B of B's map is at R(psi) p_B + (x, y) in A's. The merged grid lies on A's cell lattice
(A's cells are copied, never resampled), grown to hold both maps.

Interpolation of B's occupancy (`interpolation`):
- "nearest" (default): each merged cell takes the value of the B cell under its centre. It never
  invents a value: a trinary map stays trinary, unknown stays unknown, and a wall one cell thick
  stays a connected line at any rotation, displaced by at most half a cell diagonal. This is
  what grid-map mergers do (multirobot_map_merge warps with INTER_NEAREST).
- "linear": bilinear on the probabilities of the *known* neighbours only (weights renormalised;
  unknown when less than half of the weight is known, i.e. the sample point is nearer unknown
  cells than known ones). Treating unknown as p = 0.5 instead would pull every cell at the edge
  of the explored area towards 0.5 and shrink the map. It is smoother for scale-mode maps, but
  it averages a one-cell wall with the free cells beside it: between two cells the wall's p
  falls to ~0.5, below occupied_thresh, so rotated thin walls lose cells (tests/test_mapping.py
  measures it), which is why it is not the default.

Union: where both maps know a cell, the larger occupancy wins (a wall that either robot saw is
kept: conservative for navigation, as multirobot_map_merge's max rule); where one knows it, its
value; unknown where neither does.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from rhaml_jax import planar
from rhaml_jax.errors import RhamlError
from rhaml_jax.mapping._mapfile import OccupancyMap, grid_to_map, map_to_grid

__all__ = ["MergeReport", "resample", "merge_maps", "transform_points"]

Interpolation = Literal["nearest", "linear"]


def transform_points(T, pts: np.ndarray) -> np.ndarray:
    """Points (..., 2) in frame B -> frame A, with T = the pose (x, y, psi) of B in A."""
    T = np.asarray(T, np.float64)
    p = np.concatenate([pts, np.zeros(pts.shape[:-1] + (1,))], -1)
    return planar.compose(np.broadcast_to(T, p.shape), p)[..., :2]


def resample(m: OccupancyMap, query: np.ndarray, interpolation: Interpolation = "nearest") -> np.ndarray:
    """Occupancy of map `m` at points `query` (..., 2) of m's map frame; NaN (unknown) outside."""
    g = map_to_grid(m.origin, query) / m.resolution - 0.5  # continuous cell index (cell centres at integers)
    H, W = m.shape
    occ = m.occupancy
    if interpolation == "nearest":
        j, i = np.floor(g[..., 0] + 0.5).astype(np.int64), np.floor(g[..., 1] + 0.5).astype(np.int64)
        inside = (i >= 0) & (i < H) & (j >= 0) & (j < W)
        return np.where(inside, occ[np.clip(i, 0, H - 1), np.clip(j, 0, W - 1)], np.nan).astype(np.float32)
    if interpolation != "linear":
        raise RhamlError(f"interpolation: expected nearest or linear, got {interpolation!r}")
    j0, i0 = np.floor(g[..., 0]).astype(np.int64), np.floor(g[..., 1]).astype(np.int64)
    fx, fy = g[..., 0] - j0, g[..., 1] - i0
    num = np.zeros(g.shape[:-1])
    wsum = np.zeros(g.shape[:-1])
    for di, dj, w in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        i, j = i0 + di, j0 + dj
        v = np.where((i >= 0) & (i < H) & (j >= 0) & (j < W), occ[np.clip(i, 0, H - 1), np.clip(j, 0, W - 1)], np.nan)
        k = np.isfinite(v)
        num += np.where(k, w * np.nan_to_num(v), 0.0)
        wsum += np.where(k, w, 0.0)
    # guard: cells with no known weight divide by 1 (they come out unknown anyway)
    return np.where(wsum >= 0.5, num / np.where(wsum > 0, wsum, 1.0), np.nan).astype(np.float32)


@dataclasses.dataclass(frozen=True)
class MergeReport:
    """What merging did, for the user: notes to print and the overlap."""

    notes: tuple[str, ...]
    overlap_cells: int  # cells known in both A and B (resampled)
    overlap_fraction: float  # of the smaller map's known cells
    offset_cells: tuple[int, int]  # A's cell (0, 0) in the merged grid (row, column)


def merge_maps(a: OccupancyMap, b: OccupancyMap, a_T_b, interpolation: Interpolation = "nearest",
               names: tuple[str, str] = ("A", "B")) -> tuple[OccupancyMap, MergeReport]:
    """The union of maps a and b in a's map frame, b placed by a_T_b (x, y, psi), on a's lattice."""
    a_T_b = np.asarray(a_T_b, np.float64)
    if a_T_b.shape != (3,) or not np.all(np.isfinite(a_T_b)):
        raise RhamlError(f"transform: expected three finite numbers x, y, psi, got {a_T_b.tolist()}")
    notes = []
    if not np.isclose(a.resolution, b.resolution, rtol=1e-6):
        notes.append(f"map {names[1]} has resolution {b.resolution:g} m, map {names[0]} {a.resolution:g} m: "
                     f"{names[1]} resampled to {a.resolution:g} m ({interpolation})")
    res = a.resolution
    # B's known cells' corners, in A's grid frame (cells), to size the merged grid
    Hb, Wb = b.shape
    kb = np.argwhere(b.known)
    if len(kb):
        lo, hi = kb.min(0), kb.max(0) + 1  # (row, col)
        corners = np.array([[lo[1], lo[0]], [hi[1], lo[0]], [lo[1], hi[0]], [hi[1], hi[0]]], np.float64) * b.resolution
        in_a = map_to_grid(a.origin, transform_points(a_T_b, grid_to_map(b.origin, corners))) / res
        c0, r0 = np.floor(in_a.min(0)).astype(int) - 1
        c1, r1 = np.ceil(in_a.max(0)).astype(int) + 1
    else:
        c0 = r0 = 0
        c1 = r1 = 0
    Ha, Wa = a.shape
    r0, c0 = min(r0, 0), min(c0, 0)
    r1, c1 = max(r1, Ha), max(c1, Wa)
    H, W = r1 - r0, c1 - c0
    if H * W > 50_000_000:
        raise RhamlError(f"transform {a_T_b.tolist()}: the merged map would be {W} x {H} cells; "
                         "is the transform in metres and radians?")
    origin = tuple(planar.compose(np.asarray(a.origin), np.array([c0 * res, r0 * res, 0.0])).tolist())
    out = np.full((H, W), np.nan, np.float32)
    out[-r0 : -r0 + Ha, -c0 : -c0 + Wa] = a.occupancy
    merged_grid = OccupancyMap(out, res, origin, a.occupied_thresh, a.free_thresh)
    centres_a = merged_grid.cell_centres()  # (H, W, 2) in A's map frame
    centres_b = transform_points(planar.inverse(a_T_b), centres_a)
    ob = resample(b, centres_b, interpolation)
    ka, kb_ = np.isfinite(out), np.isfinite(ob)
    both = ka & kb_
    merged = np.where(both, np.fmax(out, ob), np.where(ka, out, ob)).astype(np.float32)
    n_both = int(both.sum())
    smaller = max(min(int(ka.sum()), int(kb_.sum())), 1)
    if n_both == 0:
        notes.append(f"maps {names[0]} and {names[1]} do not overlap with this transform "
                     f"({a_T_b[0]:.3f}, {a_T_b[1]:.3f}, {np.degrees(a_T_b[2]):.2f} deg): the union is written "
                     "with no cell seen by both")
    report = MergeReport(tuple(notes), n_both, n_both / smaller, (-r0, -c0))
    return merged_grid.replace(occupancy=merged), report
