"""Evaluation trajectories (DESIGN.md section 3) and the wheel-odometry noise model.

Poses are planar, (N, 3) float64 arrays of (x, y, psi). The static-observer scenarios are in
the observer's frame; the rendezvous scenario is in a common world frame (a room).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rhaml_jax.errors import RhamlError
from rhaml_jax.planar import between, compose, wrap_angle

# Odometry noise (DESIGN.md section 3): per step, independent.
ODOM_TRANS_FRAC = 0.02  # sigma of each translation axis, as a fraction of the step length
ODOM_DEG_PER_M = 0.5  # sigma of the heading increment per metre travelled


def circle(frames: int = 500) -> np.ndarray:
    """(frames, 3): once counter-clockwise around centre (4.5, 0), radius 2, from (2.5, 0)."""
    _check_frames(frames)
    theta = np.pi + 2.0 * np.pi * np.arange(frames) / frames
    x, y = 4.5 + 2.0 * np.cos(theta), 2.0 * np.sin(theta)
    return np.stack([x, y, wrap_angle(theta + np.pi / 2)], axis=1)


def sine(frames: int = 500) -> np.ndarray:
    """(frames, 3): s in [0, 1] evenly, x = 4.5 + 2.5 sin(4 pi s), y = -1.2 + 2.4 s."""
    _check_frames(frames)
    s = np.linspace(0.0, 1.0, frames)
    x, y = 4.5 + 2.5 * np.sin(4 * np.pi * s), -1.2 + 2.4 * s
    dx, dy = 2.5 * 4 * np.pi * np.cos(4 * np.pi * s), np.full_like(s, 2.4)  # d/ds: heading of travel
    return np.stack([x, y, np.arctan2(dy, dx)], axis=1)


@dataclasses.dataclass(frozen=True)
class Room:
    """A rectangular room [x0, x1] x [y0, y1] (m) with walls of `height` m."""

    x0: float = -1.0
    x1: float = 9.0
    y0: float = -4.0
    y1: float = 4.0
    height: float = 2.5


def rendezvous(frames: int, seed: int, room: Room = Room(), speed: float = 0.25, margin: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Two robots (A, B) moving through `room` along random waypoints: two (frames, 3) arrays.

    Each robot drives at `speed` m per frame towards its next waypoint (drawn uniformly inside
    the room, `margin` from the walls) and turns smoothly (at most 0.3 rad per frame), so the
    motion is what a differential-drive robot could do. Deterministic in `seed`.
    """
    _check_frames(frames)
    rng = np.random.default_rng(seed)

    def waypoint():
        return np.array([rng.uniform(room.x0 + margin, room.x1 - margin), rng.uniform(room.y0 + margin, room.y1 - margin)])

    out = []
    for _ in range(2):
        p, psi = waypoint(), rng.uniform(-np.pi, np.pi)
        goal = waypoint()
        traj = np.empty((frames, 3))
        for i in range(frames):
            traj[i] = (p[0], p[1], psi)
            while np.linalg.norm(goal - p) < speed:
                goal = waypoint()
            want = np.arctan2(goal[1] - p[1], goal[0] - p[0])
            turn = np.clip(wrap_angle(want - psi), -0.3, 0.3)
            psi = wrap_angle(psi + turn)
            step = speed * max(np.cos(turn), 0.0)  # slow down while turning hard
            p = p + step * np.array([np.cos(psi), np.sin(psi)])
        out.append(traj)
    return out[0], out[1]


def noisy_odometry(truth: np.ndarray, seed: int, trans_frac: float = ODOM_TRANS_FRAC, deg_per_m: float = ODOM_DEG_PER_M) -> np.ndarray:
    """(N, 3) odometry of a robot that truly moved along `truth`, starting at its true first pose.

    Each per-frame increment gets independent Gaussian noise: sigma = trans_frac * step length
    on x and y, deg_per_m degrees per metre travelled on the heading.
    """
    rng = np.random.default_rng(seed)
    steps = between(truth[:-1], truth[1:])  # (N-1, 3) true increments
    length = np.hypot(steps[:, 0], steps[:, 1])
    noise = rng.standard_normal(steps.shape) * np.stack([trans_frac * length, trans_frac * length, np.radians(deg_per_m) * length], 1)
    odo = np.empty_like(truth)
    odo[0] = truth[0]
    for i, d in enumerate(steps + noise):
        odo[i + 1] = compose(odo[i], d)
    return odo


def _check_frames(frames: int) -> None:
    if frames < 2:
        raise RhamlError(f"--frames must be at least 2, got {frames}")
