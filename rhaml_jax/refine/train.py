"""Training the learned refiner: examples from a BOP set, the loss (eq. 8 point matching + the
mask head's cross-entropy) and the `rhaml_jax.training.Task` that `python -m rhaml_jax.train
--stage refiner` runs.

An example is a pure function of (seed, index): frame index mod N of the set, its initial pose
drawn either as the paper's (ground truth + N(0, 0.15 m) on x, y and N(0, 20 deg) on psi; the
0.15 m times the robot's `RobotModel.world_scale`, 1 for the Pioneer) or as
our IML errs (range off by up to 15 %, bearing N(0, 1.5 deg), heading N(0, 10 deg), turned by
180 deg one time in eight), half each; a cascade's fine stage (`RefinerConfig.starts` "fine") from
what a coarse refiner leaves (range off by N(0, 1 %) or N(0, 3 %), bearing N(0, 0.2 deg) or
N(0, 0.6 deg), heading N(0, 2 deg) or N(0, 6 deg), half each). The crop box comes from the initial pose (DeepIM's
zoom-in, `rhaml_jax.crop.object_box`); the observed crop is `crop.crop_image_host`, the render
at the initial pose is made inside the jitted step (`render.render`, hard RGB + mask), in the
model's paint or, with `RefinerConfig.paint_prob`, repainted (`CropSource.paint`).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax import crop as _crop
from rhaml_jax import render
from rhaml_jax.errors import RhamlError
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine import net as N

__all__ = ["RefinerBatch", "CropSource", "RefinerSource", "refiner_task", "initial_pose"]


class RefinerBatch(NamedTuple):
    obs: np.ndarray  # (B, S, S, 3) float32 [0, 1] observed crop
    obs_mask: np.ndarray  # (B, S, S) float32 [0, 1] observed (visible) mask crop
    box: np.ndarray  # (B, 4) crop box, full-image px
    K: np.ndarray  # (B, 3, 3)
    T_init: np.ndarray  # (B, 7) T_cam_model wxyz_xyz of the initial pose
    T_gt: np.ndarray  # (B, 7) the true T_cam_model
    paint: np.ndarray  # (B, F, 3) float32 the render's face colours (the model's, or repainted: `RefinerConfig.paint_prob`)


def _corners(vertices: np.ndarray) -> np.ndarray:
    lo, hi = vertices.min(0), vertices.max(0)
    sel = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T
    return lo + sel * (hi - lo)


def initial_pose(xypsi: np.ndarray, rng: np.random.Generator, scale: float = 1.0, starts: str = "coarse") -> np.ndarray:
    """(3,) an initial planar estimate around the true `xypsi` (see the module docstring); `scale`:
    the robot's world scale, which the paper's 0.15 m position noise is multiplied by; `starts`:
    `RefinerConfig.starts`."""
    x, y, psi = xypsi
    if starts == "fine":  # relative to the range: the residuals of a coarse refiner lie along the line of sight
        wide = rng.random() < 0.5
        r, b = np.hypot(x, y), np.arctan2(y, x)
        r *= 1 + rng.normal(0, 0.03 if wide else 0.01)
        b += rng.normal(0, np.deg2rad(0.6 if wide else 0.2))
        psi = psi + rng.normal(0, np.deg2rad(6.0 if wide else 2.0))
        return np.array([r * np.cos(b), r * np.sin(b), wrap_angle(psi)])
    if rng.random() < 0.5:  # the paper's noise, in the robot's world
        sigma = 0.15 * scale
        return np.array([x + rng.normal(0, sigma), y + rng.normal(0, sigma), psi + rng.normal(0, np.deg2rad(20))])
    r, b = np.hypot(x, y), np.arctan2(y, x)
    r *= 1 + rng.uniform(-0.15, 0.15)
    b += rng.normal(0, np.deg2rad(1.5))
    psi = psi + rng.normal(0, np.deg2rad(10)) + (np.pi if rng.random() < 0.125 else 0.0)
    return np.array([r * np.cos(b), r * np.sin(b), wrap_angle(psi)])


def _se3_params(T: np.ndarray) -> np.ndarray:
    return np.asarray(jaxlie.SE3.from_matrix(jnp.asarray(T, jnp.float32)).wxyz_xyz)


class CropSource:
    """Crops of a BOP set's frames with the robot in view, around initial poses drawn by
    `initial_pose` (the box: `crop.object_box` at the drawn pose times `margin(rng)`): example
    number `index` is a pure function of (seed, index); decoded images kept in memory. The
    refiner's and the segmenter's training data (`cfg.crop`: the crop side)."""

    cache_bytes = 4 << 30

    def __init__(self, root: Path, split: str, cfg, batch: int, seed: int = 0, limit: int | None = None):
        from rhaml_jax.data import ImageCache, load_bop_model, read_bop

        self.frames = [f for f in read_bop(root, split) if f.observed][:limit]
        if not self.frames:
            raise RhamlError(f"{root}: split {split!r} has no image with the robot in view")
        self.model = load_bop_model(root)
        self.corners = _corners(self.model.vertices)
        self.scale = self.model.world_scale
        self.cfg, self.batch, self.seed = cfg, batch, seed
        self._cache = ImageCache(self.cache_bytes)

    _PAINT_STREAM = 7

    @functools.cached_property
    def _parts(self):
        """The model's face colours (F, 3) float32 and their colour groups (groups (G, 3), group of each face (F,))."""
        from rhaml_jax.data._appearance import color_groups

        colours = np.asarray(self.model.face_colors, np.float32)
        return colours, *color_groups(colours)

    def paint(self, index: int) -> np.ndarray:
        """(F, 3) float32 the face colours example `index` renders with: the model's, or with the
        config's `paint_prob` repainted (`data.sample_paint`: half in one paint). Drawn from a stream
        of their own, so a config without repainting draws the examples it drew before."""
        from rhaml_jax.data import sample_paint

        colours, groups, inverse = self._parts
        prob = getattr(self.cfg, "paint_prob", 0.0)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, index, self._PAINT_STREAM]))
        if not prob or rng.random() >= prob:
            return colours
        return sample_paint(rng, groups)[inverse].astype(np.float32)

    def image(self, i):
        """(H, W, 3) uint8 RGB and (H, W) uint8 mask (0 or 255) of frame i (decoded once, cached)."""
        from rhaml_jax.data import load_mask, load_rgb

        f = self.frames[i]
        both = self._cache.get(i, lambda: np.concatenate([load_rgb(f.rgb), (load_mask(f.mask)[..., None] * 255).astype(np.uint8)], -1))
        return both[..., :3], both[..., 3]  # (H, W, 3) RGB, (H, W) mask

    def initial(self, xypsi: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(3,) the estimate the crop is centred on (drawn first): `initial_pose`."""
        return initial_pose(xypsi, rng, self.scale, getattr(self.cfg, "starts", "coarse"))

    def margin(self, rng: np.random.Generator) -> float:
        """The crop box's margin (drawn after the initial pose)."""
        return self.cfg.margin

    def drawn(self, index: int):
        """(frame, T_init (4, 4) model to camera at the drawn pose, box (4,), observed crop (S, S, 3)
        and visible-mask crop (S, S), both float32 in [0, 1])."""
        i = index % len(self.frames)
        f = self.frames[i]
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, index]))
        init = self.initial(f.xypsi, rng)
        margin = self.margin(rng)
        T_obs = np.eye(4)
        c, s = np.cos(init[2]), np.sin(init[2])
        T_obs[:2, :2] = [[c, -s], [s, c]]
        T_obs[:2, 3] = init[:2]
        T_init = f.T_w2c @ T_obs
        pc = self.corners @ T_init[:3, :3].T + T_init[:3, 3]
        box = np.asarray(_crop.object_box(f.K, pc, margin=margin), np.float64)
        rgb, mask = self.image(i)
        S = self.cfg.crop
        obs = _crop.crop_image_host(rgb, box, S, S).astype(np.float32) / 255
        m = _crop.crop_image_host(np.repeat(mask[..., None], 3, -1), box, S, S)[..., 0].astype(np.float32) / 255
        return f, T_init, box, obs, m


class RefinerSource(CropSource):
    """batch(step) of B examples number step * B ... (step + 1) * B - 1 (a pure function of
    (seed, step)): `CropSource` crops at the config's margin, with the poses."""

    def example(self, index: int):
        f, T_init, box, obs, m = self.drawn(index)
        return (obs, m, box.astype(np.float32), f.K.astype(np.float32), _se3_params(T_init), _se3_params(f.T_m2c),
                self.paint(index))

    def __call__(self, step: int) -> RefinerBatch:
        ex = [self.example(step * self.batch + j) for j in range(self.batch)]
        return RefinerBatch(*(np.stack([e[k] for e in ex]) for k in range(len(RefinerBatch._fields))))


def check_refiner_batch(cfg: N.RefinerConfig, b, size: int, where: str, faces: int) -> None:
    from rhaml_jax.refine._task import check_fields

    S = cfg.crop
    check_fields(b, {"obs": (size, S, S, 3), "obs_mask": (size, S, S), "box": (size, 4), "K": (size, 3, 3),
                     "T_init": (size, 7), "T_gt": (size, 7), "paint": (size, faces, 3)}, "RefinerBatch", where)


def render_input(mesh, cfg: N.RefinerConfig, obs, T_cam: jaxlie.SE3, K, box, light_dir=render.DEFAULT_LIGHT):
    """(B, S, S, 7) network input (luma: (B, S, S, 3)): observed crop, render (RGB, mask) at
    T_cam (no gradient: the render is an input, as in DeepIM)."""
    rgb, mask = render_crop(mesh, cfg, T_cam, K, box, light_dir)
    mask = mask[..., None].astype(obs.dtype)
    if cfg.luma:
        rend = jnp.concatenate([N.luminance(rgb)[..., None], mask], -1)
        return jnp.concatenate([N.luminance(obs)[..., None], jax.lax.stop_gradient(rend)], -1)
    rend = jax.lax.stop_gradient(jnp.concatenate([rgb, mask], -1))
    return jnp.concatenate([obs, rend], -1)


def render_crop(mesh, cfg: N.RefinerConfig, T_cam: jaxlie.SE3, K, box, light_dir=render.DEFAULT_LIGHT):
    """The render at T_cam (B,) in the crop boxes (B, 4): RGB (B, S, S, 3) and mask (B, S, S) in
    [0, 1]. `cfg.native` > 0: rendered at the image's pixel centres in a window of that side
    around each box, then cropped as the observed image is (see `RefinerConfig.native`)."""
    S, Nw = cfg.crop, cfg.native
    direct = render.render(mesh, T_cam, K, S, S, box=box, light_dir=light_dir)
    if not Nw:
        return direct.rgb, direct.mask.astype(jnp.float32)
    box = jnp.broadcast_to(box, T_cam.wxyz_xyz.shape[:-1] + (4,))  # one box (4,) for a batch of poses too
    corner = jnp.round(0.5 * (box[..., :2] + box[..., 2:])) - Nw // 2  # (B, 2) the window's first pixel centre
    window = jnp.concatenate([corner - 0.5, corner + Nw - 0.5], -1)  # edges at pixel borders
    out = render.render(mesh, T_cam, K, Nw, Nw, box=window, light_dir=light_dir)
    img = jnp.concatenate([out.rgb, out.mask[..., None].astype(out.rgb.dtype)], -1)  # (B, Nw, Nw, 4)
    local = box - jnp.concatenate([corner, corner], -1)  # the box in the window's pixels
    crops = jax.vmap(lambda im, b: _crop.crop_image(im, b, S, S))(img, local)
    fits = (jnp.maximum(box[..., 2] - box[..., 0], box[..., 3] - box[..., 1]) <= Nw - 2)[..., None, None]
    return jnp.where(fits[..., None], crops[..., :3], direct.rgb), jnp.where(fits, crops[..., 3], direct.mask.astype(jnp.float32))


def painted_input(mesh, cfg: N.RefinerConfig, obs, T_init, K, box, paint):
    """`render_input` with each example's render in its own face colours: obs (B, S, S, 3), T_init
    (B, 7) wxyz_xyz, K (B, 3, 3), box (B, 4), paint (B, F, 3) -> (B, S, S, C). A batch of one inside,
    since `render_crop`'s native path maps over a batch."""
    return jax.vmap(lambda o, T, k, bx, c: render_input(mesh._replace(face_colors=c), cfg, o[None], jaxlie.SE3(T[None]),
                                                        k[None], bx[None])[0])(obs, T_init, K, box, paint)


def refiner_loss(cfg: N.RefinerConfig, mesh, points, params, b):
    obs, obs_mask, box, K, T_init, T_gt, paint = b
    T0 = jaxlie.SE3(T_init)
    x = painted_input(mesh, cfg, obs, T_init, K, box, paint)
    out = N.apply(cfg, params, x)
    Tg = jaxlie.SE3(T_gt)
    pose = N.update_loss(cfg, T0, out.update, Tg, K, box, points)
    pm = N.point_matching_loss(N.apply_update(T0, out.update, K, box), Tg, points)
    pm0 = N.point_matching_loss(T0, Tg, points)
    ce = N.mask_loss(out.mask_logits, obs_mask)
    loss = jnp.mean(pose) + cfg.w_mask * jnp.mean(ce)
    return loss, {"loss": loss, "loss_pm": jnp.mean(pm), "loss_pm_init": jnp.mean(pm0), "loss_mask": jnp.mean(ce)}


def refiner_task(cfg: N.RefinerConfig, tc, mesh, model, val_source=None, num_devices=None):
    """(the `rhaml_jax.training.Task` of the refiner, its shardings). `model`: the RobotModel
    (its name and extents are stored, so that a checkpoint of another robot is refused)."""
    from rhaml_jax.refine._task import network_task

    points = jnp.asarray(model.sample_surface(cfg.n_points, seed=0))
    mesh = render.as_mesh(mesh)
    return network_task("refiner", cfg, tc, model, init_params=N.init_params, config_to_dict=N.config_to_dict,
                        config_from_dict=N.config_from_dict,
                        loss=lambda params, *b: refiner_loss(cfg, mesh, points, params, b),
                        n_fields=len(RefinerBatch._fields),
                        check_batch=lambda b, size, where: check_refiner_batch(cfg, b, size, where, len(mesh.faces)),
                        val_source=val_source, num_devices=num_devices)


def check_robot(meta: dict, model, where: str) -> None:
    """Refuses a refiner or segmenter checkpoint made for another robot (`robots.require_same_robot`:
    extents and surface area; the name is reported, not compared: a BOP set's model is called
    obj_000001)."""
    from rhaml_jax.robots import RobotFingerprint, fingerprint, require_same_robot

    kind = meta.get("kind", "refiner")
    require_same_robot(RobotFingerprint.from_dict(meta.get("robot", {}), where), fingerprint(model),
                       f"{where}: {kind} checkpoint is for robot {{mine}}, not {{theirs}}")
