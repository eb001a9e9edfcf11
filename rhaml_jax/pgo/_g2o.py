"""g2o 2D pose graphs: VERTEX_SE2 / EDGE_SE2 (and FIX) read and write.

`EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33` carries the upper triangle of the
information matrix row by row. A file without vertices (CSAIL, KITTI) gets a chained initial
guess: edges are walked in file order, the first pose at the identity, each edge placing
an unknown end from its known one (x_j = x_i z or x_i = x_j z^-1), repeated until every node
is placed. Vertex angles need not be wrapped (ring.g2o).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rhaml_jax.planar import wrap_angle
from ..errors import RhamlError
from ._types import PoseGraph
from ._validate import validate_graph

__all__ = ["read_g2o", "write_g2o", "parse_g2o", "format_g2o"]

_UPPER = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


def _floats(tokens: list[str], where: str, field: str) -> list[float]:
    try:
        vals = [float(t) for t in tokens]
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise RhamlError(f"{where}: {field}: {bad!r} is not a number") from None
    if not all(math.isfinite(v) for v in vals):
        raise RhamlError(f"{where}: {field}: non-finite value (NaN or Inf) in {' '.join(tokens)}")
    return vals


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


def _int(token: str, where: str, field: str) -> int:
    try:
        return int(token)
    except ValueError:
        raise RhamlError(f"{where}: {field}: {token!r} is not an integer vertex id") from None


def parse_g2o(text: str, name: str = "<g2o>") -> PoseGraph:
    """Parses g2o text; errors name `name:line`. Checks the graph (see validate_graph)."""
    vertex: dict[int, tuple[float, float, float]] = {}
    vertex_line: dict[int, int] = {}
    ei: list[int] = []
    ej: list[int] = []
    meas: list[list[float]] = []
    info: list[list[float]] = []
    lines: list[int] = []
    fixed_id: int | None = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tok = line.split()
        tag, where = tok[0], f"{name}:{lineno}"
        if tag == "VERTEX_SE2":
            if len(tok) != 5:
                raise RhamlError(f"{where}: VERTEX_SE2 needs 'id x y theta' (4 values), got {len(tok) - 1}")
            vid = _int(tok[1], where, "VERTEX_SE2 id")
            if vid in vertex:
                raise RhamlError(f"{where}: VERTEX_SE2 {vid} defined twice (first on line {vertex_line[vid]})")
            x, y, t = _floats(tok[2:5], where, f"VERTEX_SE2 {vid} pose")
            vertex[vid] = (x, y, t)
            vertex_line[vid] = lineno
        elif tag == "EDGE_SE2":
            if len(tok) != 12:
                raise RhamlError(
                    f"{where}: EDGE_SE2 needs 'i j dx dy dtheta I11 I12 I13 I22 I23 I33' (11 values), got {len(tok) - 1}"
                )
            a = _int(tok[1], where, "EDGE_SE2 from-id")
            b = _int(tok[2], where, "EDGE_SE2 to-id")
            if a == b:
                raise RhamlError(f"{where}: EDGE_SE2 {a} {b} connects a vertex to itself")
            ei.append(a)
            ej.append(b)
            meas.append(_floats(tok[3:6], where, f"EDGE_SE2 {a} {b} measurement"))
            info.append(_floats(tok[6:12], where, f"EDGE_SE2 {a} {b} information"))
            lines.append(lineno)
        elif tag == "FIX":
            if len(tok) < 2:
                raise RhamlError(f"{where}: FIX needs a vertex id")
            fixed_id = _int(tok[1], where, "FIX id")
        else:
            raise RhamlError(f"{where}: unsupported g2o tag {tag!r} (2D graphs: VERTEX_SE2, EDGE_SE2, FIX)")
    if not ei:
        raise RhamlError(f"{name}: no EDGE_SE2 lines: not a 2D g2o pose graph")
    E = len(ei)
    Lam = np.zeros((E, 3, 3))
    upper = np.asarray(info, dtype=np.float64)
    for k, (r, c) in enumerate(_UPPER):
        Lam[:, r, c] = upper[:, k]
        Lam[:, c, r] = upper[:, k]
    z = np.asarray(meas, dtype=np.float64).reshape(E, 3)
    if vertex:
        for k, (a, b) in enumerate(zip(ei, ej)):
            for v in (a, b):
                if v not in vertex:
                    raise RhamlError(f"{name}:{lines[k]}: EDGE_SE2 {a} {b} refers to vertex {v}, which has no VERTEX_SE2 line")
        ids = np.array(sorted(vertex), dtype=np.int64)
        poses = np.array([vertex[v] for v in ids], dtype=np.float64).reshape(-1, 3)
    else:
        ids = np.array(sorted(set(ei) | set(ej)), dtype=np.int64)
        poses = None
    index = {int(v): k for k, v in enumerate(ids)}
    edges = np.array([[index[a], index[b]] for a, b in zip(ei, ej)], dtype=np.int32)
    fixed = 0
    if fixed_id is not None:
        if fixed_id not in index:
            raise RhamlError(f"{name}: FIX {fixed_id} names a vertex that does not exist")
        fixed = index[fixed_id]
    elif not vertex:
        fixed = index[ei[0]]
    if poses is None:
        poses = chain_initial_guess(len(ids), edges, z, root=fixed, name=name, ids=ids)
    graph = PoseGraph(poses, edges, z, Lam, ids, fixed)
    validate_graph(graph, name=name, edge_lines=np.asarray(lines))
    return graph


def chain_initial_guess(n: int, edges: np.ndarray, z: np.ndarray, root: int, name: str, ids) -> np.ndarray:
    """Places every node by composing edges outward from `root` (file order, repeated)."""
    poses = np.zeros((n, 3))
    known = np.zeros(n, dtype=bool)
    known[root] = True
    while not known.all():
        progress = False
        for k, (a, b) in enumerate(edges):
            if known[a] and not known[b]:
                xa, ya, ta = poses[a]
                ca, sa = math.cos(ta), math.sin(ta)
                poses[b] = (xa + ca * z[k, 0] - sa * z[k, 1], ya + sa * z[k, 0] + ca * z[k, 1], ta + z[k, 2])
                known[b] = progress = True
            elif known[b] and not known[a]:
                xb, yb, tb = poses[b]
                ta = tb - z[k, 2]
                ca, sa = math.cos(ta), math.sin(ta)
                poses[a] = (xb - (ca * z[k, 0] - sa * z[k, 1]), yb - (sa * z[k, 0] + ca * z[k, 1]), ta)
                known[a] = progress = True
        if not progress:
            missing = ids[np.flatnonzero(~known)[0]]
            raise RhamlError(
                f"{name}: graph is disconnected: vertex {missing} (and {int((~known).sum()) - 1} more) "
                f"cannot be reached from vertex {ids[root]}"
            )
    poses[:, 2] = wrap_angle(poses[:, 2])
    return poses


def read_g2o(path: str | Path) -> PoseGraph:
    """Reads a 2D g2o file (see module doc)."""
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise RhamlError(f"{path}: not a text g2o file") from None
    return parse_g2o(text, name=str(path))


def format_g2o(graph: PoseGraph, poses: np.ndarray | None = None) -> str:
    """g2o text of `graph` with `poses` (default: the graph's own) as VERTEX_SE2 lines."""
    poses = graph.poses if poses is None else np.asarray(poses)
    ids = graph.ids
    out = [f"VERTEX_SE2 {int(v)} {p[0]:.17g} {p[1]:.17g} {p[2]:.17g}" for v, p in zip(ids, poses)]
    for (a, b), zz, L in zip(graph.edges, graph.measurements, graph.information):
        up = " ".join(f"{L[r, c]:.17g}" for r, c in _UPPER)
        out.append(f"EDGE_SE2 {int(ids[a])} {int(ids[b])} {zz[0]:.17g} {zz[1]:.17g} {zz[2]:.17g} {up}")
    if graph.fixed != 0:  # the first vertex is every tool's default gauge
        out.append(f"FIX {int(ids[graph.fixed])}")
    return "\n".join(out) + "\n"


def write_g2o(path: str | Path, graph: PoseGraph, poses: np.ndarray | None = None) -> None:
    Path(path).write_text(format_g2o(graph, poses))
