"""Hard z-buffer rasterizer: visible face per pixel centre, depth and Lambertian shading.

Pairs are visited chunk by chunk (`_tiles.fold_chunks`); each chunk tests its pixel centres
against its faces' clipped polygons and depth planes and merges into the buffers:
depth by scatter-min, and the face id by resetting the pixels whose depth improved and then
scatter-max over the pixels whose depth equals the new minimum (ties: the larger face id).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rhaml_jax.render._edges import inside
from rhaml_jax.render._geometry import ScreenFaces
from rhaml_jax.render._tiles import chunk_pairs, chunk_size, fold_chunks, layout


class RenderOutput(NamedTuple):
    """rgb: (..., H, W, 3) float in [0, 1] (background 0); mask: (..., H, W) bool, visible model;
    depth: (..., H, W) z in metres along the optical axis (0 on background);
    face_id: (..., H, W) int32 visible face (-1 on background);
    pairs: (...,) int32 (face, block) pairs visited (the work done).
    """

    rgb: jnp.ndarray
    mask: jnp.ndarray
    depth: jnp.ndarray
    face_id: jnp.ndarray
    pairs: jnp.ndarray


def zbuffer(sf: ScreenFaces, width: int, height: int, *, block: int, chunk_pixels: int, near: float):
    """-> depth (npix,) (inf on background), face id (npix,) int32 (-1), pairs visited ()."""
    npix = width * height
    dt = sf.poly.dtype
    lay = layout(sf, 0.0, width, height, block)
    size = chunk_size(block, chunk_pixels)
    max_iz = 1.0 / (near * (1 - 1e-4))

    def body(first, carry):
        zbuf, fid = carry
        pr = chunk_pairs(lay, first, size, width, height, block)
        u, v = pr.px.astype(dt), pr.py.astype(dt)
        plane = sf.inv_depth[pr.face]  # (C, 3)
        iz = plane[:, 0:1] * u + plane[:, 1:2] * v + plane[:, 2:3]
        hit = inside(sf.poly[pr.face], sf.orient[pr.face], u, v) & pr.used & (iz > 0) & (iz <= max_iz)
        z = 1.0 / jnp.where(hit, iz, 1.0)  # guard: no 1/0 off the face
        # Computed before the scatters consume them: XLA's CPU scatter fusion would otherwise
        # evaluate the tests element by element inside the scatter's serial loop.
        idx = jnp.where(hit, pr.index, npix)
        z, hit, idx = jax.lax.optimization_barrier((z, hit, idx))
        safe = jnp.minimum(idx, npix - 1)
        old = zbuf[safe]
        zbuf = zbuf.at[idx].min(z, mode="drop")
        fid = fid.at[jnp.where(hit & (z < old), idx, npix)].set(-1, mode="drop")
        win = hit & (z <= zbuf[safe])
        fid = fid.at[jnp.where(win, idx, npix)].max(jnp.broadcast_to(pr.face[:, None], idx.shape), mode="drop")
        return zbuf, fid

    init = (jnp.full((npix,), jnp.inf, dt), jnp.full((npix,), -1, jnp.int32))
    zbuf, fid = fold_chunks(lay, size, body, init)
    return zbuf, fid, lay.needed


def rasterize(sf: ScreenFaces, face_colors, width: int, height: int, *, block: int, chunk_pixels: int,
              light_dir, ambient, diffuse, near: float) -> RenderOutput:
    """One camera: ScreenFaces -> RenderOutput with (H, W) images."""
    zbuf, fid, pairs = zbuffer(sf, width, height, block=block, chunk_pixels=chunk_pixels, near=near)
    dt = zbuf.dtype
    mask = fid >= 0
    light = light_dir / jnp.linalg.norm(light_dir)
    lam = jnp.maximum(sf.normal @ light, 0.0)  # (F,) shade per face, then one gather per pixel
    shaded = jnp.clip(face_colors * (ambient + diffuse * lam)[:, None], 0.0, 1.0)
    shaded = jnp.concatenate([jnp.zeros((1, 3), dt), shaded.astype(dt)])  # row 0: background
    rgb = shaded[fid + 1]
    depth = jnp.where(mask, zbuf, 0.0)
    return RenderOutput(rgb.reshape(height, width, 3), mask.reshape(height, width),
                        depth.reshape(height, width), fid.reshape(height, width), pairs)
