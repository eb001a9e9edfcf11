"""pgo.range_model: recovers a range scale that every observation shares, and refuses to
calibrate on observations that carry no trajectory (a localiser that failed)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import pgo
from rhaml_jax.data import circle, noisy_odometry


def _rendezvous(obs_xy, odom_b):
    n = len(obs_xy)
    psi = np.zeros(n)
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


def test_no_calibration_from_garbage():
    truth = circle(200)
    odom = noisy_odometry(truth, seed=3)
    stuck = np.tile([[6.2, 4.2]], (200, 1)) + np.random.default_rng(1).normal(0, 0.3, (200, 2))
    c = jax.jit(pgo.range_model)(_rendezvous(stuck, odom), jnp.zeros(3), jnp.ones(200))
    assert bool(jnp.all(jnp.isfinite(c))) and abs(float(c[0])) <= 0.3
