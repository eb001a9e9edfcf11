"""The learned refiner (DeepIM-style, the paper's IR): a small FlowNetS-like encoder on the
observed crop stacked with the render at the current pose, regressing a relative SE(3) update
in DeepIM's disentangled form and the observed robot's mask.

Input (S, S, 7): observed crop RGB, rendered RGB, rendered mask, all in [0, 1], one crop box
(`rhaml_jax.crop`) for both; with `luma` (S, S, 3): the two crops' BT.601 luminance and the mask
(no hue to lean on: a repainted robot reads alike). Output: (v_x, v_y) image-plane offsets of the model origin's
projection in units of the crop's size, v_z = log(z_src / z_tgt), a rotation vector (axis-angle,
camera-frame axes, about the model origin; DeepIM's disentangled rotation) and mask logits
(S, S). `apply_update` composes them with the source pose T_cam_model.

The net is a static frozen dataclass (hashable: jit argument) and its params a plain pytree
(no graphdef): `init_params(cfg, key)`, `apply(cfg, params, x)`.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

__all__ = ["RefinerConfig", "init_params", "apply", "apply_update", "point_matching_loss", "mask_loss",
           "target_update", "update_loss",
           "config_to_dict", "config_from_dict", "REFINER_CONFIGS", "get_refiner_config"]


@dataclasses.dataclass(frozen=True)
class RefinerConfig:
    name: str = "refiner_cpu"
    crop: int = 64
    """input side (px)"""
    widths: tuple[int, ...] = (32, 64, 128, 128)
    """stride-2 3x3 conv stages (FlowNetS-like, about half width)"""
    hidden: int = 256
    """fully connected layer before the pose head"""
    margin: float = 1.4
    """crop box = projected model box at the current estimate times this (DeepIM)"""
    n_iter: int = 4
    """test-time iterations (re-rendering between them)"""
    w_mask: float = 0.1
    """weight of the mask head's sigmoid cross-entropy"""
    n_points: int = 512
    """model surface points of the point-matching loss (eq. 8)"""
    scale: tuple[float, float, float, float] = (0.1, 0.1, 0.1, 0.2)
    """output scales of (v_x, v_y), v_z, rotation (rad), mask logits init: keeps the first updates small"""
    luma: bool = False
    """input luminance (observed, render) and the render's mask instead of RGB + RGB + mask"""
    loss: str = "disentangled"
    """training loss of the pose update: "disentangled" (eq. 8 once per part of the update, the
    other parts set to their true values: CosyPose's disentangled loss) or "joint" (eq. 8 on the
    whole updated pose, the runs before session 17). Under the joint L1 loss a translation error
    larger than the heading's gives every point's error the same sign, and the gradient on the
    heading cancels over the model's points (`tests/test_refine_learned.py`); the refiner's
    heading never learned with it (BENCHMARKS.md, "The refiner learns the heading")"""
    part_weights: tuple[float, float, float] = (1.0, 1.0, 10.0)
    """the disentangled loss's weights of its (image-plane offsets, depth, rotation) parts"""
    starts: str = "coarse"
    """the initial poses it trains from (`refine.train.initial_pose`): "coarse" (the paper's noise
    and our IML's errors, flips included) or "fine" (what a coarse refiner's iterations leave:
    centimetres and a few degrees), the second stage of a cascade (`RefineConfig.fine_iter`)"""
    native: int = 0
    """0: the render is made at the crop's resolution (DeepIM). N > 0: made at the image's own
    pixel centres in an N x N window around the crop box, then resampled into the crop as the
    observed crop is (`crop.crop_image`), so that the two compare like with like: the same
    pixel grid, the same quantised edges, the same filter. Exact for a box smaller than the crop
    (the far robots it is for); for a larger one the area filter's grid is the window's, not the
    image's, and the image's border is not repeated; boxes wider than N - 2 px fall back to the
    crop-resolution render. `refine.train.render_crop`"""

    paint_prob: float = 0.0
    """training: the render's parts repainted this often (`data.sample_paint`: half in one paint; the
    observed robot is repainted by the data), so that the update rests less on the model's paint
    matching the robot's: a user's CAD colours are not the robot's (it does not teach the heading of
    a robot in one paint: BENCHMARKS.md, "Refiners trained on repainted renders")"""

    def __post_init__(self):
        from rhaml_jax.errors import RhamlError

        if self.loss not in ("joint", "disentangled"):
            raise RhamlError(f"RefinerConfig.loss {self.loss!r}: expected 'joint' or 'disentangled'")
        if len(self.part_weights) != 3 or min(self.part_weights) < 0 or max(self.part_weights) <= 0:
            raise RhamlError(f"RefinerConfig.part_weights {self.part_weights}: expected three weights >= 0, one > 0")
        if self.starts not in ("coarse", "fine"):
            raise RhamlError(f"RefinerConfig.starts {self.starts!r}: expected 'coarse' or 'fine'")
        if not 0 <= self.paint_prob <= 1:
            raise RhamlError(f"RefinerConfig.paint_prob must be in [0, 1], got {self.paint_prob}")
        if self.native and self.native < self.crop:
            raise RhamlError(f"RefinerConfig.native {self.native}: expected 0 or a window of at least the crop ({self.crop} px)")


def luminance(rgb):
    """(..., 3) RGB -> (...,) BT.601 luminance (`amlnet.model.LUMA`, as AMLNet's luma input)."""
    from rhaml_jax.amlnet.model import LUMA

    return rgb @ jnp.asarray(LUMA, rgb.dtype)


def in_channels(cfg) -> int:
    return 3 if cfg.luma else 7


REFINER_CONFIGS = {"refiner_cpu": RefinerConfig(), "refiner_cpu_luma": RefinerConfig(name="refiner_cpu_luma", luma=True),
                   # the cascade's second stage: refiner_cpu's network on a tighter crop, trained from fine starts
                   "refiner_fine_cpu": RefinerConfig(name="refiner_fine_cpu", margin=1.2, starts="fine"),
                   # the same on renders at the image's pixel centres (session 42)
                   "refiner_fine_native_cpu": RefinerConfig(name="refiner_fine_native_cpu", margin=1.2, starts="fine", native=128),
                   # the coarse and fine refiners trained with their renders repainted half the time (session 46)
                   "refiner_paint_cpu": RefinerConfig(name="refiner_paint_cpu", paint_prob=0.5),
                   "refiner_fine_paint_cpu": RefinerConfig(name="refiner_fine_paint_cpu", margin=1.2, starts="fine", paint_prob=0.5),
                   "refiner_micro": RefinerConfig(name="refiner_micro", crop=32, widths=(8, 16), hidden=32, n_points=64),
                   "refiner_micro_fine": RefinerConfig(name="refiner_micro_fine", crop=32, widths=(8, 16), hidden=32,
                                                       n_points=64, margin=1.2, starts="fine"),  # the tests' cascade
                   "refiner_micro_native": RefinerConfig(name="refiner_micro_native", crop=32, widths=(8, 16), hidden=32,
                                                         n_points=64, margin=1.2, starts="fine", native=48)}


def named_config(configs: dict, name: str, what: str):
    """configs[name], or RhamlError naming the known ones (`what`: "refiner", "segmenter", ...)."""
    from rhaml_jax.errors import RhamlError

    if name not in configs:
        raise RhamlError(f"--config {name!r}: not a {what} config (known: {', '.join(configs)})")
    return configs[name]


def get_refiner_config(name: str) -> RefinerConfig:
    return named_config(REFINER_CONFIGS, name, "refiner")


def config_to_dict(cfg) -> dict:
    """A config dataclass (any of the refinement networks') as a JSON-safe dict."""
    return json_safe(dataclasses.asdict(cfg))


def json_safe(d):
    import json

    return json.loads(json.dumps(d))


def dataclass_from_dict(cls, d: dict):
    """A config dataclass from its stored JSON dict (lists back to tuples; keys it does not have,
    from another version, dropped)."""
    fields = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in fields})


def config_from_dict(d: dict) -> RefinerConfig:
    return dataclass_from_dict(RefinerConfig, {"loss": "joint", **d})  # stored before `loss` existed: joint


def _conv_init(key, k, cin, cout):
    return {"w": jax.random.normal(key, (k, k, cin, cout), jnp.float32) * np.sqrt(2.0 / (k * k * cin)),
            "b": jnp.zeros((cout,), jnp.float32)}


def encoder_init(conv_keys, fc_key, cin: int, widths, crop: int, hidden: int):
    """(convs, fc) of `encode`: stride-2 3x3 convolutions of `widths` channels on a crop x crop
    input of `cin` channels, then a fully connected layer of `hidden` units."""
    convs = []
    for k, c in zip(conv_keys, widths):
        convs.append(_conv_init(k, 3, cin, c))
        cin = c
    side = crop // 2 ** len(widths)
    flat = side * side * cin
    fc = {"w": jax.random.normal(fc_key, (flat, hidden)) * np.sqrt(2.0 / flat), "b": jnp.zeros((hidden,))}
    return convs, fc


def encode(convs, fc, x):
    """x (B, S, S, C) in [0, 1] -> (features (B, hidden), each convolution's output)."""
    h = x * 2.0 - 1.0
    feats = []
    for p in convs:
        h = jax.nn.gelu(_conv(h, p, 2))
        feats.append(h)
    return jax.nn.gelu(h.reshape(x.shape[0], -1) @ fc["w"] + fc["b"]), feats


def init_params(cfg: RefinerConfig, key) -> dict:
    keys = jax.random.split(key, len(cfg.widths) + 4)
    convs, fc = encoder_init(keys[:len(cfg.widths)], keys[-4], in_channels(cfg), cfg.widths, cfg.crop, cfg.hidden)
    head = {"w": jnp.zeros((cfg.hidden, 6)), "b": jnp.zeros((6,))}  # zero init: the first update is the identity
    mask_in = cfg.widths[1] if len(cfg.widths) > 1 else cfg.widths[0]
    mask = _conv_init(keys[-2], 3, mask_in, 1)
    return {"convs": convs, "fc": fc, "head": head, "mask": mask}


def _conv(x, p, stride):
    y = jax.lax.conv_general_dilated(x, p["w"], (stride, stride), "SAME", dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return y + p["b"]


class Output(NamedTuple):
    update: jax.Array  # (B, 6) v_x, v_y (crop fractions), v_z, rotation vector (rad)
    mask_logits: jax.Array  # (B, S, S)


def apply(cfg: RefinerConfig, params: dict, x) -> Output:
    """x (B, S, S, 7) (luma: (B, S, S, 3)) -> Output."""
    B = x.shape[0]
    z, feats = encode(params["convs"], params["fc"], x)
    raw = z @ params["head"]["w"] + params["head"]["b"]
    s = jnp.asarray([cfg.scale[0], cfg.scale[0], cfg.scale[1], cfg.scale[2], cfg.scale[2], cfg.scale[2]])
    f = feats[1] if len(feats) > 1 else feats[0]
    m = _conv(f, params["mask"], 1)[..., 0]
    m = jax.image.resize(m, (B, cfg.crop, cfg.crop), "bilinear")
    return Output(raw * s, m)


def apply_update(T_cam_model: jaxlie.SE3, update, K, box):
    """DeepIM's disentangled update of T_cam_model (batched) by `update` (..., 6).

    z_tgt = z_src / exp(v_z); x_tgt / z_tgt = x_src / z_src + v_x * box_w / f_x (likewise y);
    R_tgt = exp(rotation vector) R_src (camera-frame axes through the model origin)."""
    t = T_cam_model.translation()
    z_src = jnp.maximum(t[..., 2], 1e-3)  # guard: a source behind the camera (declined upstream)
    z_tgt = z_src * jnp.exp(-update[..., 2])
    bw, bh = box[..., 2] - box[..., 0], box[..., 3] - box[..., 1]
    xr = t[..., 0] / z_src + update[..., 0] * bw / K[..., 0, 0]
    yr = t[..., 1] / z_src + update[..., 1] * bh / K[..., 1, 1]
    t_new = jnp.stack([xr * z_tgt, yr * z_tgt, z_tgt], -1)
    R = jaxlie.SO3.exp(update[..., 3:6]) @ T_cam_model.rotation()
    return jaxlie.SE3.from_rotation_and_translation(R, t_new)


def target_update(T_src: jaxlie.SE3, T_tgt: jaxlie.SE3, K, box):
    """(..., 6) the update that `apply_update` turns T_src into T_tgt with (its inverse)."""
    ts, tt = T_src.translation(), T_tgt.translation()
    zs, zt = jnp.maximum(ts[..., 2], 1e-3), jnp.maximum(tt[..., 2], 1e-3)  # guard as in apply_update
    bw, bh = box[..., 2] - box[..., 0], box[..., 3] - box[..., 1]
    vx = (tt[..., 0] / zt - ts[..., 0] / zs) * K[..., 0, 0] / bw
    vy = (tt[..., 1] / zt - ts[..., 1] / zs) * K[..., 1, 1] / bh
    rot = (T_tgt.rotation() @ T_src.rotation().inverse()).log()
    return jnp.concatenate([jnp.stack([vx, vy, jnp.log(zs / zt)], -1), rot], -1)


def update_loss(cfg: RefinerConfig, T_src: jaxlie.SE3, update, T_gt: jaxlie.SE3, K, box, points):
    """(B,) the pose part of the training loss (`RefinerConfig.loss`) of `update` (B, 6) from T_src."""
    if cfg.loss == "joint":
        return point_matching_loss(apply_update(T_src, update, K, box), T_gt, points)
    true = jax.lax.stop_gradient(target_update(T_src, T_gt, K, box))
    parts = [slice(0, 2), slice(2, 3), slice(3, 6)]  # image-plane offsets, depth, rotation
    total = 0.0
    for part, w in zip(parts, cfg.part_weights):
        mixed = true.at[..., part].set(update[..., part])
        total = total + w * point_matching_loss(apply_update(T_src, mixed, K, box), T_gt, points)
    return total


def point_matching_loss(T_pred: jaxlie.SE3, T_gt: jaxlie.SE3, points):
    """Eq. 8: mean over model points (P, 3) of the L1 distance (m) between the points moved by
    the predicted and the true pose; (B,) per example."""
    a = jax.vmap(lambda T: T @ points)(T_pred) if T_pred.wxyz_xyz.ndim > 1 else T_pred @ points
    b = jax.vmap(lambda T: T @ points)(T_gt) if T_gt.wxyz_xyz.ndim > 1 else T_gt @ points
    return jnp.mean(jnp.sum(jnp.abs(a - b), -1), -1)


def mask_loss(logits, target):
    """(B,) mean sigmoid cross-entropy of the mask head against the observed mask in [0, 1]."""
    return jnp.mean(jnp.maximum(logits, 0) - logits * target + jnp.log1p(jnp.exp(-jnp.abs(logits))), axis=(-2, -1))
