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

__all__ = ["BandLayout", "band_layout", "band_solve", "lapack_solve", "node_bandwidth", "solve_banded", "pcr_solve", "thomas_solve", "twisted_solve"]


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
    """Solves the same SPD block tridiagonal system (Up[i] = Lo[i+1]^T) by block LDL^T: one
    forward and one backward `lax.scan` over the M groups. Fewer operations than
    `pcr_solve` (which is log2 M times the work) but M sequential steps of ~2.2 us of XLA
    kernel overhead each; `twisted_solve` halves their number."""
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


def _band_storage(D, Lo):
    """LAPACK's lower band storage of the SPD block-tridiagonal matrix (NumPy, host side):
    D, Lo (M, b, b) -> (2b, M b) with ab[k, j] = A[j + k, j], half-bandwidth 2b - 1."""
    M, b = D.shape[0], D.shape[-1]
    X = np.concatenate([D, np.concatenate([Lo[1:], np.zeros_like(Lo[:1])])], axis=1)  # (M, 2b, b): A[bi + m, bi + c]
    k, c = np.meshgrid(np.arange(2 * b), np.arange(b), indexing="ij")  # (2b, b)
    ab = np.where(k + c < 2 * b, X[:, np.minimum(k + c, 2 * b - 1), c], 0.0)  # (M, 2b, b); past the matrix: 0
    return np.ascontiguousarray(np.moveaxis(ab, 0, 1).reshape(2 * b, M * b))


def _host_pbsv(D, Lo, r, wide: bool):
    from scipy.linalg import lapack

    if wide:  # float64 travels as uint32 pairs (see `lapack_solve`)
        D, Lo, r = (np.ascontiguousarray(a).view(np.float64)[..., 0] for a in (D, Lo, r))
    M, b, k = r.shape
    pbsv = lapack.dpbsv if wide else lapack.spbsv
    _, x, info = pbsv(_band_storage(D, Lo), r.reshape(M * b, k), lower=1)
    if info != 0:  # not positive definite (or a bad argument): a non-finite step, the solver damps
        x = np.full((M * b, k), np.nan, r.dtype)
    x = x.reshape(M, b, k)
    if wide:
        return np.ascontiguousarray(x, np.float64).view(np.uint32).reshape(*x.shape, 2)
    return np.asarray(x, np.float32)


def lapack_solve(D, Lo, r):
    """Solves the same SPD block tridiagonal system as `thomas_solve` with LAPACK's banded
    Cholesky (?pbsv) on the host, through one `jax.pure_callback` per solve: no per-group
    kernel overhead, but the callback's own (see BENCHMARKS.md for which wins where); on an
    accelerator it also copies the blocks to the host and back. Not differentiable (the
    solver's while loop is not either)."""
    # As in `_linear.solve_sparse`: XLA runs the callback where a caller's `jax.enable_x64`
    # is not active and JAX would cast float64 to float32, so float64 crosses as uint32 pairs.
    wide = r.dtype == jnp.float64
    args = (D, Lo, r)
    out = jax.ShapeDtypeStruct(r.shape, r.dtype)
    if wide:
        args = tuple(jax.lax.bitcast_convert_type(a, jnp.uint32) for a in args)
        out = jax.ShapeDtypeStruct((*r.shape, 2), jnp.uint32)
    x = jax.pure_callback(functools.partial(_host_pbsv, wide=wide), out, *args, vmap_method="sequential")
    return jax.lax.bitcast_convert_type(x, jnp.float64) if wide else x


def band_solve(D, Lo, r, how: str):
    """The SPD block-tridiagonal solve by `how` = "thomas" or "lapack" (SolverConfig.band_solver)."""
    if how == "lapack":
        return lapack_solve(D, Lo, r)
    if how == "thomas":
        return thomas_solve(D, Lo, r)
    if how == "twisted":
        return twisted_solve(D, Lo, r)
    raise ValueError(f"band_solver must be 'twisted', 'thomas' or 'lapack', got {how!r}")


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
