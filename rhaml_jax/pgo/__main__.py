"""`python -m rhaml_jax.pgo IN.g2o [--out OUT.g2o] [--method gn|lm]`: solves a 2D g2o pose graph.

Prints one JSON line: initial_cost, final_cost (GTSAM's 0.5 sum r^T Lambda r with
r = Log(z^-1 x_i^-1 x_j)), iterations, seconds (the compiled solve), compile_seconds, and a
few more fields (converged, accepted, nodes, edges, linear_solver, method, init).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Annotated, Literal

import tyro

from ..errors import RhamlError, run_cli


@dataclasses.dataclass(frozen=True)
class Args:
    """Solve a 2D pose graph in g2o format (VERTEX_SE2 / EDGE_SE2) with the first pose fixed."""

    graph: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="IN.g2o")]
    """input g2o file; without VERTEX_SE2 lines the initial guess chains the edges"""
    out: Path | None = None
    """write the optimised graph here (g2o: the optimised VERTEX_SE2 lines and the same edges)"""
    method: Literal["gn", "lm"] = "gn"
    """gn: Gauss-Newton, damped only when a step fails; lm: Levenberg-Marquardt from the start"""
    init: Literal["given", "chordal"] = "given"
    """initial guess: the file's vertices (or chained edges), or chordal relaxation"""
    robust: Literal["none", "huber", "cauchy"] = "none"
    """robust kernel on every edge's Mahalanobis norm (the cost printed is then the robust one)"""
    robust_delta: float = 1.345
    """robust kernel threshold in standard deviations"""
    linear_solver: Literal["auto", "dense", "banded", "sparse"] = "auto"
    """normal-equation solver; auto: banded for chain-like graphs, dense when small, else sparse"""
    max_iterations: int = 100
    """maximum number of linear solves"""
    relative_tolerance: float = 1e-9
    """stop when a step lowers the cost by less than this fraction"""
    float32: bool = False
    """compute in float32 (default float64)"""


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    import jax

    jax.config.update("jax_enable_x64", not args.float32)
    from . import SolverConfig, optimize, read_g2o, write_g2o

    if not args.graph.is_file():
        raise RhamlError(f"{args.graph}: no such g2o file")
    if args.robust_delta <= 0:
        raise RhamlError(f"--robust-delta: must be > 0, got {args.robust_delta}")
    if args.max_iterations < 1:
        raise RhamlError(f"--max-iterations: must be >= 1, got {args.max_iterations}")
    graph = read_g2o(args.graph)
    cfg = SolverConfig(method=args.method, max_iterations=args.max_iterations,
                       relative_tolerance=args.relative_tolerance, linear_solver=args.linear_solver,
                       robust=args.robust, robust_delta=args.robust_delta, initialization=args.init)
    res = optimize(graph, cfg)
    if args.out is not None:
        write_g2o(args.out, graph, res.poses)
    report = {
        "initial_cost": res.initial_cost,
        "final_cost": res.final_cost,
        "iterations": res.iterations,
        "seconds": res.seconds,
        "compile_seconds": res.compile_seconds,
        "converged": res.converged,
        "accepted": res.accepted,
        "nodes": graph.num_nodes,
        "edges": graph.num_edges,
        "linear_solver": res.linear_solver + (" (reverse Cuthill-McKee node order)" if res.reordered else ""),
        "method": args.method,
        "init": args.init,
    }
    print(json.dumps(report))
    return report


if __name__ == "__main__":
    run_cli(main)
