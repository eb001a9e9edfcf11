"""Synthetic images: the robot rendered over a randomised backdrop, as a pure function of (seed, index).

Host-side NumPy draws the scene (robot pose, camera height, room, light, distractors) from a
generator seeded with (seed, index); the JAX rasterizer renders the robot and the distractors;
the three layers are composited by depth. Regenerating an index gives identical pixels.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax.camera import NOMINAL_HEIGHT_M, Camera, T_cam_robot
from rhaml_jax.data._backdrop import Light, photo, room_image, sample_light, sample_room
from rhaml_jax.planar import between
from rhaml_jax.frames import se3_from_xypsi
from rhaml_jax.render import Mesh, render

MIN_VISIBLE_PX = 12  # fewer visible robot pixels than this count as "not in view"


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    """How training images are drawn.

    depth_m: range of the robot's distance ahead of the observer (the working range).
    height_sigma_m: camera height noise around the nominal 0.30 m (the paper's N(0, 0.05^2)).
    cut_fraction: share of positives placed across the image border (partly cut).
    photo_fraction: share of backdrops that are photographs rather than rooms.
    max_distractors: up to this many random boxes and cylinders on the floor.
    negative_fraction: share of background-only images when generating on the fly
      (10,000 of 80,000 in the paper).
    """

    depth_m: tuple[float, float] = (1.0, 8.0)
    height_sigma_m: float = 0.05
    cut_fraction: float = 0.15
    photo_fraction: float = 0.3
    max_distractors: int = 4
    negative_fraction: float = 0.125


class Sample(NamedTuple):
    rgb: np.ndarray  # (H, W, 3) uint8
    mask_visib: np.ndarray  # (H, W) bool, robot pixels not hidden by a distractor
    mask_all: np.ndarray  # (H, W) bool, robot pixels ignoring occlusion
    observed: bool
    xypsi: np.ndarray  # (3,) float64, the robot in the observer's frame (zeros when not observed)
    camera_height: float


def sample_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of image `index` of a data set with `seed` (independent streams)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))


# ----------------------------------------------------------------------------- distractors

_SLOTS_SIDES = (4, 12)  # each distractor slot holds a box and a cylinder; one is hidden


@functools.lru_cache(maxsize=None)
def _prism_template(sides: int):
    """Unit prism: radius 1 around z, z in [0, 1]; (V, 3), (F, 3)."""
    a = np.arange(sides) * 2 * np.pi / sides + np.pi / sides
    ring = np.stack([np.cos(a), np.sin(a)], 1) / (np.cos(np.pi / sides) if sides == 4 else 1.0)
    v = np.concatenate([np.c_[ring, np.zeros(sides)], np.c_[ring, np.ones(sides)]])
    faces = []
    for i in range(sides):
        j = (i + 1) % sides
        faces += [(i, j, sides + j), (i, sides + j, sides + i)]
    for i in range(1, sides - 1):
        faces += [(0, i + 1, i), (sides, sides + i, sides + i + 1)]
    return v, np.asarray(faces, np.int32)


def _footprint_radius(mesh) -> float:
    v = np.asarray(mesh.vertices)
    return float(np.max(np.hypot(v[:, 0], v[:, 1])))


def _may_occlude(xy, reach: float, robot_xy, robot_r: float) -> bool:
    """Whether an object of radius `reach` at xy could cover part of a robot of radius robot_r
    at robot_xy, seen from the origin: their bearing intervals overlap and it is not behind."""
    d_obj, d_rob = np.hypot(*xy), np.hypot(*robot_xy)
    if d_obj - reach > d_rob + robot_r:
        return False  # entirely behind the robot
    half = lambda r, d: np.arcsin(min(1.0, r / max(d, 1e-6)))  # noqa: E731
    gap = abs(np.arctan2(np.sin(np.arctan2(xy[1], xy[0]) - np.arctan2(robot_xy[1], robot_xy[0])),
                         np.cos(np.arctan2(xy[1], xy[0]) - np.arctan2(robot_xy[1], robot_xy[0]))))
    return gap < half(reach, d_obj) + half(robot_r, d_rob) + 0.02


def distractor_mesh(rng: np.random.Generator, count: int, slots: int, keep_out_xy, keep_out_r: float, area) -> tuple:
    """World-frame vertices, faces and colours of `slots` distractor slots, `count` of them used.

    The shape is fixed for a given number of slots (one compilation); unused shapes move far
    behind the camera, where the rasterizer clips them.
    """
    verts, faces, colors = [], [], []
    x0, x1, y0, y1 = area
    offset = 0
    for k in range(slots):
        use = rng.integers(len(_SLOTS_SIDES)) if k < count else -1
        size = rng.uniform(0.1, 0.5)
        height = rng.uniform(0.1, 1.2)
        yaw = rng.uniform(0, np.pi)
        reach = size * 1.5 * np.sqrt(2.0)  # bounding radius of the footprint
        for _ in range(50):  # a spot that cannot hide any part of the robot
            cx, cy = rng.uniform(x0, x1), rng.uniform(y0, y1)
            if keep_out_xy is None or not _may_occlude((cx, cy), reach, keep_out_xy, keep_out_r):
                break
        else:
            use = -1  # no free spot: leave the slot empty
        color = rng.uniform(0.05, 0.95, 3)
        for s, sides in enumerate(_SLOTS_SIDES):
            v, f = _prism_template(sides)
            c, sn = np.cos(yaw), np.sin(yaw)
            R = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
            w = (v * [size, size * rng.uniform(0.5, 1.5), height]) @ R.T + [cx, cy, 0.0]
            if s != use:
                w = w * 0.0 + [-1000.0, 0.0, 0.0]  # hidden: behind the camera
            verts.append(w), faces.append(f + offset), colors.append(np.tile(color, (len(f), 1)))
            offset += len(v)
    return np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int32), np.concatenate(colors).astype(np.float32)


# ----------------------------------------------------------------------------- rendering


def _render(model_mesh, T_cam_model: jaxlie.SE3, camera: Camera, light: Light):
    out = render(model_mesh, T_cam_model, camera.K.astype(np.float32), camera.width, camera.height,
                 light_dir=tuple(float(x) for x in light.in_camera()), ambient=light.ambient, diffuse=light.diffuse)
    return np.asarray(out.rgb), np.asarray(out.mask), np.asarray(out.depth)


def compose(layers) -> tuple[np.ndarray, list[np.ndarray]]:
    """Depth compositing of [(rgb, mask, depth)], first layer the backdrop (mask all True).

    Returns (rgb uint8, the visible part of each layer's mask).
    """
    rgb = np.array(layers[0][0], np.float32)
    depth = np.array(layers[0][2], np.float32)
    front = np.zeros(depth.shape, np.int8)
    for i, (c, m, d) in enumerate(layers[1:], 1):
        sel = m & (d < depth)
        rgb[sel], depth[sel], front[sel] = c[sel], d[sel], i
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), [front == i for i in range(len(layers))]


def _observed_pose(rng, camera: Camera, cfg: SynthConfig) -> np.ndarray:
    x = rng.uniform(*cfg.depth_m)
    half = x * (camera.cx + 0.5) / camera.fx  # half-width of the view at depth x
    if rng.random() < cfg.cut_fraction:
        y = rng.choice([-1.0, 1.0]) * (half + rng.uniform(-0.25, 0.15))
    else:
        y = rng.uniform(-1.0, 1.0) * max(half - 0.25, 0.0)
    return np.array([x, y, rng.uniform(-np.pi, np.pi)])


def training_sample(model_mesh, camera: Camera, seed: int, index: int, negative: bool | None = None,
                    cfg: SynthConfig = SynthConfig()) -> Sample:
    """Image `index` of the training set `seed`: the robot at a random pose (or none) over a backdrop.

    negative None draws it with probability cfg.negative_fraction (on-the-fly training);
    a data set on disk passes it explicitly (its first N images positive, then M negative).
    """
    rng = sample_rng(seed, index)
    if negative is None:
        negative = bool(rng.random() < cfg.negative_fraction)
    h = NOMINAL_HEIGHT_M + cfg.height_sigma_m * rng.standard_normal()
    h = float(np.clip(h, 0.1, 0.6))
    light = sample_light(rng)
    T_cam = T_cam_robot(h)
    W, H = camera.width, camera.height
    for _attempt in range(50):
        pose = _observed_pose(rng, camera, cfg)
        # Room around observer and robot; distractors on its floor, in front of the camera.
        px, py = pose[0], pose[1]
        bounds = (-rng.uniform(0.5, 4.0), px + rng.uniform(1.0, 6.0), min(py, 0.0) - rng.uniform(1.0, 5.0), max(py, 0.0) + rng.uniform(1.0, 5.0))
        if rng.random() < cfg.photo_fraction:
            bg = photo(rng, W, H), np.ones((H, W), bool), np.full((H, W), np.inf, np.float32)
        else:
            rgb, depth = room_image(sample_room(rng, bounds), light, camera.K, W, H, (0.0, 0.0, 0.0), h)
            bg = rgb, np.ones((H, W), bool), depth
        n_dis = int(rng.integers(cfg.max_distractors + 1))
        # Distractors never hide the robot, so mask_visib is the robot's whole silhouette in the image.
        dv, df, dc = distractor_mesh(rng, n_dis, cfg.max_distractors, None if negative else pose[:2], _footprint_radius(model_mesh) + 0.05,
                                     (0.6, bounds[1] - 0.3, bounds[2] + 0.3, bounds[3] - 0.3))
        layers = [bg]
        if cfg.max_distractors:
            layers.append(_render(Mesh(jnp.asarray(dv), jnp.asarray(df), jnp.asarray(dc)), T_cam, camera, light))
        if negative:
            rgb, _ = compose(layers)
            return Sample(rgb, np.zeros((H, W), bool), np.zeros((H, W), bool), False, np.zeros(3), h)
        robot = _render(model_mesh, T_cam @ se3_from_xypsi(pose), camera, light)
        rgb, visible = compose(layers + [robot])
        if visible[-1].sum() >= MIN_VISIBLE_PX:
            return Sample(rgb, visible[-1], robot[1].astype(bool), True, pose, h)
    raise RuntimeError(f"training_sample: no visible robot placement found for seed {seed}, index {index}")


def scenario_frame(model_mesh, camera: Camera, room, light: Light, observer_xypsi, observed_xypsi, h: float = NOMINAL_HEIGHT_M):
    """One frame of a scenario: both robots in a common world frame, the backdrop a fixed room.

    Returns (rgb uint8, mask_visib, pose of the observed robot in the observer's frame (3,),
    observed: enough robot pixels in the image).
    """
    rel = between(np.asarray(observer_xypsi, np.float64), np.asarray(observed_xypsi, np.float64))
    W, H = camera.width, camera.height
    bg = (*room_image(room, light, camera.K, W, H, observer_xypsi, h),)
    bg = (bg[0], np.ones((H, W), bool), bg[1])
    if rel[0] <= 0.3:  # behind or beside the observer: cannot be in view
        rgb, _ = compose([bg])
        return rgb, np.zeros((H, W), bool), rel, False
    robot = _render(model_mesh, T_cam_robot(h) @ se3_from_xypsi(rel), camera, light)
    rgb, visible = compose([bg, robot])
    return rgb, visible[-1], rel, bool(visible[-1].sum() >= MIN_VISIBLE_PX)
