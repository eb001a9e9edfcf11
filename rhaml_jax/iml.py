"""IML, the initial mutual localisation (paper section III-A), as one pure JAX function.

    localize(model, params, images, K) -> Estimate

from a batch of full-resolution RGB images (any size and pinhole intrinsics) to the observed
robot's planar pose in the observer's frame: AMLNet on the image resampled into its camera
(`crop.network_box` + `crop.resample`), then, if the model has one, the zoom-in stage on a crop
around AMLNet's estimate (`crop.zoom_box` + `crop.crop_image`: the pixels the zoom stage was
trained on), optionally also on the mirrored crop (`zoom.mirror_average`), and the
correction applied (`zoom.apply_correction`). Pure over (params, inputs), so it jits,
vmaps, shards and differentiates; `localize_jit` is the shared compiled form.

`IMLModel` is the static part (network definitions and switches; hashed by identity, so each
loaded model compiles once per input shape), `IMLParams` the arrays. `load_iml` builds both from
checkpoint folders (default: the shipped `heat_nocart_cpu` + `zoom_fit_cpu`, `DEFAULT_AMLNET`,
`DEFAULT_ZOOM`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp

from rhaml_jax import crop
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.errors import RhamlError

__all__ = ["DEFAULT_AMLNET", "DEFAULT_ZOOM", "Estimate", "IMLModel", "IMLParams", "load_iml", "localize", "localize_jit",
           "check_mirror_symmetric", "mirror_heatmap"]


class Estimate(NamedTuple):
    """The observed robot as one stage of the pipeline sees it (batch axis B)."""

    xypsi: jax.Array  # (B, 3) x, y (m), psi (rad) in the observer's robot frame
    o: jax.Array  # (B,) probability that a robot is in view (called in view at metrics.DETECTION_THRESHOLD)
    flip_prob: jax.Array  # (B,) probability that psi is off by 180 deg (0.5: no information)
    roll_pitch: jax.Array  # (B, 2) roll and pitch (rad) of the observation; 0 for IML's planar answer


@dataclasses.dataclass(frozen=True, eq=False)
class IMLModel:
    """Static part of IML: the networks' definitions (`amlnet.Net` without their arrays) and
    switches. Compared and hashed by identity (a jit static argument)."""

    amlnet: object  # amlnet.Net (its cfg and graphdef are used)
    zoom: object | None = None  # the zoom-in stage's amlnet.Net, or None for AMLNet alone
    zoom_mirror: bool = False  # also run the zoom stage on the mirrored crop (left-right symmetric robots)
    flip_calibration: tuple[float, float] | None = None  # (a, b) of zoom.FlipCalibration; None: the raw ranking
    white_balance: bool = False  # grey-world balance each image before the networks see it (`colour.grey_world`)
    amlnet_mirror: bool = False  # a heatmap AMLNet also run on the mirrored image, the two maps averaged (`mirror_heatmap`)


class IMLParams(NamedTuple):
    amlnet: tuple  # (params, batch_stats) of AMLNet
    zoom: tuple | None  # (params, batch_stats) of the zoom-in stage, or None


def _as_8bit(x):
    """Rounded to whole 8-bit levels, as the host pipeline's OpenCV images are (training saw
    those), with a straight-through gradient (identity) so that derivatives still pass."""
    return x + jax.lax.stop_gradient(jnp.clip(jnp.round(x), 0.0, 255.0) - x)


def localize(model: IMLModel, params: IMLParams, images, K) -> Estimate:
    """images (B, H, W, 3) uint8 or float in [0, 255]; K (3, 3) or (B, 3, 3) their intrinsics."""
    from rhaml_jax.amlnet import decode
    from rhaml_jax.zoom import apply_correction, decode_correction, flip_probability, mirror_average
    from rhaml_jax.zoom import box as zoom_box

    net = model.amlnet
    B, H, W = images.shape[:3]
    if model.white_balance:
        from rhaml_jax.colour import grey_world

        images = grey_world(jnp.asarray(images, jnp.float32))
    K = jnp.broadcast_to(jnp.asarray(K, jnp.float32), (B, 3, 3))
    h, w = net.cfg.input_hw
    with jax.ensure_compile_time_eval():  # a constant of the model, not a traced value
        net_K = jnp.asarray(DEFAULT_CAMERA.resized(w, h).K, jnp.float32)
    boxes = jax.vmap(lambda k: crop.network_box(k, (W, H), net_K, (w, h)))(K)
    x = _as_8bit(jax.vmap(lambda im, b: crop.resample(im, b, w, h))(images, boxes)) / 255.0
    out = net.apply(*params.amlnet, x)
    if model.amlnet_mirror:  # the flip test-time augmentation of CenterNet: one map from both views
        out = 0.5 * (out + mirror_heatmap(net.apply(*params.amlnet, x[:, :, ::-1])))
    d = decode(out, net.cfg.angle_head)
    xypsi = jnp.stack([d["x"], d["y"], d["psi"]], -1)
    flip = jnp.full((B,), 0.5, xypsi.dtype)  # AMLNet's own heading at CPU size is a guess (README)
    if model.zoom is not None:
        z = model.zoom
        S = z.cfg.input_hw[0]
        zb = zoom_box(K, xypsi[:, :2], z.cfg)
        crops = _as_8bit(jax.vmap(lambda im, b: crop.crop_image(im, b, S, S))(images, zb)) / 255.0

        c = decode_correction(z.apply(*params.zoom, crops), z.cfg.angle_head)
        t, norm = c.as_array(), c.sure
        if model.zoom_mirror:
            cm = decode_correction(z.apply(*params.zoom, crops[:, :, ::-1]), z.cfg.angle_head)
            t = mirror_average(t, cm.as_array())
            norm = 0.5 * (norm + cm.sure)
        xypsi = apply_correction(xypsi[:, :2], t, crop.min_range_m(z.cfg.zoom_length_m))
        # A regressor torn between a heading and its opposite answers with a short direction
        # vector (their mean is near zero): the shorter, the likelier a flip. A ranking (0 for a
        # unit vector, 0.5 at length 0), made a probability by the zoom checkpoint's calibration
        # when it has one (`zoom.FlipCalibration`; BENCHMARKS.md measures both).
        flip = 0.5 * (1.0 - norm)
        if model.flip_calibration is not None:
            flip = flip_probability(flip, model.flip_calibration)
    return Estimate(xypsi, d["o"], flip, jnp.zeros((B, 2), xypsi.dtype))


localize_jit = jax.jit(localize, static_argnums=0)


def mirror_heatmap(out):
    """(B, Gh, Gw, 6) dense AMLNet head (`amlnet.heatmap`: logit, du, dv, log range, cos, sin of
    psi - bearing) of a left-right mirrored image -> the map of the image itself, for a left-right
    symmetric robot: columns reversed, the in-cell offset du -> 1 - du, the heading relative to
    the ray negated. (The pixel mirror is about the image's centre column, the camera's principal
    point 0.25 px beside it at 320 px: a bearing offset of 0.07 deg in the average.)"""
    m = out[:, :, ::-1]
    return jnp.stack([m[..., 0], 1.0 - m[..., 1], m[..., 2], m[..., 3], m[..., 4], -m[..., 5]], -1)


MAX_MIRROR_SHAPE = 0.02  # of the robot's length
MAX_MIRROR_COLOUR = 0.05  # of its surface


def check_mirror_symmetric(model, model_path, flag: str = "--zoom-mirror") -> None:
    """Mirroring the zoom crop (or the image, `flag` --amlnet-mirror) assumes a left-right
    symmetric robot: refuses a RobotModel (read from `model_path`) that is not
    (RobotModel.mirror_asymmetry)."""
    shape, colour = model.mirror_asymmetry()
    length = float(model.extents.max())
    if shape > MAX_MIRROR_SHAPE * length or colour > MAX_MIRROR_COLOUR:
        raise RhamlError(f"{flag}: the robot model {model_path} is not left-right symmetric (its mirror image is "
                         f"{100 * shape:.1f} cm off, {100 * colour:.0f} % of its surface another colour; limits "
                         f"{100 * MAX_MIRROR_SHAPE:.0f} % of its {100 * length:.0f} cm length and "
                         f"{100 * MAX_MIRROR_COLOUR:.0f} %): mirrored images would show another robot")


# The default networks (shipped in rhaml_jax/checkpoints), chosen on the validation looks (ours,
# OOD, one paint) by experiments/compare_validation.py's rule (BENCHMARKS.md, "How a default is
# chosen"). `zoom_fit_cpu` and `heat_fit_cpu` are made by `python -m rhaml_jax.fit --robot
# pioneer3dx --budget-minutes 130 --from-scratch` (session 19, BENCHMARKS.md "An out-of-distribution
# validation set"); `heat_nocart_cpu` is `heat_fit_cpu` fine-tuned on v3 images without robot-like
# carts, which had taught it to doubt near robots seen end-on (session 22, BENCHMARKS.md "Carts
# and the end-on misses"). `heat_chroma_cpu` (the local chroma contrast as its third input channel,
# session 29) was the default for one session: under the sequence-level rule of session 30 it is
# level with `heat_nocart_cpu` in every row, so it does not replace it. Before: `heat_fit_cpu`, and
# before that `amlnet_cpu` + `zoom_cpu`.
DEFAULT_AMLNET, DEFAULT_ZOOM = "heat_nocart_cpu", "zoom_fit_cpu"


def load_iml(amlnet: str | Path | None = None, zoom: str | Path | None = None, no_zoom: bool = False,
             zoom_mirror: bool = False, robot=None, robot_source: str = "the data set",
             calibrated: bool = True, white_balance: bool = False,
             amlnet_mirror: bool = False) -> tuple[IMLModel, IMLParams]:
    """IML from checkpoint folders. Defaults: the shipped `DEFAULT_AMLNET` and, with it, its own
    `DEFAULT_ZOOM` (a user's `amlnet` gets no zoom stage unless `zoom` is given). With `robot` (a
    RobotModel, from `robot_source`), networks made for another robot are refused: by the
    fingerprint each checkpoint stores (`robots.check_same_robot`) or, for a zoom stage from
    before fingerprints, by its robot length (`zoom_length_m`, 15 %). The zoom checkpoint's flip
    calibration, if it has one (`zoom.write_flip_calibration`), makes `flip_prob` a probability;
    `calibrated=False` keeps the raw ranking (to fit a calibration). `white_balance`: the
    networks see each image grey-world balanced (`colour.grey_world`). `amlnet_mirror`: a heatmap
    AMLNet's map averaged with its map of the mirrored image (a left-right symmetric robot)."""
    from rhaml_jax.amlnet import load_model, shipped_checkpoint
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta, checkpoint_robot

    amlnet_dir = amlnet or shipped_checkpoint(DEFAULT_AMLNET)
    net, p, s = load_model(amlnet_dir)
    if getattr(net.cfg, "task", "localize") != "localize":
        raise RhamlError(f"--amlnet {amlnet}: holds a zoom-in stage ({net.cfg.name}), not AMLNet")
    if amlnet_mirror and getattr(net.cfg, "head", "global") != "heatmap":
        raise RhamlError(f"--amlnet-mirror: AMLNet {amlnet_dir} ({net.cfg.name}) has a {net.cfg.head} head; only a "
                         "heatmap head's map can be mirrored back")
    if zoom is None and amlnet is None and not no_zoom:
        zoom = shipped_checkpoint(DEFAULT_ZOOM)
    znet, zp = None, None
    if zoom is not None and not no_zoom:
        znet, zparams, zstats = load_model(zoom)
        if getattr(znet.cfg, "task", "localize") != "zoom":
            raise RhamlError(f"--zoom {zoom}: holds a {znet.cfg.name} network, not a zoom-in stage")
        zp = (zparams, zstats)
    if zoom_mirror and znet is None:
        raise RhamlError("--zoom-mirror: there is no zoom-in stage to mirror (--no-zoom, or --amlnet without --zoom)")
    if robot is not None:
        from rhaml_jax.robots import check_same_robot

        check_same_robot(checkpoint_robot(amlnet_dir), robot, f"AMLNet checkpoint {amlnet_dir}", robot_source)
        if znet is not None:
            stored = checkpoint_robot(zoom)
            check_same_robot(stored, robot, f"zoom-in stage checkpoint {zoom}", robot_source)
            length, want = float(robot.extents[0]), float(znet.cfg.zoom_length_m)
            if stored is None and abs(length / want - 1) > 0.15:
                raise RhamlError(f"{robot_source}: this robot is {100 * length:.0f} cm long, but the networks were made "
                                 f"for a {100 * want:.0f} cm robot ({znet.cfg.name}): train networks for this robot "
                                 "(python -m rhaml_jax.fit), pass --amlnet/--zoom checkpoints made for it, or "
                                 "--allow-other-robot for a deliberate transfer test")
    cal = None
    if znet is not None and calibrated:
        from rhaml_jax.zoom import FlipCalibration

        stored = checkpoint_meta(zoom).get("flip_calibration")
        if stored is not None:
            c = FlipCalibration.from_dict(stored, f"zoom-in stage checkpoint {zoom}: flip_calibration")
            if c.zoom_mirror == zoom_mirror:
                cal = (c.a, c.b)
            else:  # the ranking's spread differs with and without mirroring: the raw ranking, said once
                import warnings

                warnings.warn(f"zoom-in stage checkpoint {zoom}: its flip calibration was fitted "
                              f"{'with' if c.zoom_mirror else 'without'} --zoom-mirror; flip_prob stays the raw ranking",
                              stacklevel=2)
    return IMLModel(net, znet, zoom_mirror, cal, white_balance, amlnet_mirror), IMLParams((p, s), zp)

