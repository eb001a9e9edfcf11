"""Checks that a pose graph can be solved: shapes, finite values, positive-definite
information, edge indices in range and a connected graph. Raises RhamlError naming the culprit."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import RhamlError, check_shape

__all__ = ["validate_graph"]


def validate_graph(graph, name: str = "pose graph", edge_lines: np.ndarray | None = None) -> None:
    N, E = graph.poses.shape[0], graph.edges.shape[0]

    def at(k: int) -> str:
        if edge_lines is not None and len(edge_lines) == E:
            return f"{name}:{int(edge_lines[k])}: edge {int(graph.ids[graph.edges[k, 0]])} {int(graph.ids[graph.edges[k, 1]])}"
        return f"{name}: edge {k}"

    check_shape(f"{name}: poses", graph.poses, (None, 3))
    check_shape(f"{name}: edges", graph.edges, (None, 2))
    check_shape(f"{name}: measurements", graph.measurements, (E, 3))
    check_shape(f"{name}: information", graph.information, (E, 3, 3))
    check_shape(f"{name}: ids", graph.ids, (N,))
    if N < 2 or E < 1:
        raise RhamlError(f"{name}: needs at least 2 poses and 1 edge, got {N} and {E}")
    if not 0 <= graph.fixed < N:
        raise RhamlError(f"{name}: fixed node index {graph.fixed} out of range [0, {N})")
    bad = ~np.isfinite(graph.poses).all(axis=1)
    if bad.any():
        raise RhamlError(f"{name}: pose of vertex {int(graph.ids[np.flatnonzero(bad)[0]])} is not finite (NaN or Inf)")
    e = np.asarray(graph.edges)
    out = (e < 0) | (e >= N)
    if out.any():
        k = int(np.flatnonzero(out.any(axis=1))[0])
        raise RhamlError(f"{name}: edge {k} refers to node index {int(e[k][out[k]][0])}, which does not exist (N = {N})")
    loops = e[:, 0] == e[:, 1]
    if loops.any():
        raise RhamlError(f"{at(int(np.flatnonzero(loops)[0]))}: connects a node to itself")
    for field, arr in (("measurement", graph.measurements), ("information", graph.information)):
        fin = np.isfinite(arr.reshape(E, -1)).all(axis=1)
        if not fin.all():
            raise RhamlError(f"{at(int(np.flatnonzero(~fin)[0]))}: {field} is not finite (NaN or Inf)")
    L = np.asarray(graph.information, dtype=np.float64)
    asym = np.abs(L - np.swapaxes(L, 1, 2)).max(axis=(1, 2)) > 1e-9 * np.abs(L).max(axis=(1, 2))
    if asym.any():
        raise RhamlError(f"{at(int(np.flatnonzero(asym)[0]))}: information matrix is not symmetric")
    eig = np.linalg.eigvalsh(L)
    notpd = eig[:, 0] <= 1e-12 * np.maximum(eig[:, -1], 0.0)
    notpd |= eig[:, -1] <= 0
    if notpd.any():
        k = int(np.flatnonzero(notpd)[0])
        raise RhamlError(
            f"{at(k)}: information matrix is not positive definite (eigenvalues {np.array2string(eig[k], precision=4)})"
        )
    adj = sp.coo_matrix((np.ones(E), (e[:, 0], e[:, 1])), shape=(N, N))
    ncomp, label = connected_components(adj, directed=False)
    if ncomp > 1:
        lost = np.flatnonzero(label != label[graph.fixed])
        raise RhamlError(
            f"{name}: graph is disconnected ({ncomp} components): vertex {int(graph.ids[lost[0]])} "
            f"and {lost.size - 1} more cannot be reached from the fixed vertex {int(graph.ids[graph.fixed])}"
        )
