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
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from ..errors import RhamlError, check_shape
from ..planar import wrap_angle
from ._banded import band_solve
from ._ladder import ladder_iterate, ladder_normal_equations
from ._residuals import compose, inverse, poses_to_se2, residuals, retract, se2_to_poses
from ._rhaml_graph import SMALL_GRAPH_COMPILER_OPTIONS, Rendezvous, _planar, _roll_pitch
from ._solver import Problem
from ._types import PoseGraph, SolverConfig

__all__ = ["OdometryNoise", "FusionConfig", "FusionResult", "FusionGraph", "agrees", "fuse", "fuse_jit", "fuse_online",
           "fuse_online_jit", "fuse_online_redetect", "fuse_online_redetect_jit", "fusion_graph", "odometry_information",
           "rendezvous_from_frames"]


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
    """The graph `fuse` optimises, before GNC (static shapes, K rows; poses and measurements as
    jaxlie SE2 parameters (cos, sin, x, y); `fusion_graph` gives it as a PoseGraph)."""

    T0: jax.Array  # (2K+2, 4) initial guess, node 2k = A_k, 2k+1 = B_k
    Z: jax.Array  # (3K, 4) measurements; the mutual ones with the chosen heading hypothesis
    edges: jax.Array  # (3K, 2) int32: per row odometry A, odometry B, mutual (observer, observed)
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


class _ConsensusTerms(NamedTuple):
    F: jax.Array  # (K, 2, 4) candidate odom_A -> odom_B transforms (SE2 params), h = 0, 1
    q: jax.Array  # (K, 2, K', 2) Mahalanobis distance of candidate (k, h)'s prediction of k', h'
    kern: jax.Array  # (K, 2, K') max over h' of prior(k', h') max(0, 1 - q / chi2_3(p))


def _consensus_terms(inp: "_Inputs", cfg: FusionConfig) -> _ConsensusTerms:
    """Every candidate against every observation (observation variances: those of the
    mutual information actually used)."""
    z4, prior, a_obs = inp.z4, inp.prior, inp.rv.a_observes
    obs_var = 1.0 / inp.info[2]
    oa, ob = inp.ua[1:], inp.ub[1:]  # (K, 4) A_k, odom_b[k]
    zh = jnp.stack([z4, compose(z4, jnp.broadcast_to(_ROT_PI.astype(z4.dtype), z4.shape))], 1)  # (K, 2, 4)
    Bk = jnp.where(a_obs[:, None, None], compose(oa[:, None], zh), compose(oa[:, None], inverse(zh)))
    F = compose(Bk, inverse(ob)[:, None])  # (K, 2, 4)
    Bp = compose(F[:, :, None], ob[None, None])  # (K, 2, K', 4): B_k' predicted by candidate (k, h)
    rel = compose(inverse(oa)[None, None], Bp)
    pred = jnp.where(a_obs[None, None, :, None], rel, inverse(rel))  # observation k' predicted
    d_xy = pred[..., 2:] - z4[None, None, :, 2:]
    c = z4[None, None, :, 0] * pred[..., 0] + z4[None, None, :, 1] * pred[..., 1]  # cos, sin of z^-1 pred
    s = z4[None, None, :, 0] * pred[..., 1] - z4[None, None, :, 1] * pred[..., 0]
    d_psi = jnp.arctan2(jnp.stack([s, -s], -1), jnp.stack([c, -c], -1))  # (K, 2, K', 2) for h' = 0, 1
    # variances of the prediction error (isotropic in translation): both observations, the
    # candidate's heading error levered by the distance either robot travelled since, and
    # both odometries' drift between the two rows (heading drift levered by that distance
    # and by the range)
    (ta, pa), (tb, pb) = inp.drift
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
    kern = jnp.max(jnp.maximum(0.0, 1.0 - q / thr) * prior[None, None], -1)
    return _ConsensusTerms(F, q, kern)


def _consensus_pick(t: _ConsensusTerms, score, prior, usable, cfg: FusionConfig):
    """score (K, 2): summed kernel of each candidate over the usable observations. Returns
    (F* (4,), flip (K,) bool, explained (K,) bool)."""
    score = jnp.where(usable[:, None] & (prior > 0), score, -1.0)
    best = jnp.argmax(score.reshape(-1))  # deterministic: the first of equal scores
    qb = t.q.reshape(-1, *t.q.shape[2:])[best]  # (K', 2)
    # the hypothesis the consensus predicts, with the prior: min q - 2 log prior
    logp = jnp.log(jnp.where(prior > 0, prior, 1.0))  # guard: log 0 (that hypothesis is excluded)
    cost = jnp.where(prior > 0, qb - 2.0 * logp, jnp.inf)
    flip = jnp.argmin(cost, -1) == 1
    explained = usable & (jnp.where(flip, qb[:, 1], qb[:, 0]) < _chi2_3(cfg.consensus_probability))
    return t.F.reshape(-1, 4)[best], flip, explained


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


class _Inputs(NamedTuple):
    rv: Rendezvous  # sanitised
    usable: jax.Array  # (K,) bool
    deleted: jax.Array  # (K,) bool
    prior: jax.Array  # (K, 2)
    z4: jax.Array  # (K, 4) planar observations (SE2 parameters)
    ua: jax.Array  # (K+1, 4) odometry rows of A, B (SE2 parameters)
    ub: jax.Array
    odo: jax.Array  # (2K, 4) odometry steps of A, then B
    info: tuple  # (K, 3) x 3: odometry A, odometry B, mutual (diagonals)
    drift: tuple  # per robot, cumulative (K+1,) variances of translation and heading (noise model)


def _inputs(rv, valid, flip_prob, obs_sigma, cfg: FusionConfig) -> _Inputs:
    """Everything per row, with one sin/cos and one atan2 call site (XLA expands each inline:
    fewer sites compile faster)."""
    rv, valid, deleted, usable, prior, obs_sigma, roll, pitch = _sanitize(rv, valid, flip_prob, obs_sigma, cfg)
    K = rv.observation.shape[0]
    u = poses_to_se2(jnp.concatenate([rv.odom_a, rv.odom_b])).unit_complex_xy
    ua, ub = u[: K + 1], u[K + 1 :]
    odo = jnp.concatenate([compose(inverse(ua[:-1]), ua[1:]), compose(inverse(ub[:-1]), ub[1:])])
    step = se2_to_poses(jaxlie.SE2(odo))
    sa, sb = cfg.odometry_a.sigmas(step[:K]), cfg.odometry_b.sigmas(step[K:])
    zero = jnp.zeros((1,), step.dtype)
    cum = lambda v: jnp.concatenate([zero, jnp.cumsum(v)])  # noqa: E731
    drift = ((cum(sa[:, 0] ** 2), cum(sa[:, 2] ** 2)), (cum(sb[:, 0] ** 2), cum(sb[:, 2] ** 2)))
    if cfg.information == "paper":
        km = 0.5 * cfg.kappa * jnp.exp(-jnp.abs(roll) - jnp.abs(pitch))
        o = jnp.full((K, 3), cfg.kappa, step.dtype)
        info = (o, o, jnp.stack([km, km, cfg.tau * km], -1))
    else:
        info = (1.0 / sa ** 2, 1.0 / sb ** 2, 1.0 / obs_sigma ** 2)
    return _Inputs(rv, usable, deleted, prior, _planar(rv.observation), ua, ub, odo, info, drift)


def _measurements(inp: _Inputs, flip, usable):
    """(3K, 4) measurements (odometry A, odometry B, mutual with the chosen heading) and their
    (3K, 3, 3) information (mutual: zero where not usable)."""
    z4 = inp.z4
    K = z4.shape[0]
    z_used = jnp.where(flip[:, None], compose(z4, jnp.broadcast_to(_ROT_PI.astype(z4.dtype), z4.shape)), z4)
    Z = jnp.stack([inp.odo[:K], inp.odo[K:], z_used], 1).reshape(3 * K, 4)
    i_a, i_b, i_m = inp.info
    i_m = jnp.where(usable[:, None], i_m, 0.0)
    info = jnp.stack([i_a, i_b, i_m], 1).reshape(3 * K, 3)[:, :, None] * jnp.eye(3, dtype=z4.dtype)
    return Z, info


def _assemble(inp: _Inputs, F, flip, explained, usable, cfg: FusionConfig) -> FusionGraph:
    """The ladder graph with B placed by F (SE2 params (4,)) and the chosen headings."""
    K = inp.z4.shape[0]
    flip = flip & usable
    T0 = jnp.stack([inp.ua, compose(F[None], inp.ub)], 1).reshape(2 * K + 2, 4)
    Z, info = _measurements(inp, flip, usable)
    k = jnp.arange(1, K + 1)
    A_k, B_k = 2 * k, 2 * k + 1
    mutual = jnp.where(inp.rv.a_observes[:, None], jnp.stack([A_k, B_k], -1), jnp.stack([B_k, A_k], -1))
    edges = jnp.stack([jnp.stack([A_k - 2, A_k], -1), jnp.stack([B_k - 2, B_k], -1), mutual], 1).reshape(3 * K, 2)
    w0 = (explained if cfg.gnc_init_weights == "consensus" else usable).astype(T0.dtype)
    return FusionGraph(T0, Z, edges.astype(jnp.int32), info, usable, w0, flip, explained, inp.deleted,
                       inp.rv.a_observes)


def _graph(rv, valid, flip_prob, obs_sigma, cfg: FusionConfig) -> FusionGraph:
    inp = _inputs(rv, valid, flip_prob, obs_sigma, cfg)
    t = _consensus_terms(inp, cfg)
    score = jnp.sum(jnp.where(inp.usable[None, None, :], t.kern, 0.0), -1)
    F, flip, explained = _consensus_pick(t, score, inp.prior, inp.usable, cfg)
    return _assemble(inp, F, flip, explained, inp.usable, cfg)


def _problem(g: FusionGraph) -> Problem:
    return Problem(g.T0, inverse(g.Z), g.edges[:, 0], g.edges[:, 1], g.information,
                   jnp.zeros(g.edges.shape[0], bool), None, None, None)


def _edge_weights(w):
    """(K,) mutual weights -> (3K,) edge weights (odometry edges: 1)."""
    one = jnp.ones_like(w)
    return jnp.stack([one, one, w], 1).reshape(-1)


def _mutual_u2(T, p: Problem, g: FusionGraph):
    """GTSAM's factor error 0.5 r^T Omega r of each mutual edge at T (K,)."""
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
    weights (K,), weighted cost, GNC iterations, linear solves). The first solve (initial
    weights) is iteration 0 of the same loop: one copy of the solver in the program."""
    p = _problem(g)
    T0 = p.T0
    dt = T0.dtype
    barc = jnp.asarray(cfg.barc_sq, dt)
    if cfg.robust == "gnc_tls":
        u2_0 = _mutual_u2(T0, p, g)
        excess = 2.0 * u2_0 - barc
        mu0 = jnp.min(jnp.where(g.usable & (excess > 0), barc / jnp.where(excess > 0, excess, 1.0), jnp.inf))
        mu0 = jnp.where(jnp.isfinite(mu0), jnp.maximum(mu0, 1e-6), -1.0)
        skip = (mu0 <= 0) | ~jnp.any(g.usable)
    else:
        mu0, skip = jnp.asarray(-1.0, dt), jnp.asarray(True)

    def body(c):
        T, w, mu, prev, _, it, solves, _ = c
        first = it == 0
        w = jnp.where(first, g.init_weights, _tls_weights(_mutual_u2(T, p, g), mu, barc, g.usable))
        start = T if cfg.gnc_warm_start else T0
        T, cost, n = _solve(p, jnp.where(first, T0, start), w, g.a_observes, cfg)
        rel = jnp.abs(cost - prev) / jnp.maximum(prev, 1e-7)
        binary = jnp.all(jnp.abs(w - jnp.round(w)) <= cfg.gnc_weights_tol)
        done = jnp.where(first, skip, (rel < cfg.gnc_relative_cost_tol) | binary | (it >= cfg.gnc_max_iterations))
        mu = jnp.where(first, mu, mu * cfg.gnc_mu_step)
        return T, w, mu, cost, cost, it + 1, solves + n, done

    inf = jnp.asarray(jnp.inf, dt)
    zero = jnp.asarray(0, jnp.int32)
    c = (T0, g.init_weights, mu0.astype(dt), inf, inf, zero, zero, jnp.asarray(False))
    T, w, _, _, cost, it, solves, _ = jax.lax.while_loop(lambda c: ~c[-1], body, c)
    # guard: no usable observation leaves B undetermined (singular steps): keep the start
    has = jnp.any(g.usable)
    T = jnp.where(has & jnp.all(jnp.isfinite(T)), T, T0)
    return T, w, jnp.where(has, cost, 0.0), it - 1, solves


def _final_step(T, g: FusionGraph, w, cfg: FusionConfig):
    """One undamped Gauss-Newton step from T (weights fixed): differentiable in the graph's
    measurements and information (the implicit-function derivative at an optimum)."""
    p = _problem(g)
    K = g.usable.shape[0]
    q = p._replace(info=p.info * _edge_weights(w)[:, None, None])
    D, Lo, gv, _ = ladder_normal_equations(T, q, g.a_observes, dataclasses.replace(cfg.solver, robust="none"))
    gauge = jnp.zeros((K + 1, 6), bool).at[0, :3].set(True)
    # guard: with no mutual edge B's placement is free (H singular): a unit ridge then keeps
    # the (masked) step and its derivative finite; otherwise one at the dtype's resolution of
    # the largest block: the unpivoted block elimination of a long chain held by a few mutual
    # edges lost all precision in float32 without it (NaN under one XLA compilation, finite
    # under another: the held-out rendezvous, 2 inliers in 400 rows)
    has = jnp.any(g.usable)
    ridge = jnp.where(has, 8 * jnp.finfo(D.dtype).eps * jnp.max(jnp.abs(D)) + jnp.finfo(D.dtype).tiny, 1.0)
    D = D + ridge * jnp.eye(6, dtype=D.dtype)
    x = band_solve(D, Lo, -gv[..., None], cfg.solver.band_solver)[..., 0]
    x = jnp.where(gauge | ~has, 0.0, x)
    return retract(T, x.reshape(2 * K + 2, 3))


def _result(T4, g: FusionGraph, ub0, w, cost, it, solves) -> FusionResult:
    K = g.usable.shape[0]
    pr = T4.reshape(K + 1, 2, 4)
    A, B = pr[:, 0], pr[:, 1]
    rel = compose(inverse(A[1:]), B[1:])
    rel = jnp.where(g.a_observes[:, None], rel, inverse(rel))
    a0b0 = compose(inverse(A[:1]), B[:1])
    F = compose(B[:1], inverse(ub0[None]))
    xyt = se2_to_poses(jaxlie.SE2(jnp.concatenate([A, B, rel, a0b0, F])))
    pa, pb, rel, a0b0, F = jnp.split(xyt, [K + 1, 2 * K + 2, 3 * K + 2, 3 * K + 3])
    inlier = g.usable & (w > 0.5)
    return FusionResult(pa, pb, a0b0[0], F[0], rel, inlier, g.flipped, w, g.deleted, g.consensus, cost, it, solves)


def _check_inputs(rv: Rendezvous, valid, flip_prob, obs_sigma, cfg: FusionConfig) -> None:
    """Shape and config checks at trace time (shapes are static): one RhamlError line each."""
    if not isinstance(cfg, FusionConfig):
        raise RhamlError(f"fuse: cfg must be a FusionConfig, got {type(cfg).__name__}")
    if cfg.information not in ("noise_model", "paper"):
        raise RhamlError(f"FusionConfig.information: {cfg.information!r} is not one of noise_model, paper")
    if cfg.robust not in ("gnc_tls", "none"):
        raise RhamlError(f"FusionConfig.robust: {cfg.robust!r} is not one of gnc_tls, none")
    K = int(np.shape(rv.observation)[0]) if np.ndim(rv.observation) == 2 else -1
    check_shape("rendezvous.observation", rv.observation, (None, 7))
    if K < 1:
        raise RhamlError("rendezvous: at least one row is needed")
    check_shape("rendezvous.odom_a", rv.odom_a, (K + 1, 3))
    check_shape("rendezvous.odom_b", rv.odom_b, (K + 1, 3))
    check_shape("rendezvous.a_observes", rv.a_observes, (K,))
    for name, a, shape in (("valid", valid, (K,)), ("flip_prob", flip_prob, (K,)), ("obs_sigma", obs_sigma, (K, 3))):
        if a is not None:
            check_shape(name, a, shape)


def fuse(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid: jax.Array | None = None,
         flip_prob: jax.Array | None = None, obs_sigma: jax.Array | None = None) -> FusionResult:
    """Robust fusion of K rows of odometry and observations (see the module docstring).

    valid (K,) bool: rows with a rendezvous (others: odometry only); flip_prob (K,): the
    probability that an observation's heading is turned by 180 deg (None: 0.5); obs_sigma
    (K, 3): per-row observation sigmas (x, y in m, psi in rad; None: the config's). Pure and
    jit-able with `cfg` static (`fuse_jit`), vmappable, differentiable in rv and obs_sigma."""
    _check_inputs(rv, valid, flip_prob, obs_sigma, cfg)
    sg = jax.lax.stop_gradient
    g0 = _graph(jax.tree.map(sg, rv), valid, None if flip_prob is None else sg(flip_prob),
                None if obs_sigma is None else sg(obs_sigma), cfg)
    return _fuse_graph(rv, valid, obs_sigma, g0, cfg)


def _fuse_graph(rv, valid, obs_sigma, g0: FusionGraph, cfg: FusionConfig) -> FusionResult:
    """GNC on g0 (no gradient), then the differentiable final step."""
    sg = jax.lax.stop_gradient
    T, w, cost, it, solves = _robust_solve(g0, cfg)
    # the differentiable graph: the same decisions (flips, weights), with measurements and
    # information traced from the inputs
    g, ub0 = _graph_fixed(rv, valid, obs_sigma, cfg, g0)
    T = _final_step(sg(T), g, sg(w), cfg)
    return _result(T, g, ub0, w, cost, it, solves)


def _graph_fixed(rv, valid, obs_sigma, cfg: FusionConfig, g0: FusionGraph):
    """g0's graph with measurements and information recomputed (differentiably) from the
    inputs; also B's first odometry row (SE2 params)."""
    inp = _inputs(rv, valid, None, obs_sigma, cfg)
    Z, info = _measurements(inp, g0.flipped, g0.usable)
    return g0._replace(Z=Z, information=info), inp.ub[0]


def fuse_online(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid: jax.Array | None = None,
                flip_prob: jax.Array | None = None, obs_sigma: jax.Array | None = None) -> FusionResult:
    """Online fusion: at each row k, `fuse` on the rendezvous <= k (later rows masked: their
    dangling odometry changes nothing), as one `lax.scan` compiled once for K rows. The
    consensus terms (every candidate against every observation) are computed once and summed
    causally, so update k costs one GNC solve on the K-row graph; rows without a usable
    observation reuse the last update (under vmap both branches run).

    Row k of `relative`, `a0_T_b0` (K, 3), `odom_a_T_odom_b` (K, 3), `inlier`, `flipped` and
    `weights` is what the update at row k said about row k; `poses_a`, `poses_b`, `deleted`,
    `consensus`, `final_cost` are the last update's (= `fuse` on everything); `iterations` and
    `solves` are summed over the updates."""
    return _online(rv, cfg, valid, None, 0.0, 0.0, flip_prob, obs_sigma)[0]


def fuse_online_redetect(rv: Rendezvous, cfg: FusionConfig, valid: jax.Array, candidates: jax.Array, gate: float,
                         heading_deg: float, flip_prob: jax.Array | None = None,
                         obs_sigma: jax.Array | None = None) -> tuple[FusionResult, jax.Array]:
    """`fuse_online` with a second kind of row, in the same single pass: a `candidates` row k
    (K,) bool, not `valid`, joins the graph where its observation `agrees` (`gate`, `heading_deg`)
    with what the update before it predicts for row k, i.e. the graph of the rows before k that
    joined (valid or accepted). Before the first row that joined, nothing is judged. Returns
    (FusionResult, joined (K,) bool: the usable rows of the graph, valid or accepted)."""
    return _online(rv, cfg, valid, candidates, gate, heading_deg, flip_prob, obs_sigma)


def agrees(xypsi, fused, gate: float, heading_deg: float):
    """(N,) bool, the re-detection gate: estimates (N, 3) within `gate` of the fused range of the
    fused poses (N, 3), their headings within `heading_deg` of the fused heading or its opposite
    (the graph tries both)."""
    near = jnp.linalg.norm(xypsi[:, :2] - fused[:, :2], axis=-1) <= gate * jnp.linalg.norm(fused[:, :2], axis=-1)
    d = jnp.abs(wrap_angle(xypsi[:, 2] - fused[:, 2]))
    aligned = jnp.minimum(d, jnp.pi - d) <= jnp.deg2rad(heading_deg)
    return near & aligned


def _online(rv, cfg: FusionConfig, valid, candidates, gate, heading_deg, flip_prob, obs_sigma):
    """The scan behind `fuse_online` and `fuse_online_redetect` (candidates None: none)."""
    _check_inputs(rv, valid, flip_prob, obs_sigma, cfg)
    sg = jax.lax.stop_gradient
    K = rv.observation.shape[0]
    rows = jnp.arange(K)
    confident = jnp.ones((K,), bool) if valid is None else jnp.asarray(valid, bool)
    if candidates is not None:
        check_shape("candidates", candidates, (K,))
    cand = jnp.zeros((K,), bool) if candidates is None else jnp.asarray(candidates, bool) & ~confident
    base = confident | cand  # rows whose observation is read (sanitised) at all
    inp = _inputs(jax.tree.map(sg, rv), base, None if flip_prob is None else sg(flip_prob),
                  None if obs_sigma is None else sg(obs_sigma), cfg)
    t = _consensus_terms(inp, cfg)
    z4 = inp.z4

    def update(k, used, score):
        F, flip, explained = _consensus_pick(t, score, inp.prior, used, cfg)
        g0 = _assemble(inp, F, flip, explained, used, cfg)
        return _fuse_graph(rv, base & (rows <= k), obs_sigma, g0, cfg)

    def step(carry, k):
        last, used, score = carry  # used (K,) bool: rows < k in the graph; score (K, 2): their consensus sum
        join = confident[k] & inp.usable[k]
        if candidates is not None:  # static: plain fuse_online traces no gate
            pred = last.relative[k]  # the last update's prediction of row k (its odometry carries it)
            # guard: before the first row in the graph, the last update answers nothing (its graph
            # has no rendezvous), and a candidate would be judged by garbage
            judged = cand[k] & inp.usable[k] & jnp.any(used) & jnp.all(jnp.isfinite(pred))
            z = se2_to_poses(jaxlie.SE2(z4[k][None]))  # (1, 3) row k's observation (x, y, psi)
            join = join | (judged & agrees(z, pred[None], gate, heading_deg)[0])
        used = used | (join & (rows == k))
        score = score + jnp.where(join, t.kern[:, :, k], 0.0)
        # a row that does not join adds nothing (same graph, same consensus scores): the last
        # update's answer is the batch answer on rows <= k too, no solve needed
        new = join | (k == 0)
        r = jax.lax.cond(new, lambda: update(k, used, score), lambda: last)
        zero = jnp.zeros((), jnp.int32)
        out = (r.relative[k], r.a0_T_b0, r.odom_a_T_odom_b, r.inlier[k], r.flipped[k], r.weights[k],
               jnp.where(new, r.iterations, zero), jnp.where(new, r.solves, zero))
        return (r, used, score), out

    used0, score0 = jnp.zeros((K,), bool), jnp.zeros((K, 2), z4.dtype)
    init = jax.eval_shape(update, jnp.asarray(0), used0, score0)
    init = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), init)
    (last, used, _), (rel, a0b0, F, inl, flp, w, it, sol) = jax.lax.scan(step, (init, used0, score0), rows)
    res = last._replace(relative=rel, a0_T_b0=a0b0, odom_a_T_odom_b=F, inlier=inl, flipped=flp, weights=w,
                        iterations=jnp.sum(it), solves=jnp.sum(sol))
    return res, used


def fusion_graph(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid=None, flip_prob=None,
                 obs_sigma=None) -> tuple[PoseGraph, FusionGraph]:
    """Host side: the graph `fuse` hands to GNC (after deletion, consensus and flips) as a
    PoseGraph (mutual edges of unusable rows dropped; `robust_edges` marks the mutual ones),
    e.g. for `write_g2o`, GTSAM's GncOptimizer or a plot; plus the device-side FusionGraph."""
    _check_inputs(rv, valid, flip_prob, obs_sigma, cfg)
    g = _graph_jit(jax.tree.map(jnp.asarray, rv), valid, flip_prob, obs_sigma, cfg)
    K = int(g.usable.shape[0])
    keep = np.ones((K, 3), bool)
    keep[:, 2] = np.asarray(g.usable)
    keep = keep.reshape(-1)
    robust = np.zeros((K, 3), bool)
    robust[:, 2] = True
    xyt = lambda a: np.stack([a[:, 2], a[:, 3], np.arctan2(a[:, 1], a[:, 0])], 1)  # noqa: E731
    T0, Z = np.asarray(g.T0, np.float64), np.asarray(g.Z, np.float64)
    pg = PoseGraph(xyt(T0), np.asarray(g.edges)[keep], xyt(Z)[keep],
                   np.asarray(g.information)[keep], np.arange(2 * K + 2, dtype=np.int64), 0, robust.reshape(-1)[keep])
    return pg, g


_graph_jit = jax.jit(_graph, static_argnames="cfg")

# small graphs: XLA's thread pool costs more than it brings (see rhaml_pgo_jit)
fuse_jit = jax.jit(fuse, static_argnames="cfg", compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)
"""`fuse` jit-compiled, one executable per shape and config, shared by all callers."""
fuse_online_jit = jax.jit(fuse_online, static_argnames="cfg", compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)
"""`fuse_online` jit-compiled."""
fuse_online_redetect_jit = jax.jit(fuse_online_redetect, static_argnames=("cfg", "gate", "heading_deg"),
                                   compiler_options=SMALL_GRAPH_COMPILER_OPTIONS)
"""`fuse_online_redetect` jit-compiled."""
