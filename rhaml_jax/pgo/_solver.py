"""Gauss-Newton / Levenberg-Marquardt on SE(2) as one jit-compiled `lax.while_loop`.

Each iteration solves (H + lambda D) delta = -g, D = diag(H) (floored), retracts
x <- x Exp(delta) on every free node, and accepts the step only when the new cost is finite
and lower. A rejected step (including a singular or non-finite one) raises lambda by
`lambda_factor`; in "gn" mode lambda starts at 0 and falls back to 0 once steps succeed again.
The cost is GTSAM's: 0.5 sum_e rho(r_e^T Lambda_e r_e), r_e = Log(z_e^-1 x_i^-1 x_j).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ..errors import RhamlError
from ._banded import BandLayout, band_layout, node_bandwidth, solve_banded
from ._linear import SparseLayout, solve_dense, solve_sparse, sparse_layout
from ._normal_equations import BlockStructure, assemble, block_structure
from ._residuals import linearize, poses_to_se2, residuals, retract, se2_to_poses
from ._robust import robust_rho_and_weight
from ._types import PoseGraph, SolverConfig, SolveResult

__all__ = ["optimize", "graph_cost", "Problem", "make_problem", "solve_problem"]


class Problem(NamedTuple):
    """Device-side arrays of one graph (a pytree)."""

    T0: jax.Array  # (N, 4) initial poses as jaxlie SE2 parameters (cos, sin, x, y)
    Z_inv: jax.Array  # (E, 4) inverse measurements as SE2 parameters
    ei: jax.Array  # (E,) int32
    ej: jax.Array  # (E,) int32
    info: jax.Array  # (E, 3, 3)
    robust_edges: jax.Array  # (E,) bool: the robust kernel applies (else plain squares)
    struct: BlockStructure
    layout: SparseLayout | None  # for the "sparse" linear solver
    band: BandLayout | None  # for the "banded" linear solver


class _State(NamedTuple):
    T: jax.Array  # (N, 4)
    system: object  # the normal equations at T (solver-specific pytree)
    cost0: jax.Array  # () the initial cost
    cost: jax.Array  # ()
    lam: jax.Array  # ()
    it: jax.Array  # () int32
    accepted: jax.Array  # () int32
    done: jax.Array  # () bool
    converged: jax.Array  # () bool


def _cost(T, p: Problem, cfg: SolverConfig):
    r = residuals(T, p.Z_inv, p.ei, p.ej)
    s2 = jnp.einsum("ea,eab,eb->e", r, p.info, r)
    rho, _ = _rho_w(s2, p, cfg)
    return 0.5 * jnp.sum(rho)


def _rho_w(s2, p: Problem, cfg: SolverConfig):
    rho, w = robust_rho_and_weight(s2, cfg.robust, cfg.robust_delta)
    if cfg.robust == "none":
        return rho, w
    return jnp.where(p.robust_edges, rho, s2), jnp.where(p.robust_edges, w, 1.0)


def _normal_eqs(T, p: Problem, cfg: SolverConfig):
    lin = linearize(T, p.Z_inv, p.ei, p.ej)
    s2 = jnp.einsum("ea,eab,eb->e", lin.r, p.info, lin.r)
    rho, w = _rho_w(s2, p, cfg)
    blocks, g = assemble(lin, w[:, None, None] * p.info, p.struct)
    return blocks, g, 0.5 * jnp.sum(rho)


def lm_loop(T0, linearize_fn, solve_fn, cfg: SolverConfig):
    """The GN / LM loop as one `lax.while_loop`; traceable.

    linearize_fn(T) -> (system, cost): the normal equations at T (any pytree) and the cost
    there, from the same residuals; solve_fn(system, lam) -> (delta (N, 3) per node, zero on
    the gauge; g . delta; sum damp delta^2). Each iteration solves the carried system, retracts
    and linearises once at the candidate, which gives its cost too: one residual evaluation
    per iteration and a single copy of the residual code in the loop (compile time). A
    rejected candidate's system is dropped. Returns (final state, initial cost)."""
    dt = T0.dtype
    lam0 = jnp.asarray(cfg.lambda_initial if cfg.method == "lm" else 0.0, dt)
    # iteration 0 only linearises at T0 (its solve is skipped by `lax.cond`), so the residual
    # code appears once in the program
    sys_shape, _ = jax.eval_shape(linearize_fn, T0)
    sys_init = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), sys_shape)
    n = T0.shape[0]

    def body(s: _State) -> _State:
        first = s.it == 0
        delta, g_delta, damp_dd = jax.lax.cond(
            first, lambda: (jnp.zeros((n, 3), dt), jnp.zeros((), dt), jnp.zeros((), dt)),
            lambda: solve_fn(s.system, s.lam))
        step_ok = jnp.all(jnp.isfinite(delta))
        delta = jnp.where(step_ok, delta, 0.0)
        T_new = jnp.where(first, s.T, retract(s.T, delta))
        sys_new, cost_new = linearize_fn(T_new)
        gd = -jnp.where(step_ok, g_delta, 0.0)  # > 0 for a descent direction
        predicted = 0.5 * gd + 0.5 * jnp.where(step_ok, damp_dd, 0.0)  # decrease of the local model
        ok = step_ok & jnp.isfinite(cost_new) & (cost_new < s.cost) & (gd > 0)
        # the cost itself is only known to about `noise` (its rounding error), so no tolerance
        # below it can be met: float32 would otherwise count rounding as failed steps and
        # raise the damping until max_lambda
        noise = 64 * jnp.finfo(dt).eps * s.cost
        tol = jnp.maximum(jnp.maximum(cfg.relative_tolerance * s.cost, cfg.absolute_tolerance), noise)
        small = ok & (s.cost - cost_new <= tol)
        # a (nearly) undamped finite step that cannot decrease the cost by more than the
        # tolerance: we are at the minimum already (rounding makes such steps fail)
        flat = step_ok & ~ok & (predicted <= tol) & (s.lam <= cfg.lambda_initial if cfg.method == "gn" else True)
        ok = ok | first
        T = jnp.where(ok, T_new, s.T)
        system = jax.tree.map(lambda a, b: jnp.where(ok, a, b), sys_new, s.system)
        cost = jnp.where(ok, cost_new, s.cost)
        lam_up = jnp.where(s.lam > 0, s.lam * cfg.lambda_factor, jnp.asarray(cfg.lambda_initial, dt))
        lam_down = s.lam / cfg.lambda_factor
        if cfg.method == "gn":
            lam_down = jnp.where(lam_down < cfg.lambda_initial, 0.0, lam_down)
        lam = jnp.where(first, s.lam, jnp.where(ok, lam_down, lam_up))
        it = s.it + 1
        converged = ~first & (small | flat | (lam > cfg.max_lambda))
        done = converged | (it > cfg.max_iterations) | (first & ~jnp.isfinite(cost_new))
        return _State(T, system, jnp.where(first, cost_new, s.cost0), cost, lam, it,
                      s.accepted + (ok & ~first).astype(jnp.int32), done, converged)

    inf = jnp.asarray(jnp.inf, dt)
    init = _State(T0, sys_init, inf, inf, lam0, jnp.asarray(0, jnp.int32), jnp.asarray(0, jnp.int32),
                  jnp.asarray(False), jnp.asarray(False))
    s = jax.lax.while_loop(lambda s: ~s.done, body, init)
    return s._replace(it=s.it - 1), s.cost0


def damping(diag, lam, mode: str = "identity"):
    """What LM adds to diag(H): lam (mode "identity", GTSAM's default) or lam * diag(H) (mode
    "diagonal", Marquardt's scaling), the latter floored at 1e-9 max diag(H) per entry (so a
    zero pivot still gets damped)."""
    if mode == "identity":
        return jnp.full_like(diag, 1.0) * lam
    floor = 1e-9 * jnp.max(diag) + jnp.finfo(diag.dtype).tiny
    return lam * jnp.maximum(diag, floor)


def _iterate(p: Problem, cfg: SolverConfig, linear: str):
    """The solver loop; traceable (usable inside a caller's jit). Returns (state, cost0)."""
    dt = p.T0.dtype
    nv = p.struct.var_of_node.shape[0] - 1

    def lin(T):
        blocks, g, cost = _normal_eqs(T, p, cfg)
        return (blocks, g), cost

    def solve(system, lam):
        blocks, g = system
        damp = damping(jnp.diagonal(blocks[:nv], axis1=-2, axis2=-1), lam, cfg.damping)  # (nv, 3)
        if linear == "dense":
            delta = solve_dense(blocks, g, damp, p.struct)
        elif linear == "banded":
            delta = solve_banded(blocks, g, damp, p.band, cfg.band_solver)
        else:
            delta = solve_sparse(blocks, g, damp, p.layout)
        full = jnp.concatenate([delta, jnp.zeros((1, 3), dt)])[p.struct.var_of_node]  # (N, 3)
        return full, jnp.sum(g * delta), jnp.sum(damp * delta * delta)

    return lm_loop(p.T0, lin, solve, cfg)


def _run(p: Problem, cfg: SolverConfig, linear: str):
    s, cost0 = _iterate(p, cfg, linear)
    return s.T, cost0, s.cost, s.it, s.accepted, s.converged


_run_jit = jax.jit(_run, static_argnames=("cfg", "linear"))


def _bucket(n: int) -> int:
    """Smallest power of two >= n (at least 64)."""
    return max(64, 1 << (int(n) - 1).bit_length())


def pad_graph(graph: PoseGraph) -> PoseGraph:
    """Pads nodes and edges to bucket sizes so graphs of similar size share one compiled
    solver: each extra node sits on the fixed node, tied to it by an identity edge with unit
    information; extra edges beyond those are fixed-to-fixed with zero information. Neither
    changes the cost, the optimum or the other nodes' steps."""
    N, E, f = graph.num_nodes, graph.num_edges, graph.fixed
    Np = _bucket(N)
    Ep = _bucket(E + (Np - N))
    extra = np.arange(N, Np)
    e_tie = np.stack([np.full(extra.size, f), extra], 1)
    e_nil = np.full((Ep - E - extra.size, 2), f)
    info = np.zeros((Ep - E, 3, 3))
    info[: extra.size] = np.eye(3)
    robust = np.ones(E, bool) if graph.robust_edges is None else np.asarray(graph.robust_edges, bool)
    return PoseGraph(
        np.concatenate([graph.poses, np.repeat(graph.poses[f : f + 1], Np - N, 0)]),
        np.concatenate([graph.edges, e_tie, e_nil]).astype(np.int32),
        np.concatenate([graph.measurements, np.zeros((Ep - E, 3))]),
        np.concatenate([graph.information, info]),
        np.concatenate([graph.ids, -1 - np.arange(Np - N)]), f,
        np.concatenate([robust, np.zeros(Ep - E, bool)]))


def _pad_structure(struct: BlockStructure) -> BlockStructure:
    """Pads the block list to N + E blocks (an upper bound), so the padded sizes depend on the
    node and edge buckets only."""
    B = struct.block_row.shape[0]
    Bp = struct.var_of_node.shape[0] + struct.slot_ii.shape[0]
    z = np.zeros(Bp - B, np.int32)
    slot = lambda a: np.where(a >= B, Bp, a).astype(np.int32)  # noqa: E731  trash slot moves to Bp
    return struct._replace(block_row=np.concatenate([struct.block_row, z]),
                           block_col=np.concatenate([struct.block_col, z]),
                           slot_ii=slot(struct.slot_ii), slot_jj=slot(struct.slot_jj), slot_ij=slot(struct.slot_ij))


def make_problem(graph: PoseGraph, linear: str = "dense", dtype=None) -> Problem:
    """Moves a graph to device arrays and computes its block sparsity (host). For the sparse
    solver the graph is padded to bucket sizes first (see `pad_graph`)."""
    dtype = dtype or jnp.result_type(float)
    if linear == "sparse":
        graph = pad_graph(graph)
    struct = block_structure(graph.num_nodes, graph.edges, graph.fixed)
    layout = None
    if linear == "sparse":
        padded = _pad_structure(struct)
        layout = sparse_layout(struct, nnz_capacity=9 * padded.block_row.size)  # true blocks only
        struct = padded
    band = band_layout(struct) if linear == "banded" else None
    T0 = poses_to_se2(jnp.asarray(graph.poses, dtype)).unit_complex_xy
    Z_inv = poses_to_se2(jnp.asarray(graph.measurements, dtype)).inverse().unit_complex_xy
    e = jnp.asarray(graph.edges, jnp.int32)
    return Problem(T0, Z_inv, e[:, 0], e[:, 1], jnp.asarray(graph.information, dtype), _robust_edges(graph),
                   jax.tree.map(jnp.asarray, struct), layout, band)


def _robust_edges(graph: PoseGraph) -> jax.Array:
    if graph.robust_edges is None:
        return jnp.ones(graph.num_edges, bool)
    return jnp.asarray(graph.robust_edges, bool)


def _bandwidth(graph: PoseGraph) -> int:
    return node_bandwidth(block_structure(graph.num_nodes, graph.edges, graph.fixed))


def permute_nodes(graph: PoseGraph, order: np.ndarray) -> PoseGraph:
    """The same graph with node k of the result = node order[k] of `graph`."""
    inv = np.empty_like(order)
    inv[order] = np.arange(order.size)
    return graph._replace(poses=graph.poses[order], edges=inv[graph.edges].astype(np.int32), ids=graph.ids[order],
                          fixed=int(inv[graph.fixed]))


def banded_order(graph: PoseGraph, max_width: int) -> np.ndarray | None:
    """A node order under which the graph is banded (node bandwidth <= max_width), from the
    reverse Cuthill-McKee ordering of its edges, or None. A ring's natural order has a band as
    wide as the ring (its closing edge); reverse Cuthill-McKee folds it to width 2."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n = graph.num_nodes
    e = np.asarray(graph.edges)
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    order = np.asarray(reverse_cuthill_mckee(A + A.T, symmetric_mode=True), np.int64)
    return order if _bandwidth(permute_nodes(graph, order)) <= max_width else None


def choose_linear_solver(graph: PoseGraph, cfg: SolverConfig) -> tuple[str, np.ndarray | None]:
    """"auto": banded when the node bandwidth is small (chains, the RHAML ladder, and graphs
    that reverse Cuthill-McKee makes so, like rings: then with that node order), else dense for
    small graphs and sparse above `dense_max_nodes`. Returns (solver, node order or None)."""
    if cfg.linear_solver != "auto":
        return cfg.linear_solver, None
    if _bandwidth(graph) <= cfg.banded_max_width:
        return "banded", None
    order = banded_order(graph, cfg.banded_max_width)
    if order is not None:
        return "banded", order
    return ("dense" if graph.num_nodes <= cfg.dense_max_nodes else "sparse"), None


_COMPILED: dict = {}


def solve_problem(p: Problem, cfg: SolverConfig, linear: str):
    """Compiles (cached by shapes) and runs; returns outputs, run seconds, compile seconds."""
    key = (jax.tree.map(lambda a: (a.shape, a.dtype), p), cfg, linear)
    compile_s = 0.0
    fn = _COMPILED.get(key)
    if fn is None:
        t = time.perf_counter()
        fn = _run_jit.lower(p, cfg=cfg, linear=linear).compile()
        compile_s = time.perf_counter() - t
        _COMPILED[key] = fn
    t = time.perf_counter()
    out = jax.block_until_ready(fn(p))
    return out, time.perf_counter() - t, compile_s


def optimize(graph: PoseGraph, config: SolverConfig = SolverConfig(), dtype=None) -> SolveResult:
    """Minimises 0.5 sum rho(r^T Lambda r) over all poses but `graph.fixed` (the gauge)."""
    if config.method not in ("gn", "lm"):
        raise RhamlError(f"solver method: {config.method!r} is not one of gn, lm")
    if config.initialization == "chordal":
        from ._chordal import chordal_initialization

        graph = graph._replace(poses=chordal_initialization(graph))
    linear, order = choose_linear_solver(graph, config)
    p = make_problem(graph if order is None else permute_nodes(graph, order), linear, dtype)
    (T, c0, c1, it, acc, conv), seconds, compile_s = solve_problem(p, config, linear)
    poses = np.asarray(se2_to_poses(jaxlie.SE2(T)))[: graph.num_nodes]
    if order is not None:
        poses = poses[np.argsort(order)]
    return SolveResult(poses, float(c0), float(c1), int(it), int(acc), bool(conv), seconds, compile_s, linear,
                       order is not None)


def graph_cost(graph: PoseGraph, poses: np.ndarray | None = None, robust: str = "none",
               robust_delta: float = 1.345) -> float:
    """GTSAM's cost 0.5 sum rho(r^T Lambda r) of `graph` at `poses` (default: its own)."""
    poses = graph.poses if poses is None else poses
    dtype = jnp.result_type(float)
    T = poses_to_se2(jnp.asarray(poses, dtype)).unit_complex_xy
    Z_inv = poses_to_se2(jnp.asarray(graph.measurements, dtype)).inverse().unit_complex_xy
    e = jnp.asarray(graph.edges, jnp.int32)
    p = Problem(T, Z_inv, e[:, 0], e[:, 1], jnp.asarray(graph.information, dtype), _robust_edges(graph),
                None, None, None)
    cfg = SolverConfig(robust=robust, robust_delta=robust_delta)
    return float(_cost_jit(T, p, cfg))


_cost_jit = jax.jit(_cost, static_argnames="cfg")  # op by op, each primitive would compile apart
