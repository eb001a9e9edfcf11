"""Robust two-robot fusion: consensus initialisation, GNC with truncated least squares, and
information from noise models; batch (`fuse`) and online (`fuse_online`).

The graph is Algorithm 1's ladder (node 2k = A_k, 2k+1 = B_k, per row k = 1..K: A's odometry,
B's odometry, the mutual edge), but every row is kept (static shapes): a row without a
rendezvous (`valid` False) or deleted by Algorithm 1's roll/pitch test gets a mutual edge of
weight zero, so its nodes just follow the odometry.

1. Consensus. Each usable observation k, taken as it is or with its heading turned by 180 deg
   (h = 0, 1), implies one transform F_kh from B's odometry frame to A's, F = B_k odom_b[k]^-1.
   Each candidate predicts every other observation k'; its score sums, over k', the better of
   the two headings of k' of prior(k', h') max(0, 1 - q / chi2_3(p)), q the Mahalanobis
   distance of the prediction with a variance that grows with the odometry drift between k
   and k' (from the odometry noise models) and with the heading error of observation k times
   the distance either robot travelled since. The best candidate (argmax: deterministic)
   places B by its odometry and fixes each observation's heading hypothesis (the one it
   predicts, with the flip prior); observations it cannot explain start with weight 0.
2. GNC-TLS on the mutual edges (odometry edges are known inliers), GTSAM's `GncOptimizer`
   schedule exactly: solve with the initial weights from the initial guess, mu_0 from the
   residuals at the initial guess (Yang et al. 2020, remark 5), then per outer iteration TLS
   weights at mu (eq. 14), a Gauss-Newton solve from the initial guess (or warm, with
   `gnc_warm_start`), stop when the weighted cost changes by less than `gnc_relative_cost_tol`
   or every weight is within `gnc_weights_tol` of 0 or 1, mu *= `gnc_mu_step`.
3. One more Gauss-Newton step from the (stop-gradient) solution with the final weights and
   flips held fixed, differentiable in the observations and odometry: at an optimum its
   derivative is the implicit-function derivative -H^-1 dg/dz of the optimum, so `jax.grad`
   works through `fuse` without differentiating the solver's while loops.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ._banded import band_solve
from ._ladder import ladder_iterate, ladder_normal_equations
from ._residuals import compose, inverse, poses_to_se2, retract, se2_to_poses
from ._rhaml_graph import Rendezvous, _planar, _roll_pitch
from ._solver import Problem
from ._types import PoseGraph, SolverConfig

__all__ = ["OdometryNoise", "FusionConfig", "FusionResult", "FusionGraph", "fuse", "fuse_jit", "fuse_online",
           "fuse_online_jit", "fusion_graph", "odometry_information", "rendezvous_from_frames"]


@dataclasses.dataclass(frozen=True)
class OdometryNoise:
    """A robot's wheel-odometry noise model: independent Gaussian noise on each odometry
    increment (the step between two consecutive rows), growing with the distance and angle
    travelled. Defaults are ../shared/DESIGN.md section 3's model; put your robot's figures.

    sigma_x = sigma_y = hypot(trans_frac * L, min_sigma_xy_m)
    sigma_psi = hypot(radians(deg_per_m) * L + rot_frac * |dpsi|, min_sigma_psi_rad)
    with L the step's length (m) and dpsi its heading change (rad). The floors keep a zero step
    (a robot standing still) from being infinitely certain. Rows should be consecutive
    odometry samples: across a gap the model sees the straight line between the two rows (a
    lower bound of the distance travelled) and no heading-to-position coupling."""

    trans_frac: float = 0.02  # sigma of each translation axis per metre of step
    deg_per_m: float = 0.5  # heading sigma (deg) per metre of step
    rot_frac: float = 0.0  # heading sigma (rad) per radian turned
    min_sigma_xy_m: float = 1e-4  # floors
    min_sigma_psi_rad: float = 1e-4

    def sigmas(self, step: jax.Array) -> jax.Array:
        """(..., 3) increments (x, y, psi) -> (..., 3) sigmas."""
        sq = step[..., 0] ** 2 + step[..., 1] ** 2
        # guard: d sqrt/dx is infinite at 0 (a robot standing still); the double where keeps
        # value and gradient finite there
        pos = sq > 0
        L = jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)
        st = jnp.hypot(self.trans_frac * L, self.min_sigma_xy_m)
        sp = jnp.hypot(np.deg2rad(self.deg_per_m) * L + self.rot_frac * jnp.abs(step[..., 2]), self.min_sigma_psi_rad)
        return jnp.stack([st, st, sp], -1)


def _chi2_3(p: float) -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(p, 3))


@dataclasses.dataclass(frozen=True)
class FusionConfig:
    """Settings of `fuse` / `fuse_online` (static under jit)."""

    information: Literal["noise_model", "paper"] = "noise_model"  # "paper": eqs. 9-10 (kappa, tau)
    odometry_a: OdometryNoise = OdometryNoise()
    odometry_b: OdometryNoise = OdometryNoise()
    obs_sigma_xy_m: float = 0.1  # observation sigmas when `obs_sigma` is not given per row
    obs_sigma_psi_rad: float = 0.2
    kappa: float = 100.0  # "paper" information: odometry diag(kappa), mutual eqs. 9-10
    tau: float = 0.5
    robust: Literal["gnc_tls", "none"] = "gnc_tls"
    try_flips: bool = True  # an observation may be its heading turned by 180 deg
    sigma_deg: float = 10.0  # Algorithm 1's DeleteErroneousNodes: max |roll|, |pitch|
    consensus_probability: float = 0.99  # consensus kernel width: chi2_3 quantile
    gnc_probability: float = 0.99  # TLS threshold barc^2 = 0.5 chi2_3(p) (GTSAM's default)
    gnc_mu_step: float = 1.4
    gnc_max_iterations: int = 100
    gnc_relative_cost_tol: float = 1e-5
    gnc_weights_tol: float = 1e-4
    gnc_init_weights: Literal["consensus", "ones"] = "consensus"  # weights of the first solve
    gnc_warm_start: bool = False  # inner solves from the last solution (GTSAM: from the start)
    # GTSAM's Gauss-Newton defaults (relative and absolute decrease 1e-5)
    solver: SolverConfig = SolverConfig(max_iterations=50, linear_solver="banded", relative_tolerance=1e-5,
                                        absolute_tolerance=1e-5)

    @property
    def barc_sq(self) -> float:
        return 0.5 * _chi2_3(self.gnc_probability)


class FusionResult(NamedTuple):
    poses_a: jax.Array  # (K+1, 3) A_0..A_K in A's odometry frame, A_0 fixed
    poses_b: jax.Array  # (K+1, 3) B_0..B_K in A's odometry frame
    a0_T_b0: jax.Array  # (3,) A_0^-1 B_0 (fuse_online: (K, 3), row k from rendezvous <= k)
    odom_a_T_odom_b: jax.Array  # (3,) B's odometry frame in A's (fuse_online: (K, 3))
    relative: jax.Array  # (K, 3) observed robot in the observer's frame (a_observes decides who is who)
    inlier: jax.Array  # (K,) bool: kept (not deleted, not rejected by GNC / consensus)
    flipped: jax.Array  # (K,) bool: used with its heading turned by 180 deg
    weights: jax.Array  # (K,) final GNC weights (0 for deleted rows and rows without rendezvous)
    deleted: jax.Array  # (K,) bool: Algorithm 1's roll/pitch deletion (or not finite)
    consensus: jax.Array  # (K,) bool: explained by the consensus transform
    final_cost: jax.Array  # () weighted cost 0.5 sum w r^T Omega r at the result
    iterations: jax.Array  # () int32 GNC outer iterations
    solves: jax.Array  # () int32 Gauss-Newton linear solves in total


class FusionGraph(NamedTuple):
    """The graph `fuse` optimises, before GNC (static shapes, K rows)."""

    poses: jax.Array  # (2K+2, 3) initial guess, node 2k = A_k, 2k+1 = B_k
    edges: jax.Array  # (3K, 2) int32: per row odometry A, odometry B, mutual (observer, observed)
    measurements: jax.Array  # (3K, 3); mutual ones with the chosen heading hypothesis
    information: jax.Array  # (3K, 3, 3) unweighted
    usable: jax.Array  # (K,) bool: valid, finite, not deleted (the mutual edges GNC weighs)
    init_weights: jax.Array  # (K,) weights of the first solve
    flipped: jax.Array  # (K,) bool
    consensus: jax.Array  # (K,) bool
    deleted: jax.Array  # (K,) bool
    a_observes: jax.Array  # (K,) bool


_IDENTITY7 = jnp.array([1.0, 0, 0, 0, 0, 0, 0])
_ROT_PI = jnp.array([-1.0, 0.0, 0.0, 0.0])  # SE2 parameters of a half turn


def rendezvous_from_frames(odom_a, odom_b, observation, a_observes) -> Rendezvous:
    """Per-frame arrays (N frames: odometry (N, 3), observation (N, 7), a_observes (N,)) ->
    a Rendezvous with K = N rows, row k+1 = frame k (row 0 repeats frame 0: a zero step), so
    `relative[k]` belongs to frame k. Works on NumPy and JAX arrays."""
    xp = jnp if isinstance(odom_a, jax.Array) else np
    return Rendezvous(xp.concatenate([odom_a[:1], odom_a]), xp.concatenate([odom_b[:1], odom_b]), observation,
                      a_observes)


def odometry_information(odom: jax.Array, noise: OdometryNoise) -> jax.Array:
    """(K+1, 3) odometry rows -> (K, 3) diagonal information of each step from `noise`."""
    u = poses_to_se2(odom).unit_complex_xy
    step = se2_to_poses(jaxlie.SE2(compose(inverse(u[:-1]), u[1:])))
    return 1.0 / noise.sigmas(step) ** 2


def _drift(odom: jax.Array, noise: OdometryNoise):
    """Cumulative per-row variances of translation (per axis) and heading from the noise model."""
    u = poses_to_se2(odom).unit_complex_xy
    step = se2_to_poses(jaxlie.SE2(compose(inverse(u[:-1]), u[1:])))
    s = noise.sigmas(step)
    z = jnp.zeros((1,), odom.dtype)
    return jnp.concatenate([z, jnp.cumsum(s[:, 0] ** 2)]), jnp.concatenate([z, jnp.cumsum(s[:, 2] ** 2)])


def _consensus(rv: Rendezvous, z4, obs_var, prior, usable, cfg: FusionConfig):
    """Returns (F* (4,) SE2 params, flip (K,) bool, explained (K,) bool). z4 (K, 4) planar
    observations, obs_var (K, 3) variances, prior (K, 2) of the two heading hypotheses."""
    oa = poses_to_se2(rv.odom_a).unit_complex_xy[1:]  # (K, 4) A_k
    ob = poses_to_se2(rv.odom_b).unit_complex_xy[1:]
    a_obs = rv.a_observes
    zh = jnp.stack([z4, compose(z4, jnp.broadcast_to(_ROT_PI.astype(z4.dtype), z4.shape))], 1)  # (K, 2, 4)
    Bk = jnp.where(a_obs[:, None, None], compose(oa[:, None], zh), compose(oa[:, None], inverse(zh)))
    F = compose(Bk, inverse(ob)[:, None])  # (K, 2, 4)
    Bp = compose(F[:, :, None], ob[None, None])  # (K, 2, K', 4): B_k' predicted by candidate (k, h)
    rel = compose(inverse(oa)[None, None], Bp)
    pred = jnp.where(a_obs[None, None, :, None], rel, inverse(rel))  # observation k' predicted
    d_xy = pred[..., 2:] - z4[None, None, :, 2:]
    c = z4[None, None, :, 0] * pred[..., 0] + z4[None, None, :, 1] * pred[..., 1]  # cos, sin of z^-1 pred
    s = z4[None, None, :, 0] * pred[..., 1] - z4[None, None, :, 1] * pred[..., 0]
    d_psi = jnp.stack([jnp.arctan2(s, c), jnp.arctan2(-s, -c)], -1)  # (K, 2, K', 2) for h' = 0, 1
    # variances of the prediction error (isotropic in translation)
    ta, pa = _drift(rv.odom_a, cfg.odometry_a)
    tb, pb = _drift(rv.odom_b, cfg.odometry_b)
    dd = lambda c_: jnp.abs(c_[1:, None] - c_[None, 1:])  # noqa: E731  (K, K') between rows
    lev = lambda o: jnp.sum((o[:, None, 2:] - o[None, :, 2:]) ** 2, -1)  # noqa: E731  squared distance travelled
    lever = lev(oa) + lev(ob)
    rng2 = jnp.sum(z4[:, 2:] ** 2, -1)
    v_xy = 0.5 * (obs_var[:, 0] + obs_var[:, 1])
    dpsi = dd(pa) + dd(pb)
    v_t = (v_xy[:, None] + v_xy[None, :] + obs_var[:, 2][:, None] * lever + dd(ta) + dd(tb)
           + dpsi * (lever + rng2[None, :]))
    v_p = obs_var[:, 2][:, None] + obs_var[:, 2][None, :] + dpsi
    q = (jnp.sum(d_xy ** 2, -1) / v_t[:, None])[..., None] + d_psi ** 2 / v_p[:, None, :, None]  # (K, 2, K', 2)
    thr = _chi2_3(cfg.consensus_probability)
    kern = jnp.maximum(0.0, 1.0 - q / thr) * prior[None, None]
    score = jnp.sum(jnp.where(usable[None, None, :], jnp.max(kern, -1), 0.0), -1)  # (K, 2)
    score = jnp.where(usable[:, None] & (prior > 0), score, -1.0)
    best = jnp.argmax(score.reshape(-1))
    qb = q.reshape(-1, *q.shape[2:])[best]  # (K', 2)
    # the hypothesis the consensus predicts, with the prior: min q - 2 log prior
    logp = jnp.log(jnp.where(prior > 0, prior, 1.0))  # guard: log 0 (the hypothesis is excluded below)
    cost = jnp.where(prior > 0, qb - 2.0 * logp, jnp.inf)
    flip = jnp.argmin(cost, -1) == 1
    explained = usable & (jnp.where(flip, qb[:, 1], qb[:, 0]) < thr)
    return F.reshape(-1, 4)[best], flip, explained


def _sanitize(rv: Rendezvous, valid, flip_prob, obs_sigma, cfg: FusionConfig):
    K = rv.observation.shape[0]
    dt = rv.odom_a.dtype
    valid = jnp.ones((K,), bool) if valid is None else jnp.asarray(valid, bool)
    obs = jnp.asarray(rv.observation, dt)
    finite = jnp.all(jnp.isfinite(obs), -1)
    # guard: rows without a usable observation hold NaN or garbage; the identity keeps every
    # value (and gradient) finite, and their mutual edges get weight 0
    obs = jnp.where((valid & finite)[:, None], obs, _IDENTITY7.astype(dt))
    roll, pitch = _roll_pitch(obs)
    sig = np.deg2rad(cfg.sigma_deg)
    deleted = ~finite | (jnp.abs(roll) > sig) | (jnp.abs(pitch) > sig)
    usable = valid & ~deleted
    if flip_prob is None:
        p = jnp.full((K,), 0.5, dt)
    else:
        p = jnp.clip(jnp.asarray(flip_prob, dt), 0.0, 1.0)
    prior = jnp.stack([1.0 - p, p], -1) if cfg.try_flips else jnp.stack([jnp.ones_like(p), jnp.zeros_like(p)], -1)
    if obs_sigma is None:
        obs_sigma = jnp.broadcast_to(jnp.array([cfg.obs_sigma_xy_m, cfg.obs_sigma_xy_m, cfg.obs_sigma_psi_rad], dt),
                                     (K, 3))
    rv = Rendezvous(jnp.asarray(rv.odom_a, dt), jnp.asarray(rv.odom_b, dt), obs, jnp.asarray(rv.a_observes, bool))
    return rv, valid & finite, deleted & valid, usable, prior, jnp.asarray(obs_sigma, dt), roll, pitch


def _information(rv: Rendezvous, obs_sigma, roll, pitch, cfg: FusionConfig):
    """(K, 3) diagonal information of odometry A, odometry B and the mutual edges."""
    K = rv.observation.shape[0]
    dt = rv.odom_a.dtype
    if cfg.information == "paper":
        km = 0.5 * cfg.kappa * jnp.exp(-jnp.abs(roll) - jnp.abs(pitch))
        odo = jnp.full((K, 3), cfg.kappa, dt)
        return odo, odo, jnp.stack([km, km, cfg.tau * km], -1)
    return (odometry_information(rv.odom_a, cfg.odometry_a), odometry_information(rv.odom_b, cfg.odometry_b),
            1.0 / obs_sigma ** 2)


def _graph(rv, valid, flip_prob, obs_sigma, cfg: FusionConfig) -> FusionGraph:
    rv, valid, deleted, usable, prior, obs_sigma, roll, pitch = _sanitize(rv, valid, flip_prob, obs_sigma, cfg)
    K = rv.observation.shape[0]
    z4 = _planar(rv.observation)
    i_a, i_b, i_m = _information(rv, obs_sigma, roll, pitch, cfg)
    # the consensus sees the observation variances of the information actually used
    F, flip, explained = _consensus(rv, z4, 1.0 / i_m, prior, usable, cfg)
    z_used = jnp.where(flip[:, None], compose(z4, jnp.broadcast_to(_ROT_PI.astype(z4.dtype), z4.shape)), z4)
    ua = poses_to_se2(rv.odom_a).unit_complex_xy
    ub = poses_to_se2(rv.odom_b).unit_complex_xy
    B = compose(F[None], ub)  # (K+1, 4)
    odo_a = compose(inverse(ua[:-1]), ua[1:])
    odo_b = compose(inverse(ub[:-1]), ub[1:])
    xyt = se2_to_poses(jaxlie.SE2(jnp.concatenate([B, odo_a, odo_b, z_used])))
    pb, ma, mb, mz = jnp.split(xyt, [K + 1, 2 * K + 1, 3 * K + 1])
    poses = jnp.stack([rv.odom_a, pb], 1).reshape(2 * K + 2, 3)
    k = jnp.arange(1, K + 1)
    A_k, B_k = 2 * k, 2 * k + 1
    mutual = jnp.where(rv.a_observes[:, None], jnp.stack([A_k, B_k], -1), jnp.stack([B_k, A_k], -1))
    edges = jnp.stack([jnp.stack([A_k - 2, A_k], -1), jnp.stack([B_k - 2, B_k], -1), mutual], 1).reshape(3 * K, 2)
    meas = jnp.stack([ma, mb, mz], 1).reshape(3 * K, 3)
    i_m = jnp.where(usable[:, None], i_m, 0.0)
    info = jnp.stack([i_a, i_b, i_m], 1).reshape(3 * K, 3)[:, :, None] * jnp.eye(3, dtype=xyt.dtype)
    w0 = (explained if cfg.gnc_init_weights == "consensus" else usable).astype(xyt.dtype)
    return FusionGraph(poses, edges.astype(jnp.int32), meas, info, usable, w0, flip & usable, explained, deleted,
                       rv.a_observes)


def _problem(g: FusionGraph) -> Problem:
    n = g.poses.shape[0]
    both = poses_to_se2(jnp.concatenate([g.poses, g.measurements])).unit_complex_xy
    return Problem(both[:n], inverse(both[n:]), g.edges[:, 0], g.edges[:, 1], g.information,
                   jnp.zeros(g.edges.shape[0], bool), None, None, None)


def _edge_weights(w):
    """(K,) mutual weights -> (3K,) edge weights (odometry edges: 1)."""
    one = jnp.ones_like(w)
    return jnp.stack([one, one, w], 1).reshape(-1)


def _mutual_u2(T, p: Problem, g: FusionGraph):
    """GTSAM's factor error 0.5 r^T Omega r of each mutual edge at T (K,)."""
    from ._residuals import residuals

    r = residuals(T, p.Z_inv, p.ei, p.ej)
    s2 = jnp.einsum("ea,eab,eb->e", r, p.info, r)
    return 0.5 * s2.reshape(-1, 3)[:, 2]


def _tls_weights(u2, mu, barc, usable):
    """GTSAM's TLS weights with the linear scheduler (GNC paper eq. 14)."""
    upper = (mu + 1.0) / mu * barc
    lower = mu / (mu + 1.0) * barc
    # guard: u2 = 0 divides by zero in the transition formula; such a residual is below
    # `lower` and gets weight 1 by the first branch
    mid = jnp.sqrt(barc * mu * (mu + 1.0) / jnp.where(u2 > 0, u2, 1.0)) - mu
    w = jnp.where(u2 >= upper, 0.0, jnp.where(u2 <= lower, 1.0, jnp.clip(mid, 0.0, 1.0)))
    return jnp.where(usable, w, 0.0)


def _solve(p: Problem, T_start, w, a_observes, cfg: FusionConfig):
    q = p._replace(T0=T_start, info=p.info * _edge_weights(w)[:, None, None])
    state, _ = ladder_iterate(q, a_observes, dataclasses.replace(cfg.solver, robust="none"))
    return state.T, state.cost, state.it


def _robust_solve(g: FusionGraph, cfg: FusionConfig):
    """GNC-TLS as GTSAM's GncOptimizer (see the module docstring). Returns (T (2K+2, 4),
    weights (K,), weighted cost, GNC iterations, linear solves)."""
    p = _problem(g)
    T0 = p.T0
    dt = T0.dtype
    T, cost, solves = _solve(p, T0, g.init_weights, g.a_observes, cfg)
    if cfg.robust == "none":
        w = g.usable.astype(dt)
        if cfg.gnc_init_weights == "consensus":
            w = g.init_weights
        return T, w, cost, jnp.asarray(0, jnp.int32), solves
    barc = jnp.asarray(cfg.barc_sq, dt)
    u2_0 = _mutual_u2(T0, p, g)
    excess = 2.0 * u2_0 - barc
    mu0 = jnp.min(jnp.where(g.usable & (excess > 0), barc / jnp.where(excess > 0, excess, 1.0), jnp.inf))
    mu0 = jnp.where(jnp.isfinite(mu0), jnp.maximum(mu0, 1e-6), -1.0)
    skip = (mu0 <= 0) | ~jnp.any(g.usable)

    def body(c):
        T, w, mu, prev, _, it, solves, _ = c
        w = _tls_weights(_mutual_u2(T, p, g), mu, barc, g.usable)
        T, cost, n = _solve(p, T if cfg.gnc_warm_start else T0, w, g.a_observes, cfg)
        rel = jnp.abs(cost - prev) / jnp.maximum(prev, 1e-7)
        binary = jnp.all(jnp.abs(w - jnp.round(w)) <= cfg.gnc_weights_tol)
        done = (rel < cfg.gnc_relative_cost_tol) | binary | (it + 1 >= cfg.gnc_max_iterations)
        return T, w, mu * cfg.gnc_mu_step, cost, cost, it + 1, solves + n, done

    c = (T, g.init_weights, mu0, cost, cost, jnp.asarray(0, jnp.int32), solves, skip)
    T, w, _, _, cost, it, solves, _ = jax.lax.while_loop(lambda c: ~c[-1], body, c)
    return T, w, cost, it, solves


def _final_step(T, g: FusionGraph, w, cfg: FusionConfig):
    """One undamped Gauss-Newton step from T (weights fixed): differentiable in the graph's
    measurements and information (the implicit-function derivative at an optimum)."""
    p = _problem(g)
    K = g.usable.shape[0]
    q = p._replace(info=p.info * _edge_weights(w)[:, None, None])
    D, Lo, gv, _ = ladder_normal_equations(T, q, g.a_observes, dataclasses.replace(cfg.solver, robust="none"))
    gauge = jnp.zeros((K + 1, 6), bool).at[0, :3].set(True)
    # guard: with no mutual edge left B's placement is free (H singular); a tiny ridge keeps
    # the step (zero: g = 0 at the optimum) and its derivative finite
    ridge = 1e-12 * jnp.max(jnp.abs(D)) + jnp.finfo(D.dtype).tiny
    D = D + ridge * jnp.eye(6, dtype=D.dtype)
    x = band_solve(D, Lo, -gv[..., None], cfg.solver.band_solver)[..., 0]
    x = jnp.where(gauge, 0.0, x)
    return retract(T, x.reshape(2 * K + 2, 3))


def _result(T4, g: FusionGraph, rv_odom_b0, w, cost, it, solves) -> FusionResult:
    K = g.usable.shape[0]
    pr = T4.reshape(K + 1, 2, 4)
    A, B = pr[:, 0], pr[:, 1]
    rel = compose(inverse(A[1:]), B[1:])
    rel = jnp.where(g.a_observes[:, None], rel, inverse(rel))
    a0b0 = compose(inverse(A[:1]), B[:1])
    ob0 = poses_to_se2(rv_odom_b0[None]).unit_complex_xy
    F = compose(B[:1], inverse(ob0))
    xyt = se2_to_poses(jaxlie.SE2(jnp.concatenate([A, B, rel, a0b0, F])))
    pa, pb, rel, a0b0, F = jnp.split(xyt, [K + 1, 2 * K + 2, 3 * K + 2, 3 * K + 3])
    inlier = g.usable & (w > 0.5)
    return FusionResult(pa, pb, a0b0[0], F[0], rel, inlier, g.flipped, w, g.deleted, g.consensus, cost, it, solves)


def fuse(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid: jax.Array | None = None,
         flip_prob: jax.Array | None = None, obs_sigma: jax.Array | None = None) -> FusionResult:
    """Robust fusion of K rows of odometry and observations (see the module docstring).

    valid (K,) bool: rows with a rendezvous (others: odometry only); flip_prob (K,): the
    probability that an observation's heading is turned by 180 deg (None: 0.5); obs_sigma
    (K, 3): per-row observation sigmas (x, y in m, psi in rad; None: the config's). Pure and
    jit-able with `cfg` static (`fuse_jit`), vmappable, differentiable in rv and obs_sigma."""
    sg = jax.lax.stop_gradient
    g0 = _graph(jax.tree.map(sg, rv), valid, None if flip_prob is None else sg(flip_prob),
                None if obs_sigma is None else sg(obs_sigma), cfg)
    T, w, cost, it, solves = _robust_solve(g0, cfg)
    # the differentiable graph: the same decisions (flips, weights, initial guess), with
    # measurements and information traced from the inputs
    g = _graph_fixed(rv, valid, obs_sigma, cfg, g0)
    T = _final_step(sg(T), g, sg(w), cfg)
    return _result(T, g, jnp.asarray(rv.odom_b[0], T.dtype), w, cost, it, solves)


def _graph_fixed(rv, valid, obs_sigma, cfg: FusionConfig, g0: FusionGraph) -> FusionGraph:
    """g0's graph with measurements and information recomputed (differentiably) from the inputs."""
    rv, _, _, _, _, obs_sigma, roll, pitch = _sanitize(rv, valid, None, obs_sigma, cfg)
    K = rv.observation.shape[0]
    z4 = _planar(rv.observation)
    i_a, i_b, i_m = _information(rv, obs_sigma, roll, pitch, cfg)
    z_used = jnp.where(g0.flipped[:, None], compose(z4, jnp.broadcast_to(_ROT_PI.astype(z4.dtype), z4.shape)), z4)
    ua = poses_to_se2(rv.odom_a).unit_complex_xy
    ub = poses_to_se2(rv.odom_b).unit_complex_xy
    odo_a = compose(inverse(ua[:-1]), ua[1:])
    odo_b = compose(inverse(ub[:-1]), ub[1:])
    xyt = se2_to_poses(jaxlie.SE2(jnp.concatenate([odo_a, odo_b, z_used])))
    ma, mb, mz = jnp.split(xyt, [K, 2 * K])
    meas = jnp.stack([ma, mb, mz], 1).reshape(3 * K, 3)
    i_m = jnp.where(g0.usable[:, None], i_m, 0.0)
    info = jnp.stack([i_a, i_b, i_m], 1).reshape(3 * K, 3)[:, :, None] * jnp.eye(3, dtype=xyt.dtype)
    return g0._replace(measurements=meas, information=info)


def fuse_online(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid: jax.Array | None = None,
                flip_prob: jax.Array | None = None, obs_sigma: jax.Array | None = None) -> FusionResult:
    """Online fusion: one `fuse` per row k on the rendezvous <= k (later rows masked; their
    dangling odometry changes nothing), as one `lax.scan` compiled once for K rows.

    Row k of `relative`, `a0_T_b0` (K, 3), `odom_a_T_odom_b` (K, 3), `inlier`, `flipped` and
    `weights` is what the update at row k said about row k; `poses_a`, `poses_b`, `deleted`,
    `consensus`, `final_cost` are the last update's (= `fuse` on everything); `iterations` and
    `solves` are summed over the updates."""
    K = rv.observation.shape[0]
    base = jnp.ones((K,), bool) if valid is None else jnp.asarray(valid, bool)
    rows = jnp.arange(K)

    def step(carry, k):
        r = fuse(rv, cfg, base & (rows <= k), flip_prob, obs_sigma)
        out = (r.relative[k], r.a0_T_b0, r.odom_a_T_odom_b, r.inlier[k], r.flipped[k], r.weights[k], r.iterations,
               r.solves)
        return carry, out

    _, (rel, a0b0, F, inl, flp, w, it, sol) = jax.lax.scan(step, None, rows)
    last = fuse(rv, cfg, base, flip_prob, obs_sigma)
    return last._replace(relative=rel, a0_T_b0=a0b0, odom_a_T_odom_b=F, inlier=inl, flipped=flp, weights=w,
                         iterations=jnp.sum(it), solves=jnp.sum(sol))


def fusion_graph(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid=None, flip_prob=None,
                 obs_sigma=None) -> tuple[PoseGraph, FusionGraph]:
    """Host side: the graph `fuse` hands to GNC (after deletion, consensus and flips) as a
    PoseGraph (mutual edges of unusable rows dropped; `robust_edges` marks the mutual ones),
    e.g. for `write_g2o`, GTSAM's GncOptimizer or a plot; plus the device-side FusionGraph."""
    g = _graph_jit(jax.tree.map(jnp.asarray, rv), valid, flip_prob, obs_sigma, cfg)
    K = int(g.usable.shape[0])
    keep = np.ones((K, 3), bool)
    keep[:, 2] = np.asarray(g.usable)
    keep = keep.reshape(-1)
    robust = np.zeros((K, 3), bool)
    robust[:, 2] = True
    pg = PoseGraph(np.asarray(g.poses, np.float64), np.asarray(g.edges)[keep], np.asarray(g.measurements)[keep],
                   np.asarray(g.information)[keep], np.arange(2 * K + 2, dtype=np.int64), 0, robust.reshape(-1)[keep])
    return pg, g


_graph_jit = jax.jit(_graph, static_argnames="cfg")

# small graphs: XLA's thread pool costs more than it brings (see rhaml_pgo_jit)
from ._rhaml_graph import SMALL_GRAPH_COMPILER_OPTIONS  # noqa: E402

fuse_jit = jax.jit(fuse, static_argnames="cfg", compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)
"""`fuse` jit-compiled, one executable per shape and config, shared by all callers."""
fuse_online_jit = jax.jit(fuse_online, static_argnames="cfg", compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)
"""`fuse_online` jit-compiled."""
