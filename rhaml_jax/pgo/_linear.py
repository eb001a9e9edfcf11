"""Linear solvers for the damped normal equations (H + lambda D) delta = -g.

- dense: the block matrix is scattered into a (3n, 3n) array and factored by XLA's Cholesky;
  fastest for small graphs (the RHAML two-robot graphs).
- sparse: the upper block triangle is laid out as a CSC matrix (the layout is computed once
  per graph on the host) and factored on the host by QDLDL (AMD ordering and symbolic
  analysis on the first call, numeric refactorisation afterwards) through `jax.pure_callback`,
  so the whole solver stays one jit-compiled while loop.

A failed factorisation gives a non-finite step, which the solver rejects and damps.
"""

from __future__ import annotations

import collections
import functools
import itertools
import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from ._normal_equations import BlockStructure, dense_matrix

__all__ = ["SparseLayout", "sparse_layout", "solve_dense", "solve_sparse"]


def solve_dense(blocks: jax.Array, g: jax.Array, damp: jax.Array, s: BlockStructure) -> jax.Array:
    """blocks (B, 3, 3), g (nv, 3), damp (nv, 3) added to the diagonal -> delta (nv, 3)."""
    H = dense_matrix(blocks, s)
    H = H + jnp.diag(damp.reshape(-1))
    L = jnp.linalg.cholesky(H)
    x = jax.scipy.linalg.cho_solve((L, True), -g.reshape(-1))
    return x.reshape(g.shape)


class SparseLayout(NamedTuple):
    """CSC layout of H's upper triangle, as gathers from the flattened (B*9,) blocks."""

    src: jax.Array  # (nnz,) int32: index into blocks.reshape(-1) for each CSC entry
    token: jax.Array  # () int32: key of the host-side pattern and factorisation cache


class _Pattern:
    def __init__(self, n: int, indptr: np.ndarray, indices: np.ndarray):
        self.n, self.indptr, self.indices = n, indptr, indices
        self.nnz = int(indices.size)
        self.solver = None
        self.lock = threading.Lock()


_PATTERNS: "collections.OrderedDict[int, _Pattern]" = collections.OrderedDict()
_TOKENS = itertools.count(1)
_MAX_PATTERNS = 16


def sparse_layout(s: BlockStructure, nnz_capacity: int | None = None) -> SparseLayout:
    """Host side: the CSC order of every upper-triangle entry and a registered pattern.
    `nnz_capacity` pads the gather (so graphs of similar size share one compiled solver)."""
    nv = int(np.asarray(s.var_of_node).shape[0]) - 1
    r = np.asarray(s.block_row, dtype=np.int64)
    c = np.asarray(s.block_col, dtype=np.int64)
    B = r.size
    p, q = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    rows = 3 * r[:, None, None] + p  # (B, 3, 3)
    cols = 3 * c[:, None, None] + q
    src = np.arange(B * 9).reshape(B, 3, 3)
    keep = rows <= cols
    rows, cols, src = rows[keep], cols[keep], src[keep]
    order = np.lexsort((rows, cols))
    rows, cols, src = rows[order], cols[order], src[order]
    n = 3 * nv
    indptr = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=n))]).astype(np.int64)
    token = next(_TOKENS)
    _PATTERNS[token] = _Pattern(n, indptr, rows.astype(np.int64))
    while len(_PATTERNS) > _MAX_PATTERNS:
        _PATTERNS.popitem(last=False)
    if nnz_capacity is not None and nnz_capacity > src.size:
        src = np.concatenate([src, np.zeros(nnz_capacity - src.size, src.dtype)])
    return SparseLayout(np.asarray(src, np.int32), np.asarray(token, np.int32))


def _host_factor_solve(token, data, rhs, wide: bool):
    import qdldl

    if wide:  # float64 travels as uint32 pairs (see solve_sparse)
        data = np.ascontiguousarray(data).view(np.float64)[..., 0]
        rhs = np.ascontiguousarray(rhs).view(np.float64)[..., 0]
    pat = _PATTERNS[int(token)]
    n = pat.n
    A = sp.csc_matrix((np.asarray(data[: pat.nnz], np.float64), pat.indices, pat.indptr), shape=(n, n))
    b = np.asarray(rhs, np.float64)
    with pat.lock:
        try:
            if pat.solver is None:
                pat.solver = qdldl.Solver(A, upper=True)
            else:
                pat.solver.update(A, upper=True)
            x = pat.solver.solve(b)
        except Exception:  # singular pivot: report a non-finite step, the solver damps
            pat.solver = None
            x = np.full_like(b, np.nan)
    if wide:
        return np.ascontiguousarray(x, np.float64).view(np.uint32).reshape(-1, 2)
    return np.asarray(x, dtype=np.float32)


def solve_sparse(blocks: jax.Array, g: jax.Array, damp: jax.Array, layout: SparseLayout) -> jax.Array:
    nv = g.shape[0]
    blocks = blocks.at[jnp.arange(nv), jnp.arange(3)[:, None], jnp.arange(3)[:, None]].add(damp.T)
    data = blocks.reshape(-1)[layout.src]
    rhs = -g.reshape(-1)
    # XLA runs the callback on a thread where a caller's `jax.enable_x64` context is not
    # active, and JAX would cast float64 arguments and results to float32 there: float64
    # crosses as bit-identical uint32 pairs instead.
    wide = rhs.dtype == jnp.float64
    if wide:
        data = jax.lax.bitcast_convert_type(data, jnp.uint32)  # (nnz, 2)
        rhs = jax.lax.bitcast_convert_type(rhs, jnp.uint32)
        out = jax.ShapeDtypeStruct(rhs.shape, jnp.uint32)
    else:
        out = jax.ShapeDtypeStruct(rhs.shape, rhs.dtype)
    x = jax.pure_callback(functools.partial(_host_factor_solve, wide=wide), out, layout.token, data, rhs,
                          vmap_method="sequential")
    if wide:
        x = jax.lax.bitcast_convert_type(x, jnp.float64)
    return x.reshape(g.shape)
