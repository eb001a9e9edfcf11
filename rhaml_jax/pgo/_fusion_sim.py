"""Sequences for the robust-fusion tests and benchmarks (host-side NumPy, pure functions of seed).

- `simulate_static_observer`: DESIGN.md section 3's scenarios (circle, sine): the observer A
  stands at the origin (identity odometry), the observed robot B drives `truth` with
  `data.noisy_odometry`; every frame is a rendezvous.
- `simulate_two_robots`: `data.rendezvous`'s two moving robots, both odometries noisy; at a
  frame A observes B when B is inside A's camera view (default camera: +-38.7 deg, 0.5-8 m),
  else B observes A when A is inside B's, else there is no rendezvous (valid False).

Observations are the true relative pose plus Gaussian noise `sigma` (x, y in m, psi in rad;
default the issue's 10 cm, 5 cm, 2.9 deg), then `flip_fraction` of the rendezvous get their
heading turned by 180 deg and `gross_fraction` (others) are replaced by wrong poses, off by
1-3 m in translation with a uniform heading. Odometry is expressed in each robot's own frame
starting at the origin (as a robot's odometry is), so B's odometry frame is A_0 T B_0 in A's.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._fusion import rendezvous_from_frames
from ._rhaml_graph import Rendezvous, observation_from_xy_yaw_rp

__all__ = ["FusionSequence", "simulate_static_observer", "simulate_two_robots"]

ISSUE_SIGMA = (0.10, 0.05, float(np.deg2rad(2.9)))


class FusionSequence(NamedTuple):
    rendezvous: Rendezvous  # K = N frames (see rendezvous_from_frames), numpy float64
    valid: np.ndarray  # (K,) bool: a rendezvous at this frame
    true_relative: np.ndarray  # (K, 3) observed robot in the observer's frame
    a0_T_b0: np.ndarray  # (3,) true
    flipped: np.ndarray  # (K,) bool: heading turned by 180 deg
    gross: np.ndarray  # (K,) bool: replaced by a wrong pose


def _wrap(a):
    return np.arctan2(np.sin(a), np.cos(a))


def _observe(rel, valid, rng, sigma, flip_fraction, gross_fraction):
    K = rel.shape[0]
    meas = rel + rng.standard_normal((K, 3)) * np.asarray(sigma)
    idx = np.flatnonzero(valid)
    n_flip, n_gross = int(round(flip_fraction * idx.size)), int(round(gross_fraction * idx.size))
    pick = rng.permutation(idx)
    flipped = np.zeros(K, bool)
    gross = np.zeros(K, bool)
    flipped[pick[:n_flip]] = True
    gross[pick[n_flip : n_flip + n_gross]] = True
    meas[flipped, 2] += np.pi
    ang = rng.uniform(-np.pi, np.pi, n_gross)
    dist = rng.uniform(1.0, 3.0, n_gross)
    meas[gross, 0] = rel[gross, 0] + dist * np.cos(ang)
    meas[gross, 1] = rel[gross, 1] + dist * np.sin(ang)
    meas[gross, 2] = rng.uniform(-np.pi, np.pi, n_gross)
    meas[:, 2] = _wrap(meas[:, 2])
    return meas, flipped, gross


def relative(a, b):
    """Planar a^-1 b for (..., 3) poses (as `data.relative`, kept here so that importing
    pgo does not import the data package)."""
    d = b[..., :2] - a[..., :2]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], _wrap(b[..., 2] - a[..., 2])], -1)


def _from_origin(odom):
    return relative(odom[:1], odom)


def simulate_static_observer(truth: np.ndarray, seed: int, sigma=ISSUE_SIGMA, flip_fraction: float = 0.0,
                             gross_fraction: float = 0.0) -> FusionSequence:
    """truth (N, 3): B's path in the (static) observer's frame."""
    from ..data import noisy_odometry

    rng = np.random.default_rng([seed, 1])
    N = truth.shape[0]
    odom_b = _from_origin(noisy_odometry(truth, seed))
    odom_a = np.zeros((N, 3))
    valid = np.ones(N, bool)
    meas, flipped, gross = _observe(truth.copy(), valid, rng, sigma, flip_fraction, gross_fraction)
    rv = rendezvous_from_frames(odom_a, odom_b, np.asarray(observation_from_xy_yaw_rp(meas), np.float64),
                                np.ones(N, bool))
    return FusionSequence(rv, valid, truth.copy(), truth[0].copy(), flipped, gross)


def _visible(obs, tgt, hfov=np.arctan2(320.0, 400.0), near=0.5, far=8.0):
    r = relative(obs, tgt)
    d = np.hypot(r[:, 0], r[:, 1])
    return (r[:, 0] > 0) & (np.abs(np.arctan2(r[:, 1], r[:, 0])) <= hfov) & (d >= near) & (d <= far)


def simulate_two_robots(frames: int, seed: int, sigma=ISSUE_SIGMA, flip_fraction: float = 0.0,
                        gross_fraction: float = 0.0, speed: float = 0.05) -> FusionSequence:
    """Two robots moving through `data.Room()` (each `speed` m per frame)."""
    from ..data import noisy_odometry, rendezvous

    rng = np.random.default_rng([seed, 2])
    ta, tb = rendezvous(frames, seed, speed=speed)
    oa = _from_origin(noisy_odometry(ta, seed * 2 + 11))
    ob = _from_origin(noisy_odometry(tb, seed * 2 + 12))
    a_sees, b_sees = _visible(ta, tb), _visible(tb, ta)
    a_obs = a_sees | ~b_sees
    valid = a_sees | b_sees
    rel = np.where(a_obs[:, None], relative(ta, tb), relative(tb, ta))
    meas, flipped, gross = _observe(rel, valid, rng, sigma, flip_fraction, gross_fraction)
    obs = np.asarray(observation_from_xy_yaw_rp(meas), np.float64)
    rv = rendezvous_from_frames(oa, ob, obs, a_obs)
    return FusionSequence(rv, valid, rel, relative(ta[:1], tb[:1])[0], flipped & valid, gross & valid)
