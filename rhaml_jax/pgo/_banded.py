"""Block-tridiagonal solvers, for graphs of small node bandwidth.

If every edge joins free nodes whose variable indices differ by at most w, grouping the
variables w at a time makes H block tridiagonal with (3w x 3w) blocks. The RHAML two-robot
graph, ordered A_0, B_0, A_1, B_1, ..., has w = 2 and so 6 x 6 blocks. Solvers of
`band_solve` (SolverConfig.band_solver):

- `twisted_solve` (default): block LDL^T from both ends towards the middle, the two chains in
  one batched `lax.scan` of ~M/2 steps. On XLA's CPU backend a step costs its ~17 small kernels'
  overhead (the 6 x 13 Gauss-Jordan of `_spd_solve`), not their arithmetic, so halving the
  steps is what pays.
- `thomas_solve`: the same factorisation in one direction, M steps.

experiments/profile_rhaml_pgo.py times both at M = 101 (BENCHMARKS.md). Measured slower and
dropped: parallel cyclic reduction (log2 M batched levels, 2.4x `thomas_solve`) and LAPACK's
banded Cholesky through a host callback (~3x `twisted_solve`: the callback alone costs more than
the scan). A dense factorisation of the same 606 x 606 system costs ~100x more here.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._normal_equations import BlockStructure

__all__ = ["BandLayout", "band_layout", "band_solve", "node_bandwidth", "solve_banded", "thomas_solve", "twisted_solve"]


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


def _eliminate(D, Lo, Up, r):
    """Forward block elimination down a chain: D, Lo, Up (h, b, b) with Lo[i] = A[i, i-1]
    (Lo[0] ignored), Up[i] = A[i, i+1], r (h, b, k) -> W = S_i^-1 Up[i], y = S_i^-1 (r_i -
    Lo_i y_{i-1}) per group, S_i = D_i - Lo_i W_{i-1} the Schur complements."""
    b = D.shape[-1]

    def step(X, x):
        Di, Li, URi = x  # X = S_{i-1}^-1 [A[i-1, i], rhs_{i-1}] = [W, y]_{i-1}
        P = Li @ X  # one product for both: [Lo_i W_{i-1}, Lo_i y_{i-1}]
        X = _spd_solve((Di - P[:, :b])[None], (URi - P.at[:, :b].set(0.0))[None])[0]
        return X, X

    X0 = jnp.zeros((b, b + r.shape[-1]), D.dtype)
    _, X = jax.lax.scan(step, X0, (D, Lo.at[0].set(0.0), jnp.concatenate([Up, r], axis=-1)))
    return X[..., :b], X[..., b:]


def _substitute(W, y, x_end):
    """Back substitution up the chain: x_i = y_i - W_i x_{i+1}, starting from x_end = x_h."""

    def bwd(xnext, x):
        Wi, yi = x
        xi = yi - Wi @ xnext
        return xi, xi

    return jax.lax.scan(bwd, x_end, (W, y), reverse=True)[1]


def _up(Lo):
    """A[i, i+1] = Lo[i+1]^T (zero for the last group)."""
    return jnp.swapaxes(jnp.concatenate([Lo[1:], jnp.zeros_like(Lo[:1])]), -1, -2)


def thomas_solve(D, Lo, r):
    """Solves the SPD block tridiagonal system Lo[i] x[i-1] + D[i] x[i] + Lo[i+1]^T x[i+1] = r[i]
    (D, Lo (M, b, b), Lo[0] ignored; r (M, b, k)) by block LDL^T: one forward and one backward
    `lax.scan` over the M groups, M sequential steps of ~2.2 us of XLA kernel overhead each
    (`twisted_solve` halves their number). A non-positive pivot (the matrix not positive
    definite) makes the result NaN, which the solver treats as a failed step."""
    return _substitute(*_eliminate(D, Lo, _up(Lo), r), jnp.zeros_like(r[0]))


def twisted_solve(D, Lo, r):
    """The same solve by a twisted (burn-at-both-ends) block factorisation: the groups above
    the middle one are eliminated downwards and those below it upwards, both chains in one
    batched scan of about M / 2 steps, then the middle group is solved and both chains are
    substituted back outwards, again together. The same work as `thomas_solve` in half the
    sequential steps, which is what costs here."""
    M, b = D.shape[0], D.shape[-1]
    if M < 3:
        return thomas_solve(D, Lo, r)
    m = M // 2  # the middle group; m groups above it, M - 1 - m (= m or m - 1) below
    Up = _up(Lo)
    # Below the middle, in reverse: the chain M-1, M-2, ..., m+1 sees A[g, g+1] as its lower
    # and A[g, g-1] as its upper coupling. A dummy group (identity, uncoupled) evens the lengths.
    pad = m - (M - 1 - m)
    dummy = lambda a, fill: jnp.concatenate([fill(a[:pad]), a])  # noqa: E731
    eye = lambda a: jnp.broadcast_to(jnp.eye(b, dtype=a.dtype), a.shape)  # noqa: E731
    rev = slice(M - 1, m, -1)
    chains = (jnp.stack([D[:m], dummy(D[rev], eye)]), jnp.stack([Lo[:m], dummy(Up[rev], jnp.zeros_like)]),
              jnp.stack([Up[:m], dummy(Lo[rev], jnp.zeros_like)]), jnp.stack([r[:m], dummy(r[rev], jnp.zeros_like)]))
    W, y = jax.vmap(_eliminate)(*chains)  # (2, m, b, b), (2, m, b, k)
    S = D[m] - Lo[m] @ W[0, -1] - Up[m] @ W[1, -1]
    x_m = _spd_solve(S[None], (r[m] - Lo[m] @ y[0, -1] - Up[m] @ y[1, -1])[None])[0]
    x = jax.vmap(_substitute, in_axes=(0, 0, None))(W, y, x_m)  # (2, m, b, k)
    return jnp.concatenate([x[0], x_m[None], x[1, pad:][::-1]])


def band_solve(D, Lo, r, how: str):
    """The SPD block-tridiagonal solve by `how` = "twisted" or "thomas" (SolverConfig.band_solver)."""
    if how == "thomas":
        return thomas_solve(D, Lo, r)
    if how == "twisted":
        return twisted_solve(D, Lo, r)
    raise ValueError(f"band_solver must be 'twisted' or 'thomas', got {how!r}")


def solve_banded(blocks: jax.Array, g: jax.Array, damp: jax.Array, lay: BandLayout, how: str = "thomas") -> jax.Array:
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
    Lo = jnp.concatenate([jnp.zeros_like(C[:1]), C[:-1]])  # A[i, i-1] = C[i-1]
    x = band_solve(D, Lo, rhs, how)
    return x.reshape(-1)[: 3 * nv].reshape(nv, 3)
