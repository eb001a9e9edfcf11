"""Chordal initialisation (beyond the paper): rotations, then translations, each by linear
least squares, for pose graphs whose odometry guess is poor (MITb).

1. Rotations as unit complex numbers q_i = cos + i sin: every edge asks q_j = q_i w_ij with
   w_ij = exp(i dtheta_ij), linear in (cos_i, sin_i); weighted by the rotational information
   and solved with the fixed node's rotation held; each q_i is then normalised.
2. Translations with those rotations: t_j - t_i = R_i dt_ij, weighted by the mean of the
   translational information's diagonal, with the fixed node's translation held.
Both sparse normal equations are solved on the host by SciPy.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._types import PoseGraph

__all__ = ["chordal_initialization"]


def _solve_fixed(rows, cols, vals, rhs, weights, n, fixed_vars, fixed_vals):
    """min sum w (A x - b)^2 with x[fixed_vars] = fixed_vals; A given as COO triplets."""
    A = sp.csr_matrix((vals, (rows, cols)), shape=(rhs.size, n))
    free = np.ones(n, bool)
    free[fixed_vars] = False
    x = np.zeros(n)
    x[fixed_vars] = fixed_vals
    b = rhs - A[:, ~free] @ x[~free]
    Af = A[:, free]
    W = sp.diags(weights)
    H = (Af.T @ W @ Af).tocsc()
    x[free] = spla.spsolve(H, Af.T @ (weights * b))
    return x


def chordal_initialization(graph: PoseGraph) -> np.ndarray:
    """(N, 3) initial poses (x, y, theta); the fixed node keeps its pose."""
    N, E = graph.num_nodes, graph.num_edges
    i, j = graph.edges[:, 0].astype(np.int64), graph.edges[:, 1].astype(np.int64)
    z = graph.measurements
    cw, sw = np.cos(z[:, 2]), np.sin(z[:, 2])
    f = graph.fixed
    wr = np.maximum(graph.information[:, 2, 2], 1e-12)
    # variables: c_k at 2k, s_k at 2k+1; residual rows 2e (cos) and 2e+1 (sin):
    # c_j - (c_i cw - s_i sw) and s_j - (s_i cw + c_i sw)
    e = np.arange(E)
    rows = np.concatenate([2 * e, 2 * e, 2 * e, 2 * e + 1, 2 * e + 1, 2 * e + 1])
    cols = np.concatenate([2 * j, 2 * i, 2 * i + 1, 2 * j + 1, 2 * i + 1, 2 * i])
    vals = np.concatenate([np.ones(E), -cw, sw, np.ones(E), -cw, -sw])
    th_f = graph.poses[f, 2]
    q = _solve_fixed(rows, cols, vals, np.zeros(2 * E), np.repeat(wr, 2), 2 * N,
                     np.array([2 * f, 2 * f + 1]), np.array([np.cos(th_f), np.sin(th_f)]))
    theta = np.arctan2(q[1::2], q[0::2])
    ci, si = np.cos(theta[i]), np.sin(theta[i])
    rx = ci * z[:, 0] - si * z[:, 1]
    ry = si * z[:, 0] + ci * z[:, 1]
    wt = np.maximum(0.5 * (graph.information[:, 0, 0] + graph.information[:, 1, 1]), 1e-12)
    rows = np.concatenate([2 * e, 2 * e, 2 * e + 1, 2 * e + 1])
    cols = np.concatenate([2 * j, 2 * i, 2 * j + 1, 2 * i + 1])
    vals = np.concatenate([np.ones(E), -np.ones(E), np.ones(E), -np.ones(E)])
    rhs = np.stack([rx, ry], 1).reshape(-1)
    t = _solve_fixed(rows, cols, vals, rhs, np.repeat(wt, 2), 2 * N, np.array([2 * f, 2 * f + 1]),
                     graph.poses[f, :2])
    out = np.stack([t[0::2], t[1::2], theta], 1)
    out[f] = graph.poses[f]
    return out
