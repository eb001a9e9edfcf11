"""pgo.range_model / fuse_calibrated: recover a range scale that every observation shares, and
refuse to calibrate on observations that carry no trajectory (a localiser that failed)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import pgo
from rhaml_jax.data import circle, noisy_odometry


def _rendezvous(obs_xy, odom_b, psi=None):
    n = len(obs_xy)
    psi = np.zeros(n) if psi is None else psi
    obs = pgo.observation_from_xy_yaw_rp(jnp.asarray(np.c_[obs_xy, psi], jnp.float32))
    return pgo.rendezvous_from_frames(jnp.zeros((n, 3)), jnp.asarray(odom_b, jnp.float32), obs, jnp.ones(n, bool))


def test_recovers_a_shared_range_scale():
    truth = circle(200)
    odom = noisy_odometry(truth, seed=3)
    rng = np.random.default_rng(0)
    for scale in (0.96, 1.0, 1.05):
        rv = _rendezvous(truth[:, :2] * scale + rng.normal(0, 0.02, (200, 2)), odom)
        c = jax.jit(pgo.range_model)(rv, jnp.zeros(3), jnp.ones(200))
        assert abs(float(jnp.exp(c[0])) - scale) < 0.01, (scale, c)
        fixed = pgo.rescale_observations(rv, c)
        np.testing.assert_allclose(np.asarray(fixed.observation[:, 4:6]), truth[:, :2], atol=0.12)


def _fuse(xy, odom, psi=None):
    return jax.jit(pgo.fuse_calibrated, static_argnames="cfg")(_rendezvous(xy, odom, psi), pgo.FusionConfig())


def test_no_calibration_from_garbage():
    """A localiser stuck near one point: range_model's own checks pass a fit on the few rows the
    fusion kept (c_0 about -10 %); fuse_calibrated refuses it, since the calibrated fusion still
    keeps almost none of them."""
    truth = circle(500)
    odom = noisy_odometry(truth, seed=3)
    stuck = np.tile([[6.2, 4.2]], (500, 1)) + np.random.default_rng(1).normal(0, 0.3, (500, 2))
    rv = _rendezvous(stuck, odom)
    first = pgo.fuse_jit(rv, pgo.FusionConfig())
    c_fit = pgo.range_model(rv, first.odom_a_T_odom_b, first.inlier.astype(jnp.float32))
    assert bool(jnp.all(jnp.isfinite(c_fit))) and abs(float(c_fit[0])) > 0.02  # the fit alone is fooled
    fusion, c = _fuse(stuck, odom)
    assert float(jnp.mean(fusion.inlier)) < pgo.MIN_SUPPORT
    np.testing.assert_array_equal(np.asarray(c), 0.0)
    # the first fusion is returned; the two compilations of that solve agree to the float32
    # Gauss-Newton's precision (0.3 mm measured on one machine), not bit for bit, while a kept
    # calibration would have moved the estimates by decimetres
    kept = pgo.fuse_jit(pgo.rescale_observations(rv, c_fit), pgo.FusionConfig())
    assert float(jnp.max(jnp.abs(kept.relative - first.relative))) > 0.05
    np.testing.assert_allclose(np.asarray(fusion.relative), np.asarray(first.relative), atol=2e-3)


def test_calibrates_a_biased_localiser_and_half_garbage():
    """Ranges read 20 % long: the uncalibrated fusion keeps under half the rows, the calibrated one
    nearly all, and c_0 is found; with every other frame garbage, the consistent half calibrates."""
    truth = circle(500)
    odom = noisy_odometry(truth, seed=3)
    rng = np.random.default_rng(0)
    long = truth[:, :2] * 1.2 + rng.normal(0, 0.03, (500, 2))
    psi = truth[:, 2]
    assert float(jnp.mean(pgo.fuse_jit(_rendezvous(long, odom, psi), pgo.FusionConfig()).inlier)) < 0.5
    fusion, c = _fuse(long, odom, psi)
    assert float(jnp.mean(fusion.inlier)) > 0.95 and abs(float(c[0]) - np.log(1.2)) < 0.03
    half = truth[:, :2] * 1.05 + rng.normal(0, 0.05, (500, 2))
    half[::2] = np.tile([[6.2, 4.2]], (250, 1)) + rng.normal(0, 0.3, (250, 2))
    fusion, c = _fuse(half, odom, psi)
    assert abs(float(c[0]) - np.log(1.05)) < 0.01
    np.testing.assert_allclose(np.asarray(fusion.relative[1::2, :2]), truth[1::2, :2], atol=0.15)


def test_relative_errors_weight_each_observation_by_its_range():
    """relative=True is the absolute model with weights (R0 / rho)^2, rho the observed range: a
    percentage read off weighs a far observation less; the two differ on errors that grow with range."""
    truth = circle(200)
    odom = noisy_odometry(truth, seed=3)
    r = np.hypot(truth[:, 0], truth[:, 1])
    bent = truth[:, :2] * (1.02 + 0.01 * (r - r.mean()))[:, None]  # the error grows with the range
    rv = _rendezvous(bent, odom)
    rho = jnp.hypot(rv.observation[:, 4], rv.observation[:, 5])
    fit = jax.jit(pgo.range_model, static_argnames="relative")
    rel = fit(rv, jnp.zeros(3), jnp.ones(200))
    np.testing.assert_allclose(rel, fit(rv, jnp.zeros(3), (pgo.RANGE_R0_M / rho) ** 2, relative=False), atol=1e-5)
    assert abs(float(rel[0] - fit(rv, jnp.zeros(3), jnp.ones(200), relative=False)[0])) > 1e-4


def test_gradient_is_finite_with_an_observation_at_the_observer():
    """An observation at range 0 (a degenerate row) leaves the fit's gradient finite."""
    truth = circle(50)
    odom = noisy_odometry(truth, seed=3)
    obs_xy = truth[:, :2] * 1.03
    obs_xy[7] = 0.0

    def c0(xy):
        obs = pgo.observation_from_xy_yaw_rp(jnp.concatenate([xy, jnp.zeros((50, 1))], -1))
        rv = pgo.rendezvous_from_frames(jnp.zeros((50, 3)), jnp.asarray(odom, jnp.float32), obs, jnp.ones(50, bool))
        return pgo.range_model(rv, jnp.zeros(3), jnp.ones(50).at[7].set(0.0))[0]

    g = jax.grad(c0)(jnp.asarray(obs_xy, jnp.float32))
    assert bool(jnp.all(jnp.isfinite(g))) and float(jnp.abs(g).sum()) > 0


def test_a_window_keeps_the_odometrys_drift_out_of_the_scale():
    """Exact observations, drifting odometry: one transform for the whole 500-frame circle reads the
    drift as a range error (up to half a percent); a transform per 200 rows does not, at either scale."""
    truth = circle(500)
    fit = jax.jit(pgo.fuse_calibrated, static_argnames=("cfg", "window"))
    errors = {None: [], 200: []}
    for seed in range(1, 6):
        odom = noisy_odometry(truth, seed=seed)
        for scale in (1.0, 1.03):
            rv = _rendezvous(truth[:, :2] * scale, odom, truth[:, 2])
            for window in errors:
                errors[window].append(abs(float(fit(rv, pgo.FusionConfig(), window=window)[1][0]) - np.log(scale)))
    assert max(errors[200]) < 0.0025, errors[200]
    assert sum(errors[200]) < 0.5 * sum(errors[None]) and max(errors[None]) > 0.004, errors


def test_drift_tie_between_windows_spans_window_and_whole_sequence():
    """`drift_sigma` ties consecutive windows' transforms: loose, the fit is the windowed one; tight,
    the windows move as one and the fit is the whole sequence's (up to the weak pull to the fused
    transform); in between it differs from both."""
    truth = circle(300)
    rv = _rendezvous(truth[:, :2] * 1.03, noisy_odometry(truth, seed=2), truth[:, 2])
    fit = jax.jit(pgo.range_model, static_argnames=("window", "drift_sigma"))
    F, w = jnp.zeros(3), jnp.ones(300)
    windowed, whole = fit(rv, F, w, window=50)[0], fit(rv, F, w)[0]
    assert abs(float(windowed - whole)) > 1e-3, (windowed, whole)  # the check below can tell them apart
    np.testing.assert_allclose(fit(rv, F, w, window=50, drift_sigma=(1e3, 1e3, 1e3))[0], windowed, atol=2e-5)
    np.testing.assert_allclose(fit(rv, F, w, window=50, drift_sigma=(1e-5, 1e-5, 1e-5))[0], whole, atol=3e-4)
    mid = fit(rv, F, w, window=50, drift_sigma=(0.02, 0.02, 0.005))[0]
    assert min(abs(float(mid - windowed)), abs(float(mid - whole))) > 1e-5


def test_window_max_scale_keeps_the_whole_sequences_fit_for_a_large_scale():
    """`window_max_scale`: the windowed calibration where the whole sequence's fit finds a small
    scale, the whole sequence's where it finds a larger one (a look the localiser does not read)."""
    truth = circle(400)
    fit = jax.jit(pgo.fuse_calibrated, static_argnames=("cfg", "window", "window_max_scale"))
    odom = noisy_odometry(truth, seed=4)
    for scale in (1.005, 1.10):
        rv = _rendezvous(truth[:, :2] * scale, odom, truth[:, 2])
        whole, windowed = fit(rv, pgo.FusionConfig())[1], fit(rv, pgo.FusionConfig(), window=100)[1]
        assert abs(float(whole[0] - windowed[0])) > 1e-4, (scale, whole, windowed)  # the two differ
        picked = fit(rv, pgo.FusionConfig(), window=100, window_max_scale=0.02)[1]
        np.testing.assert_allclose(picked, windowed if scale < 1.02 else whole, atol=1e-7)
