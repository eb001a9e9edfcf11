"""Synthetic two-robot rendezvous sequences for tests, benchmarks and the outlier study.

Both robots drive smooth random paths in a common world frame; odometry follows DESIGN.md
section 3 (per step: sigma = 2 % of the step length on each translation axis, 0.5 deg per metre
on heading) and starts at each robot's true first pose. At each rendezvous one robot (chosen
at random) observes the other: the true relative pose plus Gaussian noise, with small roll and
pitch noise; `outlier_fraction` of the observations are replaced by wrong ones (off by 1-3 m
in translation and 90-180 deg in yaw).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rhaml_jax.planar import between, compose, wrap_angle
from ._rhaml_graph import Rendezvous

__all__ = ["SimulatedRendezvous", "simulate_rendezvous"]


class SimulatedRendezvous(NamedTuple):
    rendezvous: Rendezvous  # numpy float64 arrays
    true_a: np.ndarray  # (K+1, 3) true poses of A at start and rendezvous
    true_b: np.ndarray  # (K+1, 3)
    a0_T_b0: np.ndarray  # (3,) true B_0 in A_0's frame
    outlier: np.ndarray  # (K,) bool: observation replaced by a wrong one


def _drive(rng, start, steps, step_len):
    """True path (steps+1, 3) and noisy odometry (steps+1, 3) starting at the true start."""
    true = [start]
    odom = [start]
    heading_rate = 0.0
    for _ in range(steps):
        heading_rate = 0.8 * heading_rate + rng.normal(0, 0.15)
        d = step_len * (1.0 + 0.2 * rng.uniform(-1, 1))
        motion = np.array([d, 0.0, heading_rate * d])
        true.append(compose(true[-1], motion))
        noisy = motion + rng.normal(0, 1, 3) * np.array([0.02 * d, 0.02 * d, np.deg2rad(0.5) * d])
        odom.append(compose(odom[-1], noisy))
    return np.array(true), np.array(odom)


def simulate_rendezvous(K: int = 100, seed: int = 0, steps_between: int = 5, step_len: float = 0.2,
                        sigma_xy: float = 0.05, sigma_yaw_deg: float = 2.0, sigma_rp_deg: float = 2.0,
                        outlier_fraction: float = 0.0, tilted_fraction: float = 0.0) -> SimulatedRendezvous:
    """K rendezvous, each `steps_between` odometry steps apart. `tilted_fraction` of the
    observations get a roll or pitch above 10 deg (which DeleteErroneousNodes should drop)."""
    from ._rhaml_graph import observation_from_xy_yaw_rp

    rng = np.random.default_rng(seed)
    steps = K * steps_between
    ta, oa = _drive(rng, np.zeros(3), steps, step_len)
    b0 = np.array([rng.uniform(1, 3), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)])
    tb, ob = _drive(rng, b0, steps, step_len)
    idx = np.arange(0, steps + 1, steps_between)  # start, then each rendezvous
    true_a, true_b = ta[idx], tb[idx]
    a_obs = rng.uniform(size=K) < 0.5
    rel = np.where(a_obs[:, None], between(true_a[1:], true_b[1:]), between(true_b[1:], true_a[1:]))
    noise = rng.normal(0, 1, (K, 3)) * np.array([sigma_xy, sigma_xy, np.deg2rad(sigma_yaw_deg)])
    meas = rel + noise
    meas[:, 2] = wrap_angle(meas[:, 2])
    outlier = np.zeros(K, bool)
    n_out = int(round(outlier_fraction * K))
    if n_out:
        outlier[rng.choice(K, n_out, replace=False)] = True
        ang = rng.uniform(-np.pi, np.pi, n_out)
        dist = rng.uniform(1.0, 3.0, n_out)
        meas[outlier, 0] += dist * np.cos(ang)
        meas[outlier, 1] += dist * np.sin(ang)
        meas[outlier, 2] = wrap_angle(meas[outlier, 2] + rng.choice([-1, 1], n_out) * rng.uniform(np.pi / 2, np.pi, n_out))
    rp = rng.normal(0, np.deg2rad(sigma_rp_deg), (K, 2))
    n_tilt = int(round(tilted_fraction * K))
    if n_tilt:
        tilt = rng.choice(K, n_tilt, replace=False)
        rp[tilt, rng.integers(0, 2, n_tilt)] = rng.choice([-1, 1], n_tilt) * rng.uniform(np.deg2rad(12), np.deg2rad(40), n_tilt)
    obs = np.asarray(observation_from_xy_yaw_rp(meas, rp), np.float64)
    rv = Rendezvous(oa[idx], ob[idx], obs, a_obs)
    return SimulatedRendezvous(rv, true_a, true_b, between(true_a[0], true_b[0]), outlier)
