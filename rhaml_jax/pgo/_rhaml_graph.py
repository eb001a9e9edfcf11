"""The paper's Algorithm 1 (RHAML pose-graph optimisation), each step a pure JAX function.

Inputs are K rendezvous in time order (`Rendezvous`). At rendezvous k one robot observes the
other: T_ref,k is the observed robot's pose in the observer's robot frame (SE(3), from IR).
The graph has nodes A_0, B_0, A_1, B_1, ..., A_K, B_K (node 2k = A_k, 2k+1 = B_k), in A's
odometry frame with A_0 held fixed at A's first odometry pose (the gauge), and per rendezvous
three edges: A's odometry A_{k-1} -> A_k, B's odometry B_{k-1} -> B_k, and the mutual edge
observer -> observed with measurement T_ref,k (its planar part x, y, yaw).

Shapes stay static under jit: DeleteErroneousNodes moves the kept rendezvous to the front
(stable) and pads the tail with copies of the last kept one whose mutual edges get zero
information. The padded nodes then sit exactly on their odometry and add nothing to the cost,
so the optimum over the kept part is that of the paper's graph with 2(1 + alpha_d + beta_d)
nodes and 3(alpha_d + beta_d) edges, which `rhaml_pose_graph` returns without padding.

GlobalOptimization minimises the usual sum of squared Mahalanobis errors,
0.5 sum_e r_e^T Omega_e r_e. The paper's eq. 11 prints the norms ||Omega^(1/2) r||_2 without
the square; that is taken to be a typo: the squared form is what g2o-style PGO minimises
and what the information matrices of eqs. 9-10 are for.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ..errors import RhamlError, check_finite, check_shape
from ._banded import band_layout
from ._normal_equations import block_structure
from ._residuals import compose, inverse, poses_to_se2, se2_to_poses
from ._ladder import ladder_iterate
from ._solver import Problem, _iterate
from ._types import PoseGraph, SolverConfig

__all__ = ["Rendezvous", "RhamlPGOConfig", "RhamlPGOResult", "PoseGraphArrays", "delete_erroneous_nodes",
           "construct_pose_graph", "calculate_information_matrix", "global_optimization", "rhaml_pgo", "rhaml_pgo_jit",
           "rhaml_pose_graph", "observation_from_xy_yaw_rp"]


class Rendezvous(NamedTuple):
    """K rendezvous in time order (the paper's O_A and O_B together)."""

    odom_a: jax.Array  # (K+1, 3) A's odometry (x, y, psi): start (row 0), then at rendezvous 1..K
    odom_b: jax.Array  # (K+1, 3) B's odometry, same rows
    observation: jax.Array  # (K, 7) SE(3) wxyz_xyz: T_ref,k, observed robot in observer's frame
    a_observes: jax.Array  # (K,) bool: A is the observer (B observed); False: B observes A


@dataclasses.dataclass(frozen=True)
class RhamlPGOConfig:
    """Algorithm 1's parameters (paper: sigma = 10 deg, kappa = 100, tau = 0.5)."""

    sigma_deg: float = 10.0  # DeleteErroneousNodes: max |roll| and |pitch| of an observation
    kappa: float = 100.0  # odometry information diag(kappa, kappa, kappa)
    tau: float = 0.5  # weight of the angle in the mutual information (eq. 10)
    # GTSAM's default stopping rule (relative and absolute decrease 1e-5): Gauss-Newton
    # converges quadratically here, so the step after which it stops leaves the cost within
    # ~1e-9 of the optimum, one solve earlier than a tighter tolerance
    solver: SolverConfig = SolverConfig(max_iterations=30, linear_solver="banded", relative_tolerance=1e-5,
                                        absolute_tolerance=1e-5)
    robust_mutual_only: bool = True  # a robust kernel (solver.robust) acts on mutual edges only


class PoseGraphArrays(NamedTuple):
    """ConstructPoseGraph's output (static shapes, K rendezvous incl. padding)."""

    poses: jax.Array  # (2K+2, 3) initial (x, y, psi); node 2k = A_k, 2k+1 = B_k
    edges: jax.Array  # (3K, 2) int32: per rendezvous odom A, odom B, mutual (observer, observed)
    measurements: jax.Array  # (3K, 3)
    roll_pitch: jax.Array  # (K, 2) the mutual observations' roll and pitch (rad)
    valid: jax.Array  # (K,) bool: a kept rendezvous (False: padding)
    a_observes: jax.Array  # (K,) bool


class RhamlPGOResult(NamedTuple):
    poses_a: jax.Array  # (K+1, 3) optimised A_0..A_K (kept rendezvous first, then padding)
    poses_b: jax.Array  # (K+1, 3) optimised B_0..B_K in A's odometry frame
    a0_T_b0: jax.Array  # (3,) B_0 in A_0's frame (x, y, psi): A_0^-1 B_0
    odom_a_T_odom_b: jax.Array  # (3,) B's odometry frame in A's odometry frame
    num_kept: jax.Array  # () int32: alpha_d + beta_d
    keep: jax.Array  # (K,) bool: DeleteErroneousNodes' verdict, input order
    initial_cost: jax.Array  # ()
    final_cost: jax.Array  # ()
    iterations: jax.Array  # () int32
    converged: jax.Array  # () bool


def observation_from_xy_yaw_rp(xy_yaw: jax.Array, roll_pitch: jax.Array | None = None,
                               z: jax.Array | None = None) -> jax.Array:
    """(K, 3) planar poses (+ optional (K, 2) roll, pitch and (K,) z) -> (K, 7) SE(3) wxyz_xyz."""
    xy_yaw = jnp.asarray(xy_yaw)
    rp = jnp.zeros(xy_yaw.shape[:-1] + (2,), xy_yaw.dtype) if roll_pitch is None else jnp.asarray(roll_pitch)
    zz = jnp.zeros(xy_yaw.shape[:-1], xy_yaw.dtype) if z is None else jnp.asarray(z)
    R = jaxlie.SO3.from_rpy_radians(rp[..., 0], rp[..., 1], xy_yaw[..., 2])
    t = jnp.stack([xy_yaw[..., 0], xy_yaw[..., 1], zz], -1)
    return jaxlie.SE3.from_rotation_and_translation(R, t).wxyz_xyz


def _roll_pitch(obs: jax.Array):
    """Roll and pitch (rad) of SE(3) wxyz_xyz poses (jaxlie's SO3.compute_roll_radians and
    compute_pitch_radians written out on the quaternion)."""
    w, x, y, z = (obs[..., k] for k in range(4))
    roll = jnp.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = jnp.arcsin(jnp.clip(2.0 * (w * y - x * z), -1.0, 1.0))
    return roll, pitch


def _planar(obs: jax.Array) -> jax.Array:
    """The planar part of SE(3) wxyz_xyz poses as SE2 parameters (cos yaw, sin yaw, x, y),
    straight from the quaternion (no trigonometric call)."""
    w, x, y, z = (obs[..., k] for k in range(4))
    c, s = 1.0 - 2.0 * (y * y + z * z), 2.0 * (w * z + x * y)
    n = jnp.sqrt(c * c + s * s)
    n = jnp.where(n > 0, n, 1.0)
    return jnp.stack([c / n, s / n, obs[..., 4], obs[..., 5]], -1)


def delete_erroneous_nodes(rv: Rendezvous, sigma_deg: float = 10.0) -> tuple[Rendezvous, jax.Array, jax.Array]:
    """Drops observations with |roll| or |pitch| > sigma (planar robots: both should be ~0).

    Returns (compacted rendezvous: kept first in time order, tail padded with the last kept
    one; valid (K,) bool: the first alpha_d + beta_d rows; keep (K,) bool in input order)."""
    roll, pitch = _roll_pitch(rv.observation)
    sigma = jnp.deg2rad(sigma_deg)
    keep = (jnp.abs(roll) <= sigma) & (jnp.abs(pitch) <= sigma) & jnp.all(jnp.isfinite(rv.observation), -1)
    K = keep.shape[0]
    count = jnp.sum(keep)
    order = jnp.argsort(~keep, stable=True)  # kept first, time order preserved
    valid = jnp.arange(K) < count
    last = order[jnp.maximum(count - 1, 0)]
    src = jnp.where(valid, order, last)  # padding repeats the last kept rendezvous
    rows = jnp.where(count > 0, src + 1, 0)  # odometry row of each compacted rendezvous
    rows = jnp.concatenate([jnp.zeros((1,), rows.dtype), rows])
    out = Rendezvous(rv.odom_a[rows], rv.odom_b[rows], rv.observation[src], rv.a_observes[src])
    return out, valid, keep


def construct_pose_graph(rv: Rendezvous, valid: jax.Array) -> PoseGraphArrays:
    """Nodes A_0, B_0, ..., A_K, B_K; edges odometry A, odometry B, mutual per rendezvous.

    Initial guess: A from its odometry; B from its odometry placed by B_0, which is taken as
    the medoid of the B_0 implied by each kept observation (robust to a few wrong ones;
    distance between two candidates: translation distance plus the chord |e^(i a) - e^(i b)|
    of their headings). Works on SE2 parameters (cos, sin, x, y) throughout, with one sin/cos
    and one atan2 call site for the whole construction (XLA expands each inline; fewer sites
    compile faster)."""
    K = rv.observation.shape[0]
    roll, pitch = _roll_pitch(rv.observation)
    T_ref = _planar(rv.observation)  # (K, 4)
    ka = jnp.arange(1, K + 1)
    ob_all = poses_to_se2(jnp.concatenate([rv.odom_a, rv.odom_b])).unit_complex_xy
    oa, ob = ob_all[: K + 1], ob_all[K + 1 :]
    odo_a = compose(inverse(oa[:-1]), oa[1:])  # (K, 4)
    odo_b = compose(inverse(ob[:-1]), ob[1:])
    b0_bk = compose(inverse(ob[:1]), ob)  # (K+1, 4): odom_b[0]^-1 odom_b[k]
    # B_k implied by each observation, then B_0 = B_k (odom_b[0]^-1 odom_b[k])^-1
    B_k = compose(oa[1:], jnp.where(rv.a_observes[:, None], T_ref, inverse(T_ref)))
    B0_cand = compose(B_k, inverse(b0_bk[1:]))  # (K, 4)
    diff = B0_cand[:, None, :] - B0_cand[None, :, :]  # (K, K, 4)
    sq = diff * diff
    # written out rather than two jnp.linalg.norm calls: 4.7x faster here on XLA's CPU backend.
    # The sqrt is not differentiable at 0 (the diagonal), but d only feeds the argmin, which
    # carries no gradient.
    d = jnp.sqrt(sq[..., 2] + sq[..., 3]) + jnp.sqrt(sq[..., 0] + sq[..., 1])
    score = jnp.where(valid[:, None] & valid[None, :], d, 0.0).sum(1)
    best = jnp.argmin(jnp.where(valid, score, jnp.inf))
    poses_b = compose(B0_cand[best][None], b0_bk)  # (K+1, 4)
    xyt = se2_to_poses(jaxlie.SE2(jnp.concatenate([poses_b, odo_a, odo_b, T_ref])))  # one atan2 site
    poses_b, odo_a, odo_b, T_ref = jnp.split(xyt, [K + 1, 2 * K + 1, 3 * K + 1])
    poses = jnp.stack([rv.odom_a, poses_b], 1).reshape(2 * K + 2, 3)
    A_k, Bn = 2 * ka, 2 * ka + 1
    mutual = jnp.where(rv.a_observes[:, None], jnp.stack([A_k, Bn], -1), jnp.stack([Bn, A_k], -1))
    edges = jnp.stack([jnp.stack([A_k - 2, A_k], -1), jnp.stack([Bn - 2, Bn], -1), mutual], 1)
    meas = jnp.stack([odo_a, odo_b, T_ref], 1)
    return PoseGraphArrays(poses, edges.reshape(3 * K, 2).astype(jnp.int32), meas.reshape(3 * K, 3),
                           jnp.stack([roll, pitch], -1), valid, rv.a_observes)


def calculate_information_matrix(g: PoseGraphArrays, kappa: float = 100.0, tau: float = 0.5) -> jax.Array:
    """(3K, 3, 3): odometry diag(kappa); mutual diag(k_m, k_m, tau k_m) with
    k_m = kappa/2 exp(-|roll| - |pitch|) (eqs. 9-10); zero for padding rows."""
    K = g.valid.shape[0]
    dt = g.measurements.dtype
    km = 0.5 * kappa * jnp.exp(-jnp.abs(g.roll_pitch[:, 0]) - jnp.abs(g.roll_pitch[:, 1]))
    km = jnp.where(g.valid, km, 0.0)
    odo = jnp.full((K, 3), kappa, dt)
    mut = jnp.stack([km, km, tau * km], -1)
    diag = jnp.stack([odo, odo, mut], 1).reshape(3 * K, 3)
    return diag[:, :, None] * jnp.eye(3, dtype=dt)


def _canonical_structure(K: int):
    """Block structure of the ladder graph (depends on K only; mutual edges as A_k -> B_k)."""
    k = np.arange(1, K + 1)
    e = np.stack([np.stack([2 * k - 2, 2 * k], -1), np.stack([2 * k - 1, 2 * k + 1], -1),
                  np.stack([2 * k, 2 * k + 1], -1)], 1).reshape(3 * K, 2)
    s = block_structure(2 * K + 2, e, 0)
    return s, band_layout(s)


def global_optimization(g: PoseGraphArrays, info: jax.Array, solver: SolverConfig = SolverConfig(
        linear_solver="banded"), robust_mutual_only: bool = True):
    """Minimises 0.5 sum r^T Omega r with A_0 fixed. Returns (poses (2K+2, 3), A_0^-1 B_0 (3,),
    initial cost, final cost, iterations, converged)."""
    K = g.valid.shape[0]
    dt = g.poses.dtype
    robust = jnp.ones((K, 3), bool)
    if robust_mutual_only:
        robust = robust.at[:, :2].set(False)
    n = g.poses.shape[0]
    both = poses_to_se2(jnp.concatenate([g.poses, g.measurements])).unit_complex_xy  # one sin/cos site
    T0, Z_inv = both[:n], inverse(both[n:])
    linear = solver.linear_solver if solver.linear_solver != "auto" else "banded"
    if linear == "sparse":
        raise RhamlError("RHAML global optimisation: use the banded or dense linear solver inside jit")
    if linear == "banded":  # the ladder's block-tridiagonal H, assembled without scatters
        p = Problem(T0, Z_inv, g.edges[:, 0], g.edges[:, 1], info.astype(dt), robust.reshape(-1), None, None, None)
        state, cost0 = ladder_iterate(p, g.a_observes, solver)
    else:
        s, band = _canonical_structure(K)
        s = jax.tree.map(jnp.asarray, s)
        swap = jnp.zeros((K, 3), bool).at[:, 2].set(~g.a_observes).reshape(-1)
        s = s._replace(slot_ii=jnp.where(swap, s.slot_jj, s.slot_ii), slot_jj=jnp.where(swap, s.slot_ii, s.slot_jj),
                       ij_upper=jnp.where(swap, ~s.ij_upper, s.ij_upper))
        p = Problem(T0, Z_inv, g.edges[:, 0], g.edges[:, 1], info.astype(dt), robust.reshape(-1), s, None, band)
        state, cost0 = _iterate(p, solver, linear)
    a0_b0 = compose(inverse(state.T[:1]), state.T[1:2])
    xyt = se2_to_poses(jaxlie.SE2(jnp.concatenate([state.T, a0_b0])))
    poses, a0_T_b0 = xyt[:-1], xyt[-1]
    return poses, a0_T_b0, cost0, state.cost, state.it, state.converged


def rhaml_pgo(rv: Rendezvous, config: RhamlPGOConfig = RhamlPGOConfig()) -> RhamlPGOResult:
    """Algorithm 1 end to end; pure and jit-able (`jax.jit(rhaml_pgo, static_argnames="config")`)."""
    compact, valid, keep = delete_erroneous_nodes(rv, config.sigma_deg)
    g = construct_pose_graph(compact, valid)
    info = calculate_information_matrix(g, config.kappa, config.tau)
    poses, a0b0, c0, c1, it, conv = global_optimization(g, info, config.solver, config.robust_mutual_only)
    K = valid.shape[0]
    pr = poses.reshape(K + 1, 2, 3)
    # B's odometry frame in A's odometry frame: B_0 = F odom_b[0]  =>  F = B_0 odom_b[0]^-1
    u = poses_to_se2(jnp.stack([pr[0, 1], compact.odom_b[0]])).unit_complex_xy
    F = se2_to_poses(jaxlie.SE2(compose(u[0], inverse(u[1]))))
    return RhamlPGOResult(pr[:, 0], pr[:, 1], a0b0, F, jnp.sum(valid).astype(jnp.int32), keep, c0, c1, it, conv)


# A RHAML-size graph is thousands of kernels of a few hundred numbers each: handing them to
# Eigen's thread pool costs more than it brings (K = 100: 2.0 against 2.5 ms on this 2-core
# machine, BENCHMARKS.md). Other backends ignore the option.
SMALL_GRAPH_COMPILER_OPTIONS = {"xla_cpu_multi_thread_eigen": False}

rhaml_pgo_jit = jax.jit(rhaml_pgo, static_argnames="config", compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)
"""`rhaml_pgo` jit-compiled (single-threaded XLA kernels on the CPU: faster at this size): one
executable per input shape and config, shared by all callers."""


def _check_rendezvous(rv: Rendezvous) -> None:
    K = int(np.shape(rv.observation)[0])
    check_shape("rendezvous.odom_a", rv.odom_a, (K + 1, 3))
    check_shape("rendezvous.odom_b", rv.odom_b, (K + 1, 3))
    check_shape("rendezvous.observation", rv.observation, (K, 7))
    check_shape("rendezvous.a_observes", rv.a_observes, (K,))
    for name in ("odom_a", "odom_b"):
        check_finite(f"rendezvous.{name}", getattr(rv, name))
    if K < 1:
        raise RhamlError("rendezvous: at least one observation is needed")


@functools.partial(jax.jit, static_argnums=(1, 2, 3))
def _prepare(rv: Rendezvous, sigma_deg: float, kappa: float, tau: float):
    """DeleteErroneousNodes, ConstructPoseGraph and CalculateInformationMatrix, compiled once
    per shape (run op by op they would compile every primitive separately)."""
    compact, valid, _ = delete_erroneous_nodes(rv, sigma_deg)
    g = construct_pose_graph(compact, valid)
    return valid, g, calculate_information_matrix(g, kappa, tau)


def rhaml_pose_graph(rv: Rendezvous, config: RhamlPGOConfig = RhamlPGOConfig()) -> PoseGraph:
    """Host side: the paper's graph without padding (2(1 + n) nodes, 3 n edges for n kept
    observations) as a PoseGraph with its initial guess, e.g. for `write_g2o` or GTSAM.
    Vertex ids: A_k = 2k, B_k = 2k + 1."""
    _check_rendezvous(rv)
    rv = jax.tree.map(jnp.asarray, rv)
    valid, g, info = _prepare(rv, config.sigma_deg, config.kappa, config.tau)
    n = int(np.sum(np.asarray(valid)))
    if n == 0:
        raise RhamlError(f"rendezvous: every observation has |roll| or |pitch| > {config.sigma_deg} deg "
                         "(or is not finite): no mutual edge is left to link the robots")
    N = 2 * (n + 1)
    robust = np.zeros((n, 3), bool)
    robust[:, 2] = True
    if not config.robust_mutual_only:
        robust[:] = True
    return PoseGraph(np.asarray(g.poses[:N], np.float64), np.asarray(g.edges[: 3 * n], np.int32),
                     np.asarray(g.measurements[: 3 * n], np.float64), np.asarray(info[: 3 * n], np.float64),
                     np.arange(N, dtype=np.int64), 0, robust.reshape(-1))
