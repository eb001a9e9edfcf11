"""A simulated two-robot exploration like the paper's map-fusion experiment (its section V-D).

A field (10 m x 7 m by default) with random obstacles; robot A starts near the left wall, B near
the right one. Each explores its part of the field by frontiers: it drives to the nearest (by
path length) frontier cell of the map it has built so far (a free cell next to an unknown one),
along a breadth-first path on that map with its obstacles inflated by the robot's radius
(unknown cells count as passable, and the path is replanned every second as the lidar sees
more). After `explore_steps` steps (or when no frontier is left) both drive to the middle and
face each other; the rendezvous then lasts `rendezvous_seconds` while both move slowly, and
`rendezvous_frames` frames at equal intervals are kept.

The planner works on a map built along the *true* poses (so that the simulated robot does not
hit what it has seen); the map each robot reports is built from the same lidar scans along its
*noisy odometry* (DESIGN.md section 3's model, `data.noisy_odometry`) in its own odometry frame,
whose origin is its start pose: these are the maps that get merged.
"""

from __future__ import annotations

import dataclasses
from collections import deque

import jax.numpy as jnp
import numpy as np

from rhaml_jax import planar
from rhaml_jax.errors import RhamlError
from rhaml_jax.mapping._lidar import GridSpec, LidarConfig, beam_angles, cast_rays, integrate_scans, occupancy_from_log_odds
from rhaml_jax.mapping._mapfile import OccupancyMap
from rhaml_jax.mapping._world import Field, random_field

__all__ = ["ExploreConfig", "ExploreRun", "simulate_exploration", "robot_map", "scan"]


@dataclasses.dataclass(frozen=True)
class ExploreConfig:
    width: float = 10.0  # m, the field
    height: float = 7.0
    obstacles: int = 12
    resolution: float = 0.05  # m, the robots' maps
    lidar: LidarConfig = LidarConfig()
    dt: float = 0.1  # s per step (odometry, scans)
    speed: float = 0.4  # m/s
    turn_rate: float = 1.5  # rad/s
    robot_radius: float = 0.3  # m, for planning and collisions (the Pioneer is 455 x 381 mm)
    explore_steps: int = 450  # steps of frontier exploration before heading for the rendezvous
    max_steps: int = 2000  # the whole run
    overlap: float = 1.0  # m: A explores x < width/2 + overlap/2, B x > width/2 - overlap/2
    meet_distance: float = 2.4  # m between the robots when the rendezvous starts
    rendezvous_seconds: float = 5.0
    rendezvous_frames: int = 10
    scan_every: int = 2  # a scan enters the reported map every this many steps
    plan_resolution: float = 0.1  # m, the planner's grid


@dataclasses.dataclass(frozen=True)
class ExploreRun:
    field: Field
    truth_a: np.ndarray  # (N, 3) true poses in the field
    truth_b: np.ndarray
    odom_a: np.ndarray  # (N, 3) odometry in A's own frame (its start pose is the origin)
    odom_b: np.ndarray
    ranges_a: np.ndarray  # (N, beams) lidar ranges (m)
    ranges_b: np.ndarray
    rendezvous: np.ndarray  # (F,) step indices of the rendezvous frames
    config: ExploreConfig

    @property
    def a0_T_b0(self) -> np.ndarray:
        """The true A_0 T B_0: B's start pose (map origin) in A's."""
        return planar.between(self.truth_a[0], self.truth_b[0])


def scan(field_segments, pose, cfg: LidarConfig, rng: np.random.Generator) -> np.ndarray:
    """One lidar scan (beams,) from a true pose (3,), with Gaussian range noise."""
    th = pose[2] + beam_angles(cfg)
    d = np.stack([np.cos(th), np.sin(th)], -1)[None]
    r = np.asarray(cast_rays(jnp.asarray(field_segments, jnp.float32), jnp.asarray(pose[None, :2], jnp.float32),
                             jnp.asarray(d, jnp.float32), cfg.max_range))[0]
    hit = r < cfg.max_range
    return np.where(hit, np.clip(r + cfg.range_sigma * rng.standard_normal(r.shape), 0.0, cfg.max_range - 1e-3), r)


class _Planner:
    """A robot's frontier planner on its world-frame map (true poses), BFS on the planning grid."""

    def __init__(self, field: Field, cfg: ExploreConfig, x_range):
        self.cfg, self.field = cfg, field
        r = cfg.plan_resolution
        self.spec = GridSpec(-0.5, -0.5, int(np.ceil((field.width + 1) / r)), int(np.ceil((field.height + 1) / r)), r)
        self.lo = jnp.zeros((self.spec.height, self.spec.width), jnp.float32)
        self.seen = np.zeros((self.spec.height, self.spec.width), bool)
        gx = self.spec.x0 + (np.arange(self.spec.width) + 0.5) * r
        gy = self.spec.y0 + (np.arange(self.spec.height) + 0.5) * r
        X, Y = np.meshgrid(gx, gy)
        self.centres = np.stack([X, Y], -1)
        self.allowed = (X > x_range[0]) & (X < x_range[1]) & (X > 0) & (X < field.width) & (Y > 0) & (Y < field.height)
        k = int(np.ceil((cfg.robot_radius + 0.05) / r))
        yy, xx = np.mgrid[-k : k + 1, -k : k + 1]
        self.disk = (xx**2 + yy**2) * r * r <= (cfg.robot_radius + 0.05) ** 2
        self.blacklist: set = set()
        self.bumped: set = set()

    def add(self, pose, ranges):
        lo, seen = integrate_scans(self.lo, jnp.asarray(pose[None]), jnp.asarray(ranges[None]), self.spec, self.cfg.lidar)
        self.lo, self.seen = lo, self.seen | np.asarray(seen)

    def bump(self, pose):
        """The bumper: marks the cell just ahead of the robot occupied (what the lidar missed)."""
        ahead = pose[:2] + self.cfg.robot_radius * np.array([np.cos(pose[2]), np.sin(pose[2])])
        c = self.cell(ahead)
        self.lo = self.lo.at[c].set(self.cfg.lidar.l_max)
        self.seen[c] = True
        self.bumped.add(c)

    def cell(self, p):
        j = int(np.clip((p[0] - self.spec.x0) // self.spec.resolution, 0, self.spec.width - 1))
        i = int(np.clip((p[1] - self.spec.y0) // self.spec.resolution, 0, self.spec.height - 1))
        return i, j

    def plan(self, pose, goal=None):
        """A path [(x, y), ...] to `goal` (x, y), or to the nearest frontier; None if there is none."""
        from scipy.ndimage import distance_transform_edt

        lo = np.asarray(self.lo)
        occupied = self.seen & (lo > 0.3)
        clearance = distance_transform_edt(~occupied) * self.spec.resolution  # m to the nearest occupied cell
        blocked = clearance <= self.cfg.robot_radius + 0.05
        free = self.seen & (lo < -0.3)
        unknown = ~self.seen
        frontier = free & ~blocked & self.allowed & (
            np.roll(unknown, 1, 0) | np.roll(unknown, -1, 0) | np.roll(unknown, 1, 1) | np.roll(unknown, -1, 1))
        passable = ~blocked & (self.allowed | (goal is not None)) & (self.centres[..., 0] > 0.2) & (
            self.centres[..., 0] < self.field.width - 0.2) & (self.centres[..., 1] > 0.2) & (
            self.centres[..., 1] < self.field.height - 0.2)
        start = self.cell(pose)
        target = None if goal is None else self.cell(goal)
        H, W = lo.shape
        parent = {start: None}
        q = deque([start])
        found = None
        min_d2 = (0.6 / self.spec.resolution) ** 2
        while q:
            c = q.popleft()
            if target is not None:
                if c == target:
                    found = c
                    break
            elif frontier[c] and c not in self.blacklist and (c[0] - start[0]) ** 2 + (c[1] - start[1]) ** 2 >= min_d2:
                found = c
                break
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)):
                n = (c[0] + di, c[1] + dj)
                # inside the inflated zone (too close to something just seen) a step may still lead away from it
                ok = passable[n] or n == target or (blocked[c] and clearance[n] > clearance[c] and not occupied[n])
                if 0 <= n[0] < H and 0 <= n[1] < W and n not in parent and ok:
                    parent[n] = c
                    q.append(n)
        if found is None:
            return None, None
        path = []
        c = found
        while c is not None:
            path.append(self.centres[c])
            c = parent[c]
        return np.array(path[::-1]), found


def _drive(pose, target_xy, cfg: ExploreConfig, field: Field):
    """One step towards target_xy: turn (rate-limited), then go forward if roughly facing it;
    no forward motion into an obstacle. Returns (new pose, moved)."""
    want = np.arctan2(target_xy[1] - pose[1], target_xy[0] - pose[0])
    err = planar.wrap_angle(want - pose[2])
    turn = np.clip(err, -cfg.turn_rate * cfg.dt, cfg.turn_rate * cfg.dt)
    psi = planar.wrap_angle(pose[2] + turn)
    v = cfg.speed * max(np.cos(err), 0.0) ** 4 * min(1.0, np.hypot(*(target_xy - pose[:2])) / 0.3)
    new = np.array([pose[0] + v * cfg.dt * np.cos(psi), pose[1] + v * cfg.dt * np.sin(psi), psi])
    if field.occupied(new[None, :2], inflate=cfg.robot_radius - 0.05)[0]:  # blocked: back off a little
        back = np.array([pose[0] - 0.03 * np.cos(psi), pose[1] - 0.03 * np.sin(psi), psi])
        if not field.occupied(back[None, :2], inflate=cfg.robot_radius - 0.05)[0]:
            return back, False
        return np.array([pose[0], pose[1], psi]), False
    return new, v > 1e-3


def _meeting(cfg: ExploreConfig):
    cx, cy, d = cfg.width / 2, cfg.height / 2, cfg.meet_distance / 2
    return np.array([cx - d, cy, 0.0]), np.array([cx + d, cy, np.pi])


def simulate_exploration(seed: int, cfg: ExploreConfig = ExploreConfig(), progress=None) -> ExploreRun:
    """One exploration, a pure function of (seed, cfg)."""
    from rhaml_jax.data import noisy_odometry

    rng = np.random.default_rng(seed)
    meet_a, meet_b = _meeting(cfg)
    start_a = np.array([rng.uniform(0.8, 2.2), rng.uniform(1.0, cfg.height - 1.0), rng.uniform(-np.pi, np.pi)])
    start_b = np.array([rng.uniform(cfg.width - 2.2, cfg.width - 0.8), rng.uniform(1.0, cfg.height - 1.0),
                        rng.uniform(-np.pi, np.pi)])
    clear = ((start_a[0], start_a[1], 0.8), (start_b[0], start_b[1], 0.8),
             (cfg.width / 2, cfg.height / 2, cfg.meet_distance / 2 + 0.9))
    field = random_field(seed, cfg.width, cfg.height, cfg.obstacles, clear)
    segs = field.segments
    half = cfg.width / 2
    robots = []
    for start, meet, xr in ((start_a, meet_a, (-1.0, half + cfg.overlap / 2)), (start_b, meet_b, (half - cfg.overlap / 2, cfg.width + 1.0))):
        robots.append({"pose": start.copy(), "meet": meet, "planner": _Planner(field, cfg, xr), "path": None,
                       "phase": "explore", "since_plan": 10**9, "stuck": 0, "goal": None, "poses": [], "ranges": []})
    rv_steps = int(round(cfg.rendezvous_seconds / cfg.dt))
    rv_start = None
    for step in range(cfg.max_steps):
        for k, r in enumerate(robots):
            z = scan(segs, r["pose"], cfg.lidar, rng)
            r["poses"].append(r["pose"].copy())
            r["ranges"].append(z)
            r["planner"].add(r["pose"], z)
        if rv_start is not None and step - rv_start >= rv_steps:
            break
        if rv_start is None and all(r["phase"] == "wait" for r in robots):
            rv_start = step
        for k, r in enumerate(robots):
            if rv_start is not None:  # the rendezvous: both move slowly, facing each other
                t = (step - rv_start) * cfg.dt
                v, w = (0.06, 0.12 * np.sin(2 * np.pi * t / 5.0)) if k == 0 else (0.04, -0.15 * np.sin(2 * np.pi * t / 2.5))
                p = r["pose"]
                r["pose"] = np.array([p[0] + v * cfg.dt * np.cos(p[2]), p[1] + v * cfg.dt * np.sin(p[2]),
                                      planar.wrap_angle(p[2] + w * cfg.dt)])
                continue
            if r["phase"] == "explore" and step >= cfg.explore_steps:
                r["phase"], r["path"] = "meet", None
            if r["phase"] == "wait":
                continue
            to_meet = np.hypot(*(r["pose"][:2] - r["meet"][:2]))
            if r["phase"] == "meet" and to_meet < 0.6:  # the middle is kept clear: straight to the point, then turn
                if to_meet > 0.08:
                    r["pose"], _ = _drive(r["pose"], r["meet"][:2], cfg, field)
                    continue
                err = planar.wrap_angle(r["meet"][2] - r["pose"][2])
                if abs(err) < np.radians(2):
                    r["phase"] = "wait"
                else:
                    p = r["pose"]
                    r["pose"] = np.array([p[0], p[1], planar.wrap_angle(p[2] + np.clip(err, -cfg.turn_rate * cfg.dt,
                                                                                            cfg.turn_rate * cfg.dt))])
                continue
            r["since_plan"] += 1
            if r["path"] is None or r["since_plan"] >= 10 or r["stuck"] > 15:
                if r["stuck"] > 15 and r["goal"] is not None:
                    r["planner"].blacklist.add(r["goal"])
                goal = r["meet"][:2] if r["phase"] == "meet" else None
                r["path"], r["goal"] = r["planner"].plan(r["pose"], goal)
                r["since_plan"], r["stuck"] = 0, 0
                if r["path"] is None:
                    if r["phase"] == "explore":  # nothing left to explore
                        r["phase"] = "meet"
                        r["path"], r["goal"] = r["planner"].plan(r["pose"], r["meet"][:2])
                    if r["path"] is None:  # the meeting point is unreachable on this map: go straight
                        r["path"] = np.array([r["meet"][:2]])
            path = r["path"]
            d = np.hypot(*(path - r["pose"][None, :2]).T)
            ahead = np.nonzero(d > 0.35)[0]
            if d[-1] < 0.15:  # at the path's end: plan again next step (and give up a goal never left)
                r["path"] = None
                r["stuck"] += 1
                continue
            target = path[ahead[0]] if len(ahead) else path[-1]
            r["pose"], moved = _drive(r["pose"], target, cfg, field)
            r["stuck"] = 0 if moved else r["stuck"] + 1
            if not moved and np.cos(planar.wrap_angle(np.arctan2(target[1] - r["pose"][1], target[0] - r["pose"][0])
                                                      - r["pose"][2])) > 0.9:
                r["planner"].bump(r["pose"])
                r["path"] = None
        if progress is not None:
            progress(step, [(r["phase"], r["pose"].copy()) for r in robots])
    else:
        raise RhamlError(f"exploration seed {seed}: the robots did not meet within {cfg.max_steps} steps")
    truth_a, truth_b = np.array(robots[0]["poses"]), np.array(robots[1]["poses"])
    odo_a = planar.between(np.broadcast_to(truth_a[0], truth_a.shape), noisy_odometry(truth_a, seed * 2 + 1))
    odo_b = planar.between(np.broadcast_to(truth_b[0], truth_b.shape), noisy_odometry(truth_b, seed * 2 + 2))
    frames = rv_start + np.round(np.arange(cfg.rendezvous_frames) * rv_steps / cfg.rendezvous_frames).astype(int)
    return ExploreRun(field, truth_a, truth_b, odo_a, odo_b, np.array(robots[0]["ranges"]), np.array(robots[1]["ranges"]),
                      frames, cfg)


def robot_map(poses: np.ndarray, ranges: np.ndarray, cfg: ExploreConfig, extent: float = 14.0) -> OccupancyMap:
    """The log-odds map of scans (N, beams) taken at poses (N, 3) (every cfg.scan_every-th scan),
    on a grid of +-extent m around the frame's origin, cropped to what was seen."""
    n = int(np.ceil(2 * extent / cfg.resolution))
    spec = GridSpec(-extent, -extent, n, n, cfg.resolution)
    sel = slice(None, None, cfg.scan_every)
    lo, seen = integrate_scans(jnp.zeros((n, n), jnp.float32), jnp.asarray(poses[sel]), jnp.asarray(ranges[sel]), spec,
                               cfg.lidar)
    return occupancy_from_log_odds(lo, seen, spec)
