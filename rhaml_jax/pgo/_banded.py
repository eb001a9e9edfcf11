"""Block-tridiagonal solver by cyclic reduction, for graphs of small node bandwidth.

If every edge joins free nodes whose variable indices differ by at most w, grouping the
variables w at a time makes H block tridiagonal with (3w x 3w) blocks. The RHAML two-robot
graph, ordered A_0, B_0, A_1, B_1, ..., has w = 2 and so 6 x 6 blocks. Odd-even cyclic
reduction (`pcr_solve`) then takes ceil(log2 M) batched steps with an unrolled Gauss-Jordan
solve per block instead of M sequential ones, and no LAPACK call per block (which costs
microseconds each here). Block LDL^T (`thomas_solve`, M sequential steps of ~2.2 us) does
less work and measured faster for M = 101 (0.44 against 1.05 ms with one XLA thread,
experiments/profile_rhaml_pgo.py); the RHAML ladder solver uses it. A dense factorisation of
the same 600 x 600 system costs ~100x more on this machine.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._normal_equations import BlockStructure

__all__ = ["BandLayout", "band_layout", "node_bandwidth", "solve_banded", "pcr_solve", "thomas_solve"]


@functools.partial(jax.tree_util.register_dataclass, data_fields=["diag_pos", "diag_pos_t", "sub_pos", "pad_diag"],
                   meta_fields=["width", "groups"])
@dataclasses.dataclass(frozen=True)
class BandLayout:
    """Where each 3x3 block of H lands in the padded group matrices (width, groups static)."""

    diag_pos: jax.Array  # (B, 2) int32: (group, flat index into (w*3)^2) for block, or -1
    diag_pos_t: jax.Array  # (B, 2) int32: same for its transpose (off-diagonal blocks in a group)
    sub_pos: jax.Array  # (B, 2) int32: (group, flat index) of the transpose in the sub-diagonal
    pad_diag: jax.Array  # (P,) int32: flat diagonal indices of padded variables (group M-1 side)
    width: int  # w: variables per group
    groups: int  # M: number of groups of w variables (the last one padded)


def node_bandwidth(s: BlockStructure) -> int:
    r = np.asarray(s.block_row)
    c = np.asarray(s.block_col)
    return int(np.max(c - r)) if r.size else 0


def band_layout(s: BlockStructure, min_width: int = 1) -> BandLayout:
    """Groups of w = max(bandwidth, min_width) variables: wider groups mean fewer sequential
    steps with bigger blocks."""
    nv = int(np.asarray(s.var_of_node).shape[0]) - 1
    w = max(1, min_width, node_bandwidth(s))
    groups = -(-nv // w)
    M = groups
    r = np.asarray(s.block_row, dtype=np.int64)
    c = np.asarray(s.block_col, dtype=np.int64)
    b = 3 * w
    ga, gb, la, lb = r // w, c // w, r % w, c % w
    # 3x3 block (a, b) starts at (3 la, 3 lb) within a group matrix; store its top-left index
    same = ga == gb
    diag_pos = np.where(same[:, None], np.stack([ga, 3 * la * b + 3 * lb], 1), -1)
    offd = same & (r != c)
    diag_pos_t = np.where(offd[:, None], np.stack([ga, 3 * lb * b + 3 * la], 1), -1)
    sub = gb == ga + 1
    sub_pos = np.where(sub[:, None], np.stack([ga, 3 * lb * b + 3 * la], 1), -1)
    pad_vars = np.arange(nv, M * w)
    local = 3 * (pad_vars[:, None] % w) + np.arange(3)[None, :]  # (P, 3) row within the group
    pad_diag = ((pad_vars[:, None] // w) * b * b + local * (b + 1)).reshape(-1)
    i32 = lambda a: np.asarray(a, np.int32)  # noqa: E731
    return BandLayout(i32(diag_pos), i32(diag_pos_t), i32(sub_pos), i32(pad_diag), w, M)


def _scatter_blocks(target, pos, blocks, b):
    """Adds 3x3 `blocks` at top-left flat positions `pos` (group, index) of target (M, b*b)."""
    offs = (np.arange(3)[:, None] * b + np.arange(3)[None, :]).reshape(-1)  # (9,)
    g = jnp.where(pos[:, 0] >= 0, pos[:, 0], target.shape[0])  # out of range -> dropped
    idx = pos[:, 1:2] + jnp.asarray(offs)[None, :]
    return target.at[g[:, None], idx].add(blocks.reshape(-1, 9), mode="drop")


def _spd_solve(A, B):
    """Solves A X = B for a batch of small SPD matrices A (M, b, b), B (M, b, k) by Gauss-Jordan
    elimination without pivoting, unrolled over the b columns. XLA fuses it into a few loops,
    far cheaper here than one LAPACK call per matrix. A non-positive pivot (A not positive
    definite) makes the result NaN, which the solver treats as a failed step."""
    b = A.shape[-1]
    X = jnp.concatenate([A, B], axis=-1)
    ok = jnp.ones(A.shape[:-2], bool)
    for k in range(b):
        pivot = X[:, k, k]
        ok = ok & (pivot > 0)
        row = X[:, k, :] / pivot[:, None]
        X = X - X[:, :, k : k + 1] * row[:, None, :]
        X = X.at[:, k, :].set(row)
    return jnp.where(ok[:, None, None], X[:, :, b:], jnp.nan)


def pcr_solve(D, Lo, Up, r):
    """Solves the SPD block tridiagonal system Lo[i] x[i-1] + D[i] x[i] + Up[i] x[i+1] = r[i]
    (D, Lo, Up (M, b, b), r (M, b, k); Lo[0] = Up[M-1] = 0) by parallel cyclic reduction.

    Level l eliminates from every equation i its neighbours i -/+ s, s = 2^l, with equations
    i -/+ s, which leaves couplings at distance 2s; after ceil(log2 M) levels every block is
    decoupled. Each level's reduced blocks are Schur complements of the SPD matrix, so no
    pivoting is needed. All M equations are processed at once at every level (fixed shapes:
    one `fori_loop` body, no per-level compilation), O(M b^3 log M) work in a handful of
    batched ops per level instead of M sequential steps. A non-positive pivot (H not positive
    definite) makes the result NaN, which the solver treats as a failed step."""
    M, b = D.shape[0], D.shape[-1]
    levels = max(0, (M - 1).bit_length())
    idx = jnp.arange(M)

    def level(l, carry):
        D, Lo, Up, r = carry
        s = jnp.left_shift(1, l)
        X = _spd_solve(D, jnp.concatenate([Lo, Up, r], axis=-1))  # D^-1 [Lo Up r]
        Xm = X[jnp.maximum(idx - s, 0)]  # rows out of range meet Lo = 0 / Up = 0
        Xp = X[jnp.minimum(idx + s, M - 1)]
        Ym = Lo @ Xm
        Yp = Up @ Xp
        D = D - Ym[..., b : 2 * b] - Yp[..., :b]
        return D, -Ym[..., :b], -Yp[..., b : 2 * b], r - Ym[..., 2 * b :] - Yp[..., 2 * b :]

    D, Lo, Up, r = jax.lax.fori_loop(0, levels, level, (D, Lo, Up, r))
    return _spd_solve(D, r)


def thomas_solve(D, Lo, r):
    """Solves the same SPD block tridiagonal system (Up[i] = Lo[i+1]^T) by block LDL^T: one
    forward and one backward `lax.scan` over the M groups. Fewer operations than
    `pcr_solve` (which is log2 M times the work) but M sequential steps; for M = 101 it
    measured 0.44 ms against pcr's 1.05 ms here (experiments/profile_rhaml_pgo.py)."""
    b = D.shape[-1]

    # S_i needs S_{i-1}^-1 A[i-1, i] = S_{i-1}^-1 Lo[i]^T: the solve happens in the step
    Up_next = jnp.swapaxes(jnp.concatenate([Lo[1:], jnp.zeros_like(Lo[:1])]), -1, -2)  # A[i, i+1]

    def step(carry, x):
        W, y = carry  # S_{i-1}^-1 A[i-1, i], S_{i-1}^-1 rhs_{i-1}
        Di, Li, Ui, ri = x
        S = Di - Li @ W
        X = _spd_solve(S[None], jnp.concatenate([Ui, ri - Li @ y], axis=-1)[None])[0]
        W, y = X[:, :b], X[:, b:]
        return (W, y), (W, y)

    z = jnp.zeros((b, b), D.dtype)
    _, (W, y) = jax.lax.scan(step, (z, jnp.zeros_like(r[0])), (D, Lo.at[0].set(0.0), Up_next, r))

    def bwd(xnext, x):
        Wi, yi = x
        xi = yi - Wi @ xnext
        return xi, xi

    _, xs = jax.lax.scan(bwd, jnp.zeros_like(r[0]), (W, y), reverse=True)
    return xs


def solve_banded(blocks: jax.Array, g: jax.Array, damp: jax.Array, lay: BandLayout) -> jax.Array:
    """blocks (B, 3, 3), g (nv, 3), damp (nv, 3) -> delta (nv, 3)."""
    nv = g.shape[0]
    w, M = lay.width, lay.groups
    b = 3 * w
    blocks = blocks.at[jnp.arange(nv), jnp.arange(3)[:, None], jnp.arange(3)[:, None]].add(damp.T)
    D = jnp.zeros((M, b * b), blocks.dtype)
    D = _scatter_blocks(D, lay.diag_pos, blocks, b)
    D = _scatter_blocks(D, lay.diag_pos_t, jnp.swapaxes(blocks, -1, -2), b)
    D = D.reshape(-1).at[lay.pad_diag].set(1.0).reshape(M, b, b)
    C = jnp.zeros((M, b * b), blocks.dtype)
    C = _scatter_blocks(C, lay.sub_pos, jnp.swapaxes(blocks, -1, -2), b).reshape(M, b, b)
    rhs = jnp.zeros((M * w * 3,), g.dtype).at[: 3 * nv].set(-g.reshape(-1)).reshape(M, b, 1)
    Up = jnp.swapaxes(C, -1, -2).at[M - 1].set(0.0)  # A[i, i+1] = C[i]^T
    Lo = jnp.concatenate([jnp.zeros_like(C[:1]), C[:-1]])  # A[i, i-1] = C[i-1]
    x = pcr_solve(D, Lo, Up, rhs)
    return x.reshape(-1)[: 3 * nv].reshape(nv, 3)
