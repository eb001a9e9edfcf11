"""Block-sparse Gauss-Newton normal equations H delta = -g with 3x3 blocks.

The fixed (gauge) node has no variable. `BlockStructure` is computed once per graph on the
host: the diagonal blocks (one per free node) come first, then one block per distinct pair of
connected free nodes (stored for row < col). Each edge scatters its J^T W J pieces into its
blocks with `segment_sum`; contributions that touch the fixed node go to a trash slot.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._residuals import Linearization

__all__ = ["BlockStructure", "block_structure", "assemble", "dense_matrix"]


class BlockStructure(NamedTuple):
    """Host-computed sparsity of H (a pytree of int arrays; sizes are static)."""

    var_of_node: jax.Array  # (N,) int32: variable index of each node, num_vars for the fixed one
    block_row: jax.Array  # (B,) int32: block row (variable index); first num_vars are diagonal
    block_col: jax.Array  # (B,) int32: block column, block_row <= block_col
    slot_ii: jax.Array  # (E,) int32: block of H_ii (B = trash)
    slot_jj: jax.Array  # (E,) int32: block of H_jj
    slot_ij: jax.Array  # (E,) int32: block holding H_ij (or its transpose)
    ij_upper: jax.Array  # (E,) bool: var(i) < var(j), i.e. the block stores H_ij itself


def block_structure(num_nodes: int, edges: np.ndarray, fixed: int) -> BlockStructure:
    edges = np.asarray(edges, dtype=np.int64)
    nv = num_nodes - 1
    var = np.arange(num_nodes, dtype=np.int64)
    var[fixed + 1 :] -= 1
    var[fixed] = nv
    vi, vj = var[edges[:, 0]], var[edges[:, 1]]
    free = (vi < nv) & (vj < nv)
    lo, hi = np.minimum(vi, vj), np.maximum(vi, vj)
    keys = lo * (nv + 1) + hi
    uniq, inv = np.unique(keys[free], return_inverse=True)
    B = nv + uniq.size
    slot_ij = np.full(edges.shape[0], B, dtype=np.int64)
    slot_ij[free] = nv + inv
    block_row = np.concatenate([np.arange(nv), uniq // (nv + 1)])
    block_col = np.concatenate([np.arange(nv), uniq % (nv + 1)])
    slot_ii = np.where(vi < nv, vi, B)
    slot_jj = np.where(vj < nv, vj, B)
    i32 = lambda a: np.asarray(a, dtype=np.int32)  # noqa: E731
    return BlockStructure(i32(var), i32(block_row), i32(block_col), i32(slot_ii), i32(slot_jj),
                          i32(slot_ij), vi < vj)


def assemble(lin: Linearization, info_w: jax.Array, s: BlockStructure) -> tuple[jax.Array, jax.Array]:
    """Weighted normal equations. info_w: (E, 3, 3) robust-weighted information.

    Returns blocks (B, 3, 3) of H (upper block triangle) and g (num_vars, 3) = J^T W r.
    """
    B = s.block_row.shape[0]
    nv = s.var_of_node.shape[0] - 1
    WJi = info_w @ lin.J_i  # (E, 3, 3)
    WJj = info_w @ lin.J_j
    JiT = jnp.swapaxes(lin.J_i, -1, -2)
    JjT = jnp.swapaxes(lin.J_j, -1, -2)
    Hii, Hjj, Hij = JiT @ WJi, JjT @ WJj, JiT @ WJj
    Hup = jnp.where(s.ij_upper[:, None, None], Hij, jnp.swapaxes(Hij, -1, -2))
    slots = jnp.concatenate([s.slot_ii, s.slot_jj, s.slot_ij])
    blocks = jax.ops.segment_sum(jnp.concatenate([Hii, Hjj, Hup]), slots, num_segments=B + 1)[:B]
    Wr = info_w @ lin.r[:, :, None]  # (E, 3, 1)
    gi = (JiT @ Wr)[..., 0]
    gj = (JjT @ Wr)[..., 0]
    seg = jnp.concatenate([s.slot_ii, s.slot_jj])  # diagonal block index == variable index
    seg = jnp.where(seg < nv, seg, nv)
    g = jax.ops.segment_sum(jnp.concatenate([gi, gj]), seg, num_segments=nv + 1)[:nv]
    return blocks, g


def dense_matrix(blocks: jax.Array, s: BlockStructure) -> jax.Array:
    """(B, 3, 3) upper blocks -> dense symmetric (3 nv, 3 nv)."""
    nv = s.var_of_node.shape[0] - 1
    H = jnp.zeros((nv, nv, 3, 3), blocks.dtype)
    H = H.at[s.block_row, s.block_col].add(blocks)
    off = blocks.at[:nv].set(0.0)
    H = H.at[s.block_col, s.block_row].add(jnp.swapaxes(off, -1, -2))
    return jnp.transpose(H, (0, 2, 1, 3)).reshape(3 * nv, 3 * nv)
