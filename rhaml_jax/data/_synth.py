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
from rhaml_jax.data import _appearance as _ap
from rhaml_jax.data._backdrop import Light, RoomLook, photo, room_albedo, room_image, room_surfaces, sample_light, sample_room
from rhaml_jax.frames import se3_from_xypsi
from rhaml_jax.planar import between, wrap_angle
from rhaml_jax.render import Mesh, render

MIN_VISIBLE_PX = 12  # fewer visible robot pixels than this count as "not in view"


def check_scale(scale: float) -> None:
    """RhamlError unless `scale` (every distance of a robot's world, `generate --scale`) is positive."""
    if not scale > 0:
        from rhaml_jax.errors import RhamlError

        raise RhamlError(f"--scale {scale}: must be positive")


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
    appearance: the v2 appearance randomisation (`AppearanceConfig`, its ranges), or None for
      the v1 data the shipped checkpoints were trained on (fixed robot colours, one Lambertian
      light, six texture kinds, no camera effects; its images are unchanged).
    """

    depth_m: tuple[float, float] = (1.0, 8.0)
    height_sigma_m: float = 0.05
    cut_fraction: float = 0.15
    photo_fraction: float = 0.3
    max_distractors: int = 4
    negative_fraction: float = 0.125
    appearance: _ap.AppearanceConfig | None = _ap.AppearanceConfig()

    def scaled(self, scale: float) -> "SynthConfig":
        """This config with its working range of depths times `scale` (a smaller robot's world,
        `RobotModel.world_scale`); itself at 1."""
        check_scale(scale)
        return self if scale == 1.0 else dataclasses.replace(self, depth_m=(self.depth_m[0] * scale, self.depth_m[1] * scale))


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
    gap = abs(wrap_angle(np.arctan2(xy[1], xy[0]) - np.arctan2(robot_xy[1], robot_xy[0])))
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


def composite_layers(layers) -> tuple[np.ndarray, list[np.ndarray]]:
    """Depth compositing of image layers [(rgb, mask, depth)], first layer the backdrop (mask
    all True). Returns (rgb uint8, the visible part of each layer's mask)."""
    rgb, visible = _composite_float(layers)
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), visible


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
    With cfg.appearance set (the default), the v2 look (`training_sample_v2`).
    """
    if cfg.appearance is not None:
        return training_sample_v2(model_mesh, camera, seed, index, negative, cfg)
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
            rgb, _ = composite_layers(layers)
            return Sample(rgb, np.zeros((H, W), bool), np.zeros((H, W), bool), False, np.zeros(3), h)
        robot = _render(model_mesh, T_cam @ se3_from_xypsi(pose), camera, light)
        rgb, visible = composite_layers(layers + [robot])
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
        rgb, _ = composite_layers([bg])
        return rgb, np.zeros((H, W), bool), rel, False
    robot = _render(model_mesh, T_cam_robot(h) @ se3_from_xypsi(rel), camera, light)
    rgb, visible = composite_layers([bg, robot])
    return rgb, visible[-1], rel, bool(visible[-1].sum() >= MIN_VISIBLE_PX)


# ----------------------------------------------------------------------------- data v2 (appearance randomisation)

_CART_WHEELS = 4


def _y_prism(sides: int):
    """Unit prism of `_prism_template` turned to have its axis along y, y in [-0.5, 0.5]."""
    v, f = _prism_template(sides)
    return np.c_[v[:, 0], v[:, 2] - 0.5, v[:, 1]], f


def distractor_mesh_v2(rng: np.random.Generator, count: int, slots: int, keep_out_xy, keep_out_r: float, area,
                       colors: np.ndarray, cart_prob: float, cart_length: tuple[float, float]) -> tuple:
    """As `distractor_mesh`, each slot also holding a robot-like cart (a box on four wheels, of
    random size: no size cue from a robot-like shape); colors (slots, 2, 3): body, wheels (RGB)."""
    verts, faces, cols = [], [], []
    x0, x1, y0, y1 = area
    offset = 0
    box, cyl, wheel = _prism_template(4), _prism_template(12), _y_prism(12)
    for k in range(slots):
        use = (2 if rng.random() < cart_prob else int(rng.integers(2))) if k < count else -1
        size, height, yaw = rng.uniform(0.1, 0.5), rng.uniform(0.1, 1.2), rng.uniform(0, np.pi)
        length = rng.uniform(*cart_length)
        width, wheel_r = length * rng.uniform(0.5, 1.0), length * rng.uniform(0.1, 0.3)
        body_z0, body_h = wheel_r * rng.uniform(0.4, 1.3), length * rng.uniform(0.2, 0.6)
        # bounding radius of the footprint: box, or cart with its wheels (x: axles at +-0.35 L, y: 0.1 L each side)
        reach = max(size * 1.5 * np.sqrt(2.0), 0.5 * np.hypot(0.7 * length + 2 * wheel_r, width + 0.2 * length))
        for _ in range(50):
            cx, cy = rng.uniform(x0, x1), rng.uniform(y0, y1)
            if keep_out_xy is None or not _may_occlude((cx, cy), reach, keep_out_xy, keep_out_r):
                break
        else:
            use = -1
        c, sn = np.cos(yaw), np.sin(yaw)
        R = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
        aspect = rng.uniform(0.5, 1.5)
        # (template, scale, shift in the object's frame, colour, kind) of every piece of the slot
        pieces = [(box, [size, size * aspect, height], [0, 0, 0], colors[k, 0], 0),
                  (cyl, [size, size * aspect, height], [0, 0, 0], colors[k, 0], 1),
                  (box, [length / 2, width / 2, body_h], [0, 0, body_z0], colors[k, 0], 2)]
        for wx in (-0.35 * length, 0.35 * length):
            for wy in (-width / 2 - 0.05 * length, width / 2 + 0.05 * length):
                pieces.append((wheel, [wheel_r, 0.1 * length, wheel_r], [wx, wy, wheel_r], colors[k, 1], 2))
        for (v, f), scale, shift, color, kind in pieces:
            w = (v * scale + shift) @ R.T + [cx, cy, 0.0]
            if kind != use:
                w = w * 0.0 + [-1000.0, 0.0, 0.0]  # hidden: behind the camera
            verts.append(w), faces.append(f + offset), cols.append(np.tile(color, (len(f), 1)))
            offset += len(v)
    return (np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int32),
            np.concatenate(cols).astype(np.float32))


def _albedo_layer(mesh: Mesh, T_cam_world: jaxlie.SE3, camera: Camera):
    """Unshaded render (the face colours): (albedo, mask, depth, face_id) as NumPy."""
    out = render(mesh, T_cam_world, camera.K.astype(np.float32), camera.width, camera.height,
                 light_dir=(0.0, 0.0, -1.0), ambient=1.0, diffuse=0.0)
    return np.asarray(out.rgb), np.asarray(out.mask), np.asarray(out.depth), np.asarray(out.face_id)


def _shaded(layer, verts_world, faces, camera: Camera, cam_pose, look, highlights=True, body=None):
    albedo, mask, depth, fid = layer
    n = _ap.face_normals_world(verts_world, faces, cam_pose[1])
    return (_ap.shade_layer(albedo, mask, depth, fid, n, camera.K, cam_pose, look, highlights, body), mask,
            np.where(mask, depth, np.inf))


def _floor_shadows(bg_rgb, bg_depth, floor, verts_world, faces, T_cam_world, camera: Camera, look, scale: float):
    """Darkens the floor under the objects (verts_world (N, 3), hidden ones far behind the
    camera): a shadow cast along the sun and a contact shadow straight below."""
    out = bg_rgb
    for strength, direction, blur in ((look.shadow_strength, look.sun_dir, look.shadow_blur_px),
                                      (look.contact_strength, np.array([0.0, 0.0, 1.0]), 3.0 * look.shadow_blur_px)):
        if strength <= 0 or look.lighting == "hemisphere" and direction[2] < 1.0:
            continue
        d = np.asarray(direction, np.float64)
        flat = verts_world - verts_world[:, 2:3] / max(d[2], 1e-3) * d  # guard: sun at the horizon
        flat[:, 2] = 0.002
        flat[verts_world[:, 0] < -100] = verts_world[verts_world[:, 0] < -100]  # hidden stay hidden
        m = Mesh(jnp.asarray(flat, jnp.float32), jnp.asarray(faces), jnp.zeros((len(faces), 3), jnp.float32))
        _, mask, depth, _ = _albedo_layer(m, T_cam_world, camera)
        on_floor = mask & floor & (np.abs(bg_depth - depth) < 0.05 * np.maximum(depth, 1.0))
        out = _ap.darken(out, on_floor, strength * (1.0 if direction[2] == 1.0 else min(1.0, float(look.sun_rgb.max()))),
                         blur * scale)
    return out


def _camouflage(robot, layers, look, acfg) -> np.ndarray:
    """The robot's part colours (G, 3) recoloured towards the scene around it (AppearanceConfig's
    camouflage): robot = (shaded rgb, mask, depth) as first shaded; layers: the scene without it."""
    rgb, mask = robot[0], robot[1].astype(bool)
    scene, _ = _composite_float(layers)
    box, outside = _ap.surroundings(mask)
    around = scene[box][outside]
    if len(around) == 0:  # guard: the robot fills its whole box (it fills the image); nothing to match
        return look.part_rgb
    return _ap.camouflaged(look.part_rgb, rgb[mask].mean(0), around.mean(0), look.camouflage, acfg)


def training_sample_v2(model_mesh, camera: Camera, seed: int, index: int, negative: bool | None = None,
                       cfg: "SynthConfig" = None, heldout=None) -> Sample:
    """`training_sample` with the v2 appearance randomisation of cfg.appearance (robot colours,
    lights and highlights, floor shadows, camera effects, more room textures, robot-like
    distractors); with `heldout` (a HeldoutConfig), the held-out benchmark's look instead.
    The geometry is drawn as in v1; the look from its own stream (`sample_look`)."""
    cfg = SynthConfig() if cfg is None else cfg
    acfg = cfg.appearance or _ap.AppearanceConfig()
    rng = sample_rng(seed, index)
    if negative is None:
        negative = bool(rng.random() < cfg.negative_fraction)
    h = float(np.clip(NOMINAL_HEIGHT_M + cfg.height_sigma_m * rng.standard_normal(), 0.1, 0.6))
    groups, group_of_face = _ap.color_groups(np.asarray(model_mesh.face_colors))
    slots = cfg.max_distractors
    if heldout is None:
        look = _ap.sample_look(acfg, seed, index, groups, slots)
    else:
        look = _ap.sample_heldout_look(heldout, seed, index, groups, slots)
    robot_mesh = Mesh(model_mesh.vertices, model_mesh.faces, jnp.asarray(look.part_rgb[group_of_face], jnp.float32))
    T_cam = T_cam_robot(h)
    cam_pose = _ap.world_from_optical(h)
    W, H = camera.width, camera.height
    scale = W / 640.0
    backdrops = (look.backdrop_photo,)
    dis_rgb = _ap.hsv_to_rgb(look.distractor_hsv)
    v_model, faces_model = np.asarray(model_mesh.vertices, np.float64), np.asarray(model_mesh.faces)
    for _attempt in range(50):
        pose = _observed_pose(rng, camera, cfg)
        px, py = pose[0], pose[1]
        bounds = (-rng.uniform(0.5, 4.0), px + rng.uniform(1.0, 6.0), min(py, 0.0) - rng.uniform(1.0, 5.0), max(py, 0.0) + rng.uniform(1.0, 5.0))
        if rng.random() < cfg.photo_fraction:
            bg_rgb, bg_depth, floor = photo(rng, W, H, backdrops), np.full((H, W), np.inf, np.float32), None
        else:
            room = RoomLook(tuple(float(b) for b in bounds), float(rng.uniform(2.2, 4.0)), look.textures)
            bg_depth, face, pts = room_surfaces(room, camera.K, W, H, (0.0, 0.0, 0.0), h)
            bg_rgb, floor = _ap.shade_room(room_albedo(room, face, pts), face, pts, look, cam_pose[1]), face == 0
        n_dis = int(rng.integers(slots + 1))
        dv, df, dc = distractor_mesh_v2(rng, n_dis, slots, None if negative else pose[:2], _footprint_radius(model_mesh) + 0.05,
                                        (0.6, bounds[1] - 0.3, bounds[2] + 0.3, bounds[3] - 0.3), dis_rgb, acfg.cart_prob,
                                        acfg.cart_length_m)
        T_world_robot = np.asarray(se3_from_xypsi(pose).as_matrix(), np.float64)
        robot_world = v_model @ T_world_robot[:3, :3].T + T_world_robot[:3, 3]
        if negative:
            robot_world = robot_world * 0.0 + [-1000.0, 0.0, 0.0]
        if floor is not None:
            bg_rgb = _floor_shadows(bg_rgb, bg_depth, floor, np.concatenate([robot_world, dv]),
                                    np.concatenate([faces_model, df + len(robot_world)]), T_cam, camera, look, scale)
        layers = [(np.clip(bg_rgb * np.float32(look.room_gain), 0, None), np.ones((H, W), bool), bg_depth)]
        if slots:
            dmesh = Mesh(jnp.asarray(dv), jnp.asarray(df), jnp.asarray(dc))
            layers.append(_shaded(_albedo_layer(dmesh, T_cam, camera), dv, df, camera, cam_pose, look, highlights=False))
        if not negative:
            layer = _albedo_layer(robot_mesh, T_cam @ se3_from_xypsi(pose), camera)
            body = (T_world_robot[:3, :3], T_world_robot[:3, 3])
            robot = _shaded(layer, robot_world, faces_model, camera, cam_pose, look, body=body)
            if look.camouflage > 0 and layer[1].any():
                parts = _camouflage(robot, layers, look, acfg)
                albedo = np.where(layer[1][..., None], parts[group_of_face[np.maximum(layer[3], 0)]], 0.0).astype(np.float32)
                robot = _shaded((albedo,) + layer[1:], robot_world, faces_model, camera, cam_pose, look, body=body)
            layers.append(robot)
        linear, visible = _composite_float(layers)
        rgb = _ap.camera_effects(linear, look, scale)
        if negative:
            return Sample(rgb, np.zeros((H, W), bool), np.zeros((H, W), bool), False, np.zeros(3), h)
        if visible[-1].sum() >= MIN_VISIBLE_PX:
            return Sample(rgb, visible[-1], layers[-1][1].astype(bool), True, pose, h)
    raise RuntimeError(f"training_sample_v2: no visible robot placement found for seed {seed}, index {index}")


def _composite_float(layers):
    """`composite_layers` without the 8-bit rounding: (linear rgb (H, W, 3) float32, visible masks)."""
    rgb = np.array(layers[0][0], np.float32)
    depth = np.array(layers[0][2], np.float32)
    front = np.zeros(depth.shape, np.int8)
    for i, (c, m, d) in enumerate(layers[1:], 1):
        sel = m & (d < depth)
        rgb[sel], depth[sel], front[sel] = c[sel], d[sel], i
    return rgb, [front == i for i in range(len(layers))]


def scenario_frame_v2(model_mesh, camera: Camera, room, look, observer_xypsi, observed_xypsi, h: float = NOMINAL_HEIGHT_M,
                      frame_seed: int = 0):
    """`scenario_frame` under a v2 / held-out `look` (robot colours, lights, contact shadow,
    camera effects with per-frame noise from frame_seed)."""
    rel = between(np.asarray(observer_xypsi, np.float64), np.asarray(observed_xypsi, np.float64))
    W, H = camera.width, camera.height
    cam_pose = _ap.world_from_optical(h, observer_xypsi)
    groups, group_of_face = _ap.color_groups(np.asarray(model_mesh.face_colors))
    robot_mesh = Mesh(model_mesh.vertices, model_mesh.faces, jnp.asarray(look.part_rgb[group_of_face], jnp.float32))
    bg_depth, face, pts = room_surfaces(room, camera.K, W, H, observer_xypsi, h)
    bg = _ap.shade_room(room_albedo(room, face, pts), face, pts, look, cam_pose[1])
    look = dataclasses.replace(look, noise_seed=int(np.random.SeedSequence([look.noise_seed, int(frame_seed)]).generate_state(1)[0]))
    scale = W / 640.0
    if rel[0] <= 0.3:
        return _ap.camera_effects(bg, look, scale), np.zeros((H, W), bool), rel, False
    T_cam = T_cam_robot(h)
    T_w = np.asarray(se3_from_xypsi(np.asarray(observed_xypsi, np.float64)).as_matrix(), np.float64)
    v_model = np.asarray(model_mesh.vertices, np.float64)
    world = v_model @ T_w[:3, :3].T + T_w[:3, 3]
    o = np.asarray(observer_xypsi, np.float64)
    T_cam_world = T_cam @ se3_from_xypsi(between(o, np.zeros(3)))  # world -> observer robot -> camera
    bg = _floor_shadows(bg, bg_depth, face == 0, world, np.asarray(model_mesh.faces), T_cam_world, camera, look, scale)
    layer = _albedo_layer(robot_mesh, T_cam @ se3_from_xypsi(rel), camera)
    robot = _shaded(layer, world, np.asarray(model_mesh.faces), camera, cam_pose, look, body=(T_w[:3, :3], T_w[:3, 3]))
    linear, visible = _composite_float([(bg, np.ones((H, W), bool), bg_depth), robot])
    return _ap.camera_effects(linear, look, scale), visible[-1], rel, bool(visible[-1].sum() >= MIN_VISIBLE_PX)
