"""Binning: each face's pixel box (grown by a margin for the soft edge) is cut into blocks of
B x B pixels; the (face, block) pairs are numbered 0 .. needed-1 face by face and visited in
chunks of a fixed number of pairs.

Work is then proportional to the pixels each face can touch, not to every pixel against every
face, and nothing is ever dropped: a `lax.while_loop` runs ceil(needed / chunk) chunks, each
a fixed-shape step (one XLA program for jit, vmap, CPU and GPU alike).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rhaml_jax.render._geometry import COORD_LIMIT, ScreenFaces


class Layout(NamedTuple):
    """Per-face block grid: (F,) int32 arrays; pairs of face f are numbers starts[f] .. ends[f]-1."""

    ends: jnp.ndarray
    starts: jnp.ndarray
    x0: jnp.ndarray
    y0: jnp.ndarray
    x1: jnp.ndarray
    y1: jnp.ndarray
    nbx: jnp.ndarray

    @property
    def needed(self):
        return self.ends[-1]


class Pairs(NamedTuple):
    """C (face, block) pairs and their B * B pixels (N = B * B).

    face: (C,) int32 (clamped to a real face for unused slots); px, py: (C, N) int32 pixel
    coordinates; index: (C, N) int32 flat pixel index y * W + x, or W * H (out of range, so
    scatters drop it) where unused; used: (C, N) bool.
    """

    face: jnp.ndarray
    px: jnp.ndarray
    py: jnp.ndarray
    index: jnp.ndarray
    used: jnp.ndarray


def layout(sf: ScreenFaces, margin, width: int, height: int, block: int) -> Layout:
    """Face boxes grown by `margin` px, clipped to the image, in blocks of `block` px."""
    lo = jnp.clip(sf.lo - margin, -COORD_LIMIT, COORD_LIMIT)
    hi = jnp.clip(sf.hi + margin, -COORD_LIMIT, COORD_LIMIT)
    x0 = jnp.maximum(jnp.ceil(lo[:, 0]), 0).astype(jnp.int32)
    y0 = jnp.maximum(jnp.ceil(lo[:, 1]), 0).astype(jnp.int32)
    x1 = jnp.minimum(jnp.floor(hi[:, 0]), width - 1).astype(jnp.int32)
    y1 = jnp.minimum(jnp.floor(hi[:, 1]), height - 1).astype(jnp.int32)
    nbx = (x1 - x0) // block + 1
    nby = (y1 - y0) // block + 1
    counts = jnp.where(sf.valid & (x1 >= x0) & (y1 >= y0), nbx * nby, 0)
    ends = jnp.cumsum(counts)
    return Layout(ends, ends - counts, x0, y0, x1, y1, jnp.maximum(nbx, 1))


def chunk_pairs(lay: Layout, first, size: int, width: int, height: int, block: int) -> Pairs:
    """Pairs number first .. first+size-1 (those >= needed are unused), pixel by pixel."""
    b = chunk_blocks(lay, first, size, block)
    off = jnp.arange(block, dtype=jnp.int32)
    px = b.x[:, None, None] + off[None, None, :]  # (C, B, B)
    py = b.y[:, None, None] + off[None, :, None]
    used = (off[None, None, :] < b.ncol[:, None, None]) & (off[None, :, None] < b.nrow[:, None, None])
    px = jnp.broadcast_to(px, used.shape).reshape(size, -1)
    py = jnp.broadcast_to(py, used.shape).reshape(size, -1)
    used = used.reshape(size, -1)
    face = b.face
    index = jnp.where(used, py * width + px, width * height)
    return Pairs(face, px, py, index, used)


def padded_size(width: int, height: int, block: int):
    """(width, height) of the image padded so that every block of a `layout` fits inside."""
    return width + block - 1, height + block - 1


class Blocks(NamedTuple):
    """C (face, block) pairs as per-pair (C,) int32 arrays: face (clamped to a real face for
    unused slots), block origin x, y (px), and the numbers of the block's columns and rows that
    are inside the face's box (0 for unused slots). Pixel (x + i, y + j) of the block is used
    iff i < ncol and j < nrow."""

    face: jnp.ndarray
    x: jnp.ndarray
    y: jnp.ndarray
    ncol: jnp.ndarray
    nrow: jnp.ndarray


def chunk_blocks(lay: Layout, first, size: int, block: int) -> Blocks:
    """The pairs of `chunk_pairs`, per pair (the per-pixel arrays are left to the consumer, so
    that XLA's fused pixel loops see only broadcasts of (C,) arrays, no gathers)."""
    slot = first + jnp.arange(size, dtype=jnp.int32)
    face = jnp.searchsorted(lay.ends, slot, side="right").astype(jnp.int32)
    live = slot < lay.needed
    face = jnp.minimum(face, lay.ends.shape[0] - 1)
    local = slot - lay.starts[face]
    nbx = lay.nbx[face]
    x = lay.x0[face] + (local % nbx) * block
    y = lay.y0[face] + (local // nbx) * block
    ncol = jnp.where(live, jnp.clip(lay.x1[face] - x + 1, 0, block), 0)
    nrow = jnp.where(live, jnp.clip(lay.y1[face] - y + 1, 0, block), 0)
    return Blocks(face, x, y, ncol, nrow)


def block_pixels(b: Blocks, block: int, dtype):
    """(C, B * B) pixel centres u, v (dtype) and used (bool) of the blocks, row-major."""
    off = jnp.arange(block, dtype=jnp.int32)
    ox = jnp.tile(off, block)[None, :]
    oy = jnp.repeat(off, block)[None, :]
    u = (b.x[:, None] + ox).astype(dtype)
    v = (b.y[:, None] + oy).astype(dtype)
    used = (ox < b.ncol[:, None]) & (oy < b.nrow[:, None])
    return u, v, used


def block_rows(b: Blocks, width: int, height: int, block: int, pad_block: int):
    """(C, B) flat index in the image padded for blocks of pad_block >= B px of the first pixel of
    each block row (the row's B pixels are contiguous there); out of range (dropped by scatters)
    for unused slots."""
    wp, hp = padded_size(width, height, pad_block)
    start = (b.y[:, None] + jnp.arange(block, dtype=jnp.int32)[None, :]) * wp + b.x[:, None]
    return jnp.where((b.ncol > 0)[:, None], start, wp * hp)


def chunk_size(block: int, chunk_pixels: int) -> int:
    return max(1, chunk_pixels // (block * block))


def fold_chunks(lay: Layout, size: int, body, init):
    """carry = body(first, carry) for first = 0, size, 2 size, ... while first < needed."""

    def cond(state):
        return state[0] < lay.needed

    def step(state):
        first, carry = state
        return first + size, body(first, carry)

    return jax.lax.while_loop(cond, step, (jnp.int32(0), init))[1]
