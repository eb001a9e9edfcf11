"""Data types of the pose-graph stage: the graph, the solver's options and its result."""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import numpy as np

__all__ = ["PoseGraph", "SolverConfig", "SolveResult"]


class PoseGraph(NamedTuple):
    """A 2D pose graph with SE(2) nodes and relative-pose edges (host-side numpy arrays).

    Poses are (x, y, theta) in metres and radians; an edge (i, j) with measurement z and
    information Lambda says x_j ~ x_i z, with residual r = Log(z^-1 x_i^-1 x_j).
    """

    poses: np.ndarray  # (N, 3) float: initial guess (x, y, theta) per node
    edges: np.ndarray  # (E, 2) int32: node indices (i, j) into `poses`
    measurements: np.ndarray  # (E, 3) float: z = (dx, dy, dtheta) of x_i^-1 x_j
    information: np.ndarray  # (E, 3, 3) float: symmetric positive definite Lambda per edge
    ids: np.ndarray  # (N,) int64: the node's id in files (g2o vertex id)
    fixed: int = 0  # index of the node held fixed (the gauge)
    robust_edges: np.ndarray | None = None  # (E,) bool: edges the robust kernel applies to (None: all)

    @property
    def num_nodes(self) -> int:
        return int(self.poses.shape[0])

    @property
    def num_edges(self) -> int:
        return int(self.edges.shape[0])


RobustKernel = Literal["none", "huber", "cauchy"]


@dataclasses.dataclass(frozen=True)
class SolverConfig:
    """Options of the Gauss-Newton / Levenberg-Marquardt solver.

    method: "gn" takes plain Gauss-Newton steps and damps (as LM does) only when a step is
        singular, non-finite or does not reduce the cost; "lm" damps from the start.
    linear_solver: "auto" picks "banded" (a block-tridiagonal solve, see `band_solver`) when
        every edge joins nodes at most `banded_max_width` indices apart (chains, the RHAML
        graphs), else "dense" (Cholesky in XLA) up to `dense_max_nodes` nodes and "sparse"
        (block-sparse normal equations factored by QDLDL on the host through a callback, AMD
        ordering and symbolic analysis once per graph) above.
    band_solver: how the "banded" path solves its block-tridiagonal system by block LDL^T in
        XLA: "twisted" (from both ends at once, half the sequential steps) or "thomas" (one
        direction); see `_banded`.
    damping: what a damped step adds to H: lambda I ("identity", GTSAM's default) or
        lambda diag(H) ("diagonal", Marquardt's). On MITb with LM the first takes GTSAM's 17
        steps and the second 96 solves to the same local minimum (BENCHMARKS.md).
    robust: "none", "huber" or "cauchy" on the Mahalanobis norm s = sqrt(r^T Lambda r),
        with threshold `robust_delta` (in units of standard deviations), solved by IRLS.
    Stops when the cost decrease is below `relative_tolerance` * cost or below
    `absolute_tolerance` (either floored at the cost's rounding error, 64 eps * cost: in
    float32 about 8e-6 relative), or after `max_iterations` linear solves, or when the damping
    exceeds `max_lambda` (no step reduces the cost any more).
    """

    method: Literal["gn", "lm"] = "gn"
    max_iterations: int = 100
    relative_tolerance: float = 1e-9
    absolute_tolerance: float = 1e-12
    lambda_initial: float = 1e-5
    damping: Literal["identity", "diagonal"] = "identity"
    lambda_factor: float = 10.0
    max_lambda: float = 1e10
    linear_solver: Literal["auto", "dense", "banded", "sparse"] = "auto"
    dense_max_nodes: int = 100
    banded_max_width: int = 4
    band_solver: Literal["twisted", "thomas"] = "twisted"
    robust: RobustKernel = "none"
    robust_delta: float = 1.345
    initialization: Literal["given", "chordal"] = "given"


class SolveResult(NamedTuple):
    """What `optimize` returns (host-side)."""

    poses: np.ndarray  # (N, 3) float: optimised (x, y, theta), theta wrapped to (-pi, pi]
    initial_cost: float  # 0.5 sum rho(r^T Lambda r) at the initial guess
    final_cost: float  # the same at the result
    iterations: int  # linear solves (accepted or rejected steps)
    accepted: int  # accepted steps
    converged: bool  # a tolerance was met (not max_iterations)
    seconds: float  # wall time of the compiled solve
    compile_seconds: float  # wall time of tracing + compiling (0 when cached)
    linear_solver: str = ""  # the linear solver used ("banded", "dense", "sparse"; "auto" resolved)
    reordered: bool = False  # solved in a reverse Cuthill-McKee node order (poses are in the caller's)
