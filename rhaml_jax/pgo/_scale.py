"""The observations' range error, calibrated from odometry.

An image-based localiser reads ranges with an error that every frame shares (the robot's size
misjudged: another camera, another paint, BENCHMARKS.md), and that grows with the range (the
shipped IML reads 1 % long at 2.7 m and 5 % at 6.4 m on our circle). No pose graph that trusts
its observations' ranges can remove that: a rigid transform between the odometry frames cannot
stretch a trajectory. Wheel odometry is metric, though, and over a sequence in which the
observed robot moves, its path's extent fixes the range error. Model, with rho the observed
and r the true range (both about the observer):

    rho = r exp(c_0 + c_1 (r - R0)),      R0 = 4.5 m (the middle of the scenarios' ranges)

fitted with the transform F = odom_A T odom_B by Gauss-Newton on the observations' x, y
(predicted by odometry and F) over the rows the robust fusion kept, with priors c_0 ~ N(0, 0.1^2)
and c_1 ~ N(0, (0.05 / m)^2) that keep the correction near zero where the path does not tell.
By default only the scale c_0 is fitted (`slope=False`): for a static observer and a path that
runs mostly towards and away from it (the sine) a translation of F along the line of sight and
the slope c_1 explain the same errors (measured: the sine's fit then read c_0 = 0.050 for a
true 0.025; BENCHMARKS.md, "Pipeline").

Odometry drifts, so one rigid F for a whole sequence cannot match the path's far end, and a
scale fitted with it takes up some of the drift: given the true relative poses of validation
sequences as observations it read +0.2 to +0.4 %, more than the refiner's own range error.
`window` fits one F per that many consecutive rows with the scale shared (a weak prior ties
each F to the fused one): drift within a window is small, and the window's path still shows the
scale (the pipeline's default for refined estimates: 200 rows; BENCHMARKS.md, "The range
calibration read the odometry's drift"). But windows also take up part of a large scale: where the
whole sequence's fit finds more than `window_max_scale` (the pipeline: 2 %, where the refiner no
longer reads the look) the whole sequence's fit is kept (BENCHMARKS.md, "The range window only
for small scales").

The observations' errors are taken as relative by default (`relative=True`: sigma = obs_sigma_m
rho / R0, a monocular range read a percentage off), which weights the far observations, whose
errors are largest and vary most along a path, less. On 8 validation sequences it fitted the scale
better for both stages' estimates (rms error 1.08 -> 0.73 % with IML's, 0.40 -> 0.34 % with the
refiner's); fused ATE 0.046 -> 0.034 with IML's, 0.0158 -> 0.0170 (level) with the refiner's
(BENCHMARKS.md, "Range calibration with the refiner").

`fuse_calibrated` is the whole batch step (fuse, fit, rescale, fuse again) with a guard against
a localiser that failed: a calibration is kept only if the fusion with it keeps at least
`MIN_SUPPORT` of the valid observations. A failed localiser's answers can hold a small
consistent subset (24 of 500 on the held-out circle, where the fit read -15 %), but rescaling
garbage does not make it agree with the odometry; a biased localiser's calibrated ranges do
(BENCHMARKS.md, "A guard for the range calibration").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from rhaml_jax.planar import between, compose

from ._fusion import FusionConfig, FusionResult, fuse
from ._rhaml_graph import Rendezvous, _planar

__all__ = ["MAX_LOG_SCALE", "MIN_SUPPORT", "RANGE_R0_M", "fuse_calibrated", "range_model", "rescale_observations"]

RANGE_R0_M = 4.5
MAX_LOG_SCALE = 0.3  # a range error beyond +-35 % is no calibration but a localiser that failed
# the share of the valid observations the calibrated fusion must keep (measured: 93-100 % on
# validation sequences, 50 % with every other frame garbage, 3-5 % for failed localisers)
MIN_SUPPORT = 0.25


def _log_ratio(c, r):
    return c[0] + c[1] * (r - RANGE_R0_M)


def range_model(rv: Rendezvous, odom_a_T_odom_b: jax.Array, weights: jax.Array, obs_sigma_m: float = 0.1,
                prior_sigma=(0.1, 0.05), slope: bool = False, iterations: int = 8, relative: bool = True,
                window: int | None = None, drift_sigma: tuple[float, float, float] | None = None) -> jax.Array:
    """(2,) coefficients c of rho = r exp(c_0 + c_1 (r - R0)) from rows with `weights` (K,) (e.g.
    the fusion's inliers), starting from the fused transform between the odometry frames (3,);
    c_1 = 0 unless `slope`; `window`: rows per window of consecutive rows, each with its own
    transform (None: one for all); `drift_sigma` (m, m, rad): consecutive windows' transforms also
    tied to each other by that much (a random walk, as odometry drifts). Pure JAX, fixed iteration
    count, differentiable."""
    z = _planar(rv.observation)[:, 2:]  # (K, 2) observed x, y
    oa, ob = rv.odom_a[1:], rv.odom_b[1:]
    K = z.shape[0]
    W = K if window is None else min(window, K)
    M = -(-K // W)  # windows
    win = jnp.arange(K) // W
    w = jnp.sqrt(jnp.asarray(weights, z.dtype))[:, None] / obs_sigma_m
    if relative:  # sigma grows with the observed range rho, from 1 m on (the floor: finite weight
        # at rho = 0; the 1e-12: a finite gradient there, where sqrt's is infinite)
        w = w * (RANGE_R0_M / jnp.maximum(jnp.sqrt(jnp.sum(z**2, -1, keepdims=True) + 1e-12), 1.0))
    nc = 2 if slope else 1
    prior = jnp.asarray(prior_sigma[:nc], z.dtype)

    F_sigma = jnp.asarray([1.0, 1.0, 0.2], z.dtype)  # m, m, rad: a weak pull of every window's transform
    # towards the fused one (a window without kept rows stays there)

    def coefficients(theta):
        c = theta[3 * M:]
        return c if slope else jnp.concatenate([c, jnp.zeros((1,), theta.dtype)])

    def residuals(theta):  # theta = (F_1 (x, y, psi), ..., F_M, c_0[, c_1])
        F = theta[: 3 * M].reshape(M, 3)
        B = compose(F[win], ob)
        rel = jnp.where(rv.a_observes[:, None], between(oa, B), between(B, oa))[:, :2]
        r = jnp.sqrt(jnp.sum(rel**2, -1) + 1e-12)  # guard: finite gradient with the robots at one spot
        pred = rel * jnp.exp(_log_ratio(coefficients(theta), r))[:, None]
        pull = ((F - odom_a_T_odom_b) / F_sigma).reshape(-1) if M > 1 else jnp.zeros((0,), z.dtype)
        if drift_sigma is not None and M > 1:
            pull = jnp.concatenate([pull, ((F[1:] - F[:-1]) / jnp.asarray(drift_sigma, z.dtype)).reshape(-1)])
        return jnp.concatenate([(w * (z - pred)).reshape(-1), pull, theta[3 * M:] / prior])

    def step(theta, _):
        J = jax.jacfwd(residuals)(theta)  # (2K [+ 3M] + nc, 3M + nc)
        r = residuals(theta)
        H = J.T @ J + 1e-9 * jnp.eye(3 * M + nc, dtype=J.dtype)  # guard: the priors keep H positive definite
        return theta - jnp.linalg.solve(H, J.T @ r), None

    theta0 = jnp.concatenate([jnp.tile(odom_a_T_odom_b, M), jnp.zeros((nc,), odom_a_T_odom_b.dtype)])
    theta, _ = jax.lax.scan(step, theta0, None, length=iterations)
    # guard: undamped Gauss-Newton on garbage (a localiser that does not see the robot) can
    # diverge; keep the fit only if it lowered the cost, is finite, and stays within +-30 %
    cost = lambda t: jnp.sum(residuals(t) ** 2)  # noqa: E731
    c = coefficients(theta)
    ok = jnp.all(jnp.isfinite(c)) & (cost(theta) <= cost(theta0)) & (jnp.abs(c[0]) <= MAX_LOG_SCALE)
    return jnp.where(ok, c, 0.0)


def rescale_observations(rv: Rendezvous, c: jax.Array, iterations: int = 6) -> Rendezvous:
    """The rendezvous with every observation's x, y moved to the range r the model says it
    saw (rho = r exp(c_0 + c_1 (r - R0)) solved by fixed-point iteration, a contraction for
    |c_1| R0 < 1), bearings and headings kept."""
    xy = rv.observation[:, 4:6]
    rho = jnp.sqrt(jnp.sum(xy**2, -1) + 1e-12)
    r = rho
    for _ in range(iterations):
        r = rho * jnp.exp(-_log_ratio(c, r))
    obs = rv.observation.at[:, 4:6].set(xy * (r / rho)[:, None])
    return rv._replace(observation=obs)


def fuse_calibrated(rv: Rendezvous, cfg: FusionConfig = FusionConfig(), valid: jax.Array | None = None,
                    flip_prob: jax.Array | None = None, relative: bool = True, slope: bool = False,
                    min_support: float = MIN_SUPPORT, window: int | None = None,
                    drift_sigma: tuple[float, float, float] | None = None,
                    window_max_scale: float | None = None) -> tuple[FusionResult, jax.Array]:
    """`fuse`, the range model fitted on its inliers (`range_model`), and `fuse` again on the
    rescaled observations -> (fusion, c (2,)). The calibrated fusion is kept only if it keeps
    at least `min_support` of the valid rows (K,); else the first fusion and c = 0.
    `window_max_scale`: with a `window`, the windowed fit only where the whole sequence's fit finds
    |c_0| under it; else the whole sequence's (a localiser that does not read the look reads
    ranges several percent off, a scale one transform fits better than windows that can take part
    of it up). Jit with cfg, relative, slope, window, drift_sigma, window_max_scale static."""
    valid = jnp.ones(rv.observation.shape[0], bool) if valid is None else valid
    first = fuse(rv, cfg, valid=valid, flip_prob=flip_prob)
    used = (first.inlier & valid).astype(rv.observation.dtype)
    # guard: with no inlier the transform is undetermined (NaN); fit from the identity then
    # (the cost guard inside range_model refuses it, and the support test below too)
    F = jnp.where(jnp.any(used > 0), first.odom_a_T_odom_b, 0.0)

    def calibrated(window, drift_sigma):  # the fit on the first fusion's inliers, the fusion again
        c = range_model(rv, F, used, cfg.obs_sigma_xy_m, relative=relative, slope=slope, window=window,
                        drift_sigma=drift_sigma)
        second = fuse(rescale_observations(rv, c), cfg, valid=valid, flip_prob=flip_prob)
        support = jnp.sum(second.inlier & valid) / jnp.maximum(jnp.sum(valid), 1)
        keep = (support >= min_support) & jnp.any(c != 0)
        return jax.tree.map(lambda a, b: jnp.where(keep, a, b), second, first), jnp.where(keep, c, 0.0)

    result = calibrated(window, drift_sigma)
    if window is not None and window_max_scale is not None:
        whole = calibrated(None, None)
        result = jax.tree.map(lambda a, b: jnp.where(jnp.abs(whole[1][0]) < window_max_scale, a, b), result, whole)
    return result
