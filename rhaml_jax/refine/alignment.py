"""Multi-hypothesis silhouette alignment of the planar pose (x, y, psi) to an observed mask.

A batch of hypotheses (the estimate, its heading turned by 180 deg, its mirror image about the
line of sight and the mirror's flip, optionally a few perturbed starts) is aligned at once, as
Diff-DOPE runs many optimisations side by side to escape the local minima of symmetric objects.
Each hypothesis is parameterised by (log range, bearing, heading) in the observer's frame (the
crop shows range as scale and bearing as offset: well-conditioned steps at any depth) and moves
by Levenberg-Marquardt steps (or Adam) on the pixel residuals between our soft silhouette
(`render.silhouette`) and the observed mask, both cropped by one box (`rhaml_jax.crop`, DeepIM's
zoom-in, fixed by the initial estimate so that every hypothesis is scored against the same
target). The sharpness is annealed from soft to sharp (per crop pixel); the first stage holds
the heading (a position error is otherwise partly "explained" by turning). A step is taken only
if it lowers the hypothesis' loss, so each hypothesis' loss never rises within a stage. The
hypothesis with the lowest final loss wins; the initial estimate itself is scored too and kept
if nothing beats it, so a converged estimate is never made worse.

Unbiased end (`debias_stages`): the soft silhouette is larger than the hard one (each silhouette
edge is shared by at least two faces, whose probabilistic union moves the 0.5 level outwards by
about 0.9 / sharpness px), so matching it to a hard mask reads the range long. The last stages
compare like with like: the renderer's own excess at the stage's start pose,
b = stop_gradient(soft - hard), is subtracted from the soft render, so at the start pose the
residual is hard render - observed mask and the fixed point is the hard silhouette's. Measured
(experiments/bench_refine.py, oracle masks, circle): range bias +1.0 % without, -0.04 % with.

Camera: the observer's camera at (0, 0, h) in its robot frame looking along +x, no tilt
(DESIGN.md section 2; `camera.T_cam_robot(h)`), h = `AlignConfig.camera_height_m`.

Gradients: the optimisation's increments are stop-gradient (straight-through: d result /
d init = identity); differentiating through the optimiser would need the silhouette's second
derivatives, which its custom VJP does not provide.

Pure JAX: jit-able (cfg static), vmappable over frames, fixed iteration counts.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax import crop as _crop
from rhaml_jax import render
from rhaml_jax.camera import T_cam_robot
from rhaml_jax.planar import wrap_angle

__all__ = ["AlignConfig", "AlignResult", "align", "align_to", "align_crop", "crop_box", "hypotheses", "pose_from_params", "params_from_xypsi",
           "xypsi_from_params", "check_init", "start_iou"]


@dataclasses.dataclass(frozen=True)
class AlignConfig:
    """Static settings of `align` (hashable: a change recompiles)."""

    crop: int = 64
    """side (px) of the square crop the silhouettes are compared in"""
    margin: float = 1.4
    """crop box = projected model box at the initial estimate times this (DeepIM's 1.4)"""
    camera_height_m: float = 0.30
    """observer camera height h (camera at (0, 0, h) looking along +x)"""
    stages: tuple[tuple, ...] = ((1.0, 4, "xy"), (1.0, 6), (2.0, 6), (4.0, 5), (8.0, 4), (8.0, 4))
    """(sharpness per crop px, Adam iterations[, "xy"]) per stage, soft to sharp; "xy": range and
    bearing only, the heading held (a position error is otherwise partly 'explained' by turning)"""
    debias_stages: int = 2
    """how many final stages subtract the renderer's soft-minus-hard excess, recomputed at each
    stage's start (0: plain L2 throughout). Only at the end: far from the optimum the excess
    image sits in the wrong place (debiasing every stage measured worse: 5 flips in 20 frames)"""
    optimizer: str = "lm"
    """"lm": Levenberg-Marquardt on the pixel residuals with central finite-difference Jacobians
    (the silhouette has reverse-mode derivatives only: 6 extra forward renders per step, no
    backward); "adam": Adam steps on the loss gradient"""
    fd_step: tuple[float, float, float] = (0.004, 0.0015, 0.015)
    """finite-difference steps (log range, bearing rad, heading rad) of the "lm" optimizer"""
    fd: str = "central"
    """the "lm" optimizer's Jacobian: "central" differences (6 renders per hypothesis and step) or
    "forward" (3: the residuals at the current params are known), an error of order fd_step
    in the Jacobian, none in the loss that accepts a step; renders are the alignment's cost"""
    max_step: tuple[float, float, float] = (0.1, 0.05, 0.6)
    """largest "lm" step per parameter (the rest of a longer step is dropped)"""
    lr: tuple[float, float, float] = (0.02, 0.006, 0.08)
    """first Adam step per parameter (log range, bearing rad, heading rad); halves each stage"""
    coarse_margin: float = 2.5
    """`align` first centres the estimate in a crop this much wider than the model's box
    (position only, the estimate alone), then crops again at `margin` around the result: a
    decimetre lateral error at 3 m otherwise leaves half the robot outside the 1.4x crop"""
    coarse_stages: tuple[tuple, ...] = ((1.0, 6, "xy"),)
    """the stages of that first pass (() to skip it)"""
    flip: bool = True
    """also start from the heading turned by 180 deg"""
    mirror: bool = True
    """also start from the heading mirrored about the line of sight (psi' = 2 bearing - psi, and
    its flip): a left-right symmetric robot's silhouette at relative heading a and -a are mirror
    images, often nearly the same outline, so these are the local minima to start from"""
    perturbed: int = 0
    """extra starts drawn around the estimate (a fixed pseudo-random pattern)"""
    perturb_sigma: tuple[float, float, float] = (0.06, 0.01, 0.6)
    """std of the perturbed starts (log range, bearing rad, heading rad)"""
    tie: float = 0.3
    """hypotheses whose final loss is within (1 + tie) x the lowest are tied: the one nearest the
    initial estimate wins (0: the lowest loss always wins)"""
    tie_scale: tuple[float, float, float] = (0.05, 0.02, 0.5)
    """units of the distance from the start that breaks ties (log range, bearing rad, heading rad):
    near head-on views a hypothesis can trade range for heading at almost the same loss"""
    min_range_m: float = 0.3
    """an initial estimate nearer than this (or behind the camera) is declined"""
    max_score: float | None = None
    """accept the result only if the winner's final loss (mean squared silhouette difference in
    the crop) is at most this; else keep the initial estimate (`AlignResult.accepted` False).
    For an observed mask that may be wrong (a segmenter's): a mask that no pose of the model
    explains is not followed (None: always accept)"""
    min_turn: float = 0.0
    """accept the result only if it turned the heading by more than this (rad) from the initial
    estimate; else keep the initial estimate (0: no such condition). After a refiner cascade,
    which reads the position better than the alignment to a segmenter's mask wherever it reads the
    heading, the alignment is kept for the headings the cascade could not read (`refine.SEGMENTER_ALIGN`)"""
    max_shift: float | None = None
    """accept the result only if it moved the position by at most this fraction of the initial
    estimate's range; else keep the initial estimate (None: no such condition). From a cascade's
    end, within centimetres, a longer move follows a wrong mask (`refine.SEGMENTER_ALIGN`)"""
    cull: bool = False
    """render the soft silhouettes without a closed model's back faces (`render.RenderConfig.soft_cull`):
    half the pairs to visit, and their edge nearer the hard one. Off by default: with it the default
    stage ran 1.4-1.6x faster in the pipeline, but on validation IML+IR's ATE was worse, 1.097
    (1.003-1.219), with 716 flips against 680 (BENCHMARKS.md, "Back faces")"""
    skip_iou: float | None = None
    """skip the optimisation (keep the initial estimate, `AlignResult.skipped`) where the observed
    mask and the initial estimate's hard silhouette already agree at this IoU or more (`start_iou`;
    None: never skip). With `min_turn` such a start is rarely turned far enough to be kept, and the
    skip saves the alignment's renders: under `jax.lax.cond`, so only where frames are aligned one
    at a time (under vmap both branches run; `pipeline` maps IR over single frames)"""

    def __post_init__(self):
        for field, allowed in (("optimizer", ("lm", "adam")), ("fd", ("central", "forward"))):
            if getattr(self, field) not in allowed:
                raise ValueError(f"AlignConfig.{field}: {getattr(self, field)!r} is not one of {allowed}")
        if self.skip_iou is not None and not 0 < self.skip_iou <= 1:
            raise ValueError(f"AlignConfig.skip_iou: {self.skip_iou!r} is not in (0, 1] or None")


class AlignResult(NamedTuple):
    xypsi: jax.Array  # (3,) aligned planar pose (the initial one when declined)
    pose: jax.Array  # (7,) SE3 wxyz_xyz in the observer's robot frame (roll = pitch = 0, z = 0)
    roll_pitch: jax.Array  # (2,) zeros: the alignment is planar (see refine.RefineResult)
    declined: jax.Array  # () bool: initial pose behind the camera / projecting outside the image
    flip_confidence: jax.Array  # () in [0, 1]: (L_other - L_best) / (L_other + L_best), L_other the best
    #                            hypothesis facing the other way (> 90 deg away); 0 if there is none
    score: jax.Array  # () final loss of the winner (mean squared silhouette difference)
    hypotheses: jax.Array  # (N, 3) final planar pose of every hypothesis
    scores: jax.Array  # (N,) their final losses
    box: jax.Array  # (4,) the crop box (full-image px)
    accepted: jax.Array  # () bool: the result was kept (not declined, score within max_score, turned by more than
    #                       min_turn, moved by at most max_shift, not skipped)
    skipped: jax.Array  # () bool: the start already agreed with the mask (AlignConfig.skip_iou): not optimised
    #                      (hypotheses stay at their starts, scores all the start's)
    start_iou: jax.Array  # () IoU of the observed mask and the hard silhouette at the start (`start_iou`; 0 when
    #                        declined): whether the robot is where the start puts it


# ------------------------------------------------------------------------------ parameters


def params_from_xypsi(xypsi):
    """(..., 3) (x, y, psi) -> (log range, bearing, psi). Range floored at 1 mm (guard: log 0)."""
    r = jnp.maximum(jnp.hypot(xypsi[..., 0], xypsi[..., 1]), 1e-3)
    return jnp.stack([jnp.log(r), jnp.arctan2(xypsi[..., 1], xypsi[..., 0]), xypsi[..., 2]], -1)


def xypsi_from_params(p):
    r = jnp.exp(p[..., 0])
    return jnp.stack([r * jnp.cos(p[..., 1]), r * jnp.sin(p[..., 1]), wrap_angle(p[..., 2])], -1)


def pose_from_params(p, h) -> jaxlie.SE3:
    """(..., 3) params -> T_cam_model (batched SE3)."""
    xyp = xypsi_from_params(p)
    T_obs = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_z_radians(xyp[..., 2]), jnp.stack([xyp[..., 0], xyp[..., 1], jnp.zeros_like(xyp[..., 0])], -1))
    return T_cam_robot(h) @ T_obs


def _planar_pose(xypsi) -> jax.Array:
    """(7,) SE3 wxyz_xyz of the planar pose (3,) (z = roll = pitch = 0)."""
    T = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_z_radians(xypsi[2]),
                                                 jnp.stack([xypsi[0], xypsi[1], jnp.zeros_like(xypsi[0])]))
    return T.wxyz_xyz


def _corners(mesh) -> jax.Array:
    """(8, 3) corners of the model's axis-aligned bounding box (model frame)."""
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    sel = jnp.asarray(np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1).T, lo.dtype)
    return lo + sel * (hi - lo)


def crop_box(mesh, K, xypsi, cfg: AlignConfig):
    """(4,) DeepIM box of the model at the planar pose `xypsi` (`rhaml_jax.crop.object_box`)."""
    T = pose_from_params(params_from_xypsi(xypsi), cfg.camera_height_m)
    return _crop.object_box(K, T @ _corners(mesh), margin=cfg.margin)


def check_init(mesh, K, xypsi, width: int, height: int, cfg: AlignConfig):
    """() bool: the initial pose cannot be refined (non-finite, nearer than min_range_m or
    behind the camera, or the model's box centre projecting outside the image)."""
    finite = jnp.all(jnp.isfinite(xypsi))
    safe = jnp.where(finite, xypsi, jnp.array([3.0, 0.0, 0.0], xypsi.dtype))
    near = safe[0] < cfg.min_range_m
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    c = 0.5 * (lo + hi)
    T = pose_from_params(params_from_xypsi(safe), cfg.camera_height_m)
    pc = T @ c
    z = jnp.maximum(pc[2], 1e-6)  # guard: behind the camera is caught by `near`
    u = K[0, 0] * pc[0] / z + K[0, 2]
    v = K[1, 1] * pc[1] / z + K[1, 2]
    outside = (u < -0.5) | (u > width - 0.5) | (v < -0.5) | (v > height - 0.5)
    return ~finite | near | (pc[2] <= cfg.min_range_m * 0.5) | outside


def hypotheses(p0, cfg: AlignConfig):
    """(N, 3) starting params: the estimate, its flip, its mirror image and the mirror's flip, `perturbed` fixed pseudo-random starts."""
    starts = [p0]
    if cfg.flip:
        starts.append(p0 + jnp.array([0.0, 0.0, jnp.pi], p0.dtype))
    if cfg.mirror:
        pm = p0.at[2].set(2 * p0[1] - p0[2])
        starts.append(pm)
        if cfg.flip:
            starts.append(pm + jnp.array([0.0, 0.0, jnp.pi], p0.dtype))
    if cfg.perturbed:
        z = np.random.default_rng(1234).standard_normal((cfg.perturbed, 3)).clip(-2, 2)
        starts.extend(p0 + jnp.asarray(z * np.asarray(cfg.perturb_sigma), p0.dtype))
    return jnp.stack(starts)


# ------------------------------------------------------------------------------ alignment


def _loss_fn(mesh, K, box, target, h, S, rcfg: render.RenderConfig):
    """losses(P, k, bias) -> (N,) and vg(P, k, bias) -> ((N,), (N, 3) per-hypothesis gradients)."""

    def residuals(P, k, bias):
        s = render.silhouette(mesh, pose_from_params(P, h), K, S, S, box=box, sharpness=k, config=rcfg)  # (..., S, S)
        return (s - bias - target).reshape(P.shape[:-1] + (S * S,))

    def losses(P, k, bias):
        return jnp.mean(residuals(P, k, bias) ** 2, axis=-1)

    def vg(P, k, bias):
        # the hypotheses are independent: the gradient of the sum is each one's own gradient
        def f(P_):
            l = losses(P_, k, bias)
            return jnp.sum(l), l

        (_, l), G = jax.value_and_grad(f, has_aux=True)(P)
        return l, G

    return residuals, losses, vg


def _hard(mesh, K, box, P, h, S, ss: int = 4):
    """(N, S, S) the hard silhouette at params P rendered ss x ss times finer and averaged: its
    pixel-area coverage, as the observed mask's area-filtered crop."""
    hard = render.render(mesh, pose_from_params(P, h), K, S * ss, S * ss, box=box).mask.astype(jnp.float32)
    return hard.reshape(hard.shape[:-2] + (S, ss, S, ss)).mean((-3, -1))


def _bias(mesh, K, box, P, k, h, S, rcfg: render.RenderConfig):
    """(N, S, S) stop-gradient soft - hard silhouette at params P: the renderer's excess, so that
    the debiased residual compares like with like (`_hard`)."""
    soft = render.silhouette(mesh, pose_from_params(P, h), K, S, S, box=box, sharpness=k, config=rcfg)
    return jax.lax.stop_gradient(soft - _hard(mesh, K, box, P, h, S))


def _iou(hard, target):
    """() IoU of two (S, S) masks in [0, 1], each read as above one half (1 where both are empty)."""
    a, b = hard > 0.5, target > 0.5
    return jnp.sum(a & b) / jnp.maximum(jnp.sum(a | b), 1)


def start_iou(mesh, K, box, target, xypsi, cfg: AlignConfig) -> jax.Array:
    """() IoU of the observed mask `target` (S, S) in the crop `box` (4,) and the hard silhouette
    (area coverage) at the planar pose xypsi (3,): `AlignConfig.skip_iou`'s test."""
    P = params_from_xypsi(jnp.asarray(xypsi, jnp.float32))[None]
    return _iou(_hard(mesh, K, box, P, cfg.camera_height_m, cfg.crop)[0], target)


def _lm_stage(residuals, P, k, bias, free, iters: int, cfg: AlignConfig):
    """`iters` Levenberg-Marquardt steps of every hypothesis (N, 3) on residuals(P, k, bias);
    a step is kept only if it lowers the hypothesis' loss (else its damping grows 4x)."""
    N = P.shape[0]
    hstep = jnp.asarray(cfg.fd_step, P.dtype) * free  # held parameters: no column
    E = jnp.eye(3, dtype=P.dtype) * hstep  # (3, 3) rows: the FD offsets
    div = jnp.maximum(hstep, 1e-12)[None, :, None]  # guard: a held parameter's column is 0 / 1e-12 = 0
    max_step = jnp.asarray(cfg.max_step, P.dtype)

    def body(_, st):
        P, r, lam = st
        if cfg.fd == "forward":
            J = (residuals(P[:, None] + E[None], k, bias[:, None]) - r[:, None]) / div
        else:
            Q = jnp.concatenate([P[:, None] + E[None], P[:, None] - E[None]], 1)  # (N, 6, 3)
            rq = residuals(Q, k, bias[:, None])  # (N, 6, M)
            J = (rq[:, :3] - rq[:, 3:]) / (2 * div)  # (N, 3, M)
        J = J * free[None, :, None]
        A = jnp.einsum("nim,njm->nij", J, J)
        g = jnp.einsum("nim,nm->ni", J, r)
        d = jnp.diagonal(A, axis1=1, axis2=2)
        # damping on the diagonal (Marquardt) plus a floor, and 1 on held parameters: never singular
        Ad = A + (lam[:, None] * d + 1e-9 + (1 - free)[None])[..., None] * jnp.eye(3, dtype=P.dtype)
        delta = -jnp.linalg.solve(Ad, g[..., None])[..., 0] * free
        delta = jnp.clip(delta, -max_step, max_step)
        C = P + delta
        rc = residuals(C, k, bias)
        Lc, L = jnp.mean(rc ** 2, -1), jnp.mean(r ** 2, -1)
        acc = (Lc < L) & jnp.all(jnp.isfinite(delta), -1)
        P = jnp.where(acc[:, None], C, P)
        r = jnp.where(acc[:, None], rc, r)
        lam = jnp.where(acc, jnp.maximum(lam / 3, 1e-6), jnp.minimum(lam * 4, 1e6))
        return P, r, lam

    r0 = residuals(P, k, bias)
    P, _, _ = jax.lax.fori_loop(0, iters, body, (P, r0, jnp.full((N,), 1e-2, P.dtype)))
    return P


def align(mesh, mask, K, init_xypsi, cfg: AlignConfig = AlignConfig()) -> AlignResult:
    """Aligns the model's silhouette to `mask` (H, W) (observed mask in [0, 1], full image,
    intrinsics K (3, 3)) from the planar estimate `init_xypsi` (3,). `mesh`: a render.Mesh.

    Pure JAX (jit with cfg static; vmap over mask and init_xypsi for many frames)."""
    mask = jnp.asarray(mask, jnp.float32)
    Hh, Ww = mask.shape
    return align_to(mesh, lambda box: _crop.crop_image(mask[..., None], box, cfg.crop, cfg.crop)[..., 0], K, init_xypsi,
                    Ww, Hh, cfg)


def align_to(mesh, target_in, K, init_xypsi, width: int, height: int, cfg: AlignConfig = AlignConfig()) -> AlignResult:
    """`align` given `target_in`: box (4,) -> the observed mask (S, S) in [0, 1] in that box of the
    width x height image (a cropped mask, or a segmenter's output: `refine.segmenter`). First the
    coarse pass (position only, a crop `coarse_margin` wide), then the hypotheses in the crop at
    `margin` around its result."""
    mesh = render.as_mesh(mesh)
    K = jnp.asarray(K, jnp.float32)
    init = jnp.asarray(init_xypsi, jnp.float32)
    declined = check_init(mesh, K, init, width, height, cfg)
    safe = jnp.where(declined, jnp.array([3.0, 0.0, 0.0], jnp.float32), init)  # guard: no NaN downstream
    start = init
    if cfg.coarse_stages:
        coarse = dataclasses.replace(cfg, margin=cfg.coarse_margin, stages=cfg.coarse_stages, flip=False, mirror=False,
                                     perturbed=0, debias_stages=0, coarse_stages=(), max_score=None, min_turn=0.0,
                                     max_shift=None)
        cbox = jax.lax.stop_gradient(crop_box(mesh, K, safe, coarse))
        start = align_crop(mesh, target_in(cbox), cbox, K, init, width, height, coarse).xypsi
        safe = jnp.where(declined, safe, start)
    box = jax.lax.stop_gradient(crop_box(mesh, K, safe, cfg))
    r = align_crop(mesh, target_in(box), box, K, start, width, height, cfg)
    if cfg.coarse_stages and (cfg.max_score is not None or cfg.min_turn > 0 or cfg.max_shift is not None):
        # a rejected alignment keeps the estimate from before the coarse pass too
        xyp = jnp.where(r.accepted, r.xypsi, init)
        r = r._replace(xypsi=xyp, pose=_planar_pose(xyp))
    return r


def align_crop(mesh, target, box, K, init_xypsi, width: int, height: int, cfg: AlignConfig = AlignConfig()) -> AlignResult:
    """`align` given the observed mask already cropped: target (S, S) in [0, 1] of `box` (4,)
    (S = cfg.crop), e.g. a mask head's output; the image is width x height px."""
    mesh = render.as_mesh(mesh)
    K = jnp.asarray(K, jnp.float32)
    init = jnp.asarray(init_xypsi, jnp.float32)
    S, h = cfg.crop, cfg.camera_height_m
    declined = check_init(mesh, K, init, width, height, cfg)
    safe = jnp.where(declined, jnp.array([3.0, 0.0, 0.0], jnp.float32), init)  # guard: no NaN downstream
    box = jax.lax.stop_gradient(box)
    target = jax.lax.stop_gradient(target)
    p0 = jax.lax.stop_gradient(params_from_xypsi(safe))
    P = hypotheses(p0, cfg)  # (N, 3)
    N = P.shape[0]
    rcfg = render.RenderConfig(soft_cull=cfg.cull)
    residuals, losses, vg = _loss_fn(mesh, K, box, target, h, S, rcfg)
    zero_bias = jnp.zeros((1, S, S), jnp.float32)
    lr0 = jnp.asarray(cfg.lr, jnp.float32)
    b1, b2, eps = 0.9, 0.999, 1e-12
    k_last = jnp.float32(cfg.stages[-1][0])
    # (1, S, S) the start's hard silhouette, for its debiased score, the skip test and `start_iou`
    hard0 = _hard(mesh, K, box, p0[None], h, S)
    iou0 = _iou(hard0[0], target)
    # the initial estimate, unmoved, scored as the winners are (last stage's loss; debiased at p0,
    # the residual is exactly the hard silhouette's)
    if cfg.debias_stages:
        L_init = jnp.mean((hard0[0] - target) ** 2)
    else:
        L_init = losses(p0[None], k_last, zero_bias)[0]

    def optimise(P):
        """The stages from the starts P (N, 3): (final params, their last stage's losses (N,))."""
        n_st = len(cfg.stages)
        bias = zero_bias
        for si, stage in enumerate(cfg.stages):
            k, iters = jnp.float32(stage[0]), int(stage[1])
            free = jnp.asarray([1.0, 1.0, 0.0 if stage[2:] == ("xy",) else 1.0], jnp.float32)
            debias = si >= n_st - cfg.debias_stages
            bias = _bias(mesh, K, box, P, k, h, S, rcfg) if debias else zero_bias
            if cfg.optimizer == "lm":
                P = _lm_stage(residuals, P, k, bias, free, iters, cfg)
                continue
            L, G = vg(P, k, bias)
            lr = jnp.broadcast_to(lr0 * free * 0.5 ** max(si - 1, 0), (N, 3))

            def body(t, st, k=k, bias=bias):
                P, L, G, m, v, lr = st
                m = b1 * m + (1 - b1) * G
                v = b2 * v + (1 - b2) * G * G
                tt = (t + 1).astype(jnp.float32)
                step = lr * (m / (1 - b1 ** tt)) / (jnp.sqrt(v / (1 - b2 ** tt)) + eps)  # eps: 0/0 guard on held params
                C = P - step
                Lc, Gc = vg(C, k, bias)
                acc = (Lc < L) & jnp.isfinite(Lc)
                P = jnp.where(acc[:, None], C, P)
                G = jnp.where(acc[:, None], Gc, G)
                L = jnp.where(acc, Lc, L)
                lr = jnp.where(acc[:, None], lr, 0.5 * lr)
                return P, L, G, m, v, lr

            st = (P, L, G, jnp.zeros_like(P), jnp.zeros_like(P), lr)
            P, L, G, _, _, _ = jax.lax.fori_loop(0, iters, body, st)
        return P, losses(P, k_last, bias)

    if cfg.skip_iou is None:
        skipped = jnp.bool_(False)
        P, L = optimise(P)
    else:  # where the start already agrees with the mask every hypothesis stays, scored as the start
        skipped = iou0 >= cfg.skip_iou
        P, L = jax.lax.cond(skipped, lambda P: (P, jnp.full((N,), L_init)), optimise, P)
    # Ties go to the hypothesis nearest the initial estimate: near head-on and tail-on views the
    # silhouette hardly changes with the heading, and the mirror / flipped hypotheses then score
    # within noise of the right one (measured: 9 of 50 circle frames chose a wrong one by < 30 %).
    tied = L <= jnp.min(L) * (1 + cfg.tie) + 1e-9
    dp = P - p0
    dp = dp.at[:, 2].set(wrap_angle(dp[:, 2]))
    d_init = jnp.sum(jnp.abs(dp) / jnp.asarray(cfg.tie_scale, P.dtype), -1)  # distance from the start
    best = jnp.argmin(jnp.where(tied, d_init, jnp.inf))
    keep_init = L_init <= L[best]
    p_best = jnp.where(keep_init, p0, P[best])
    L_best = jnp.where(keep_init, L_init, L[best])
    xyp_all = xypsi_from_params(P)
    xyp_best = xypsi_from_params(p_best)
    dpsi = jnp.abs(wrap_angle(xyp_all[:, 2] - xyp_best[2]))
    L_other = jnp.min(jnp.where(dpsi > jnp.pi / 2, L, jnp.inf))
    conf = jnp.where(jnp.isfinite(L_other), (L_other - L_best) / jnp.maximum(L_other + L_best, 1e-12), 0.0)
    # straight-through: the increment carries no gradient (see the module docstring)
    turn = wrap_angle(xyp_best[2] - init[2])  # the heading's move, wrapped
    out = init + jax.lax.stop_gradient(xyp_best - init)
    out = out.at[2].set(init[2] + jax.lax.stop_gradient(turn))
    out = out.at[2].set(wrap_angle(out[2]))  # wrapped; gradient 1
    accepted = ~declined & ~skipped if cfg.max_score is None else ~declined & ~skipped & (L_best <= cfg.max_score)
    if cfg.min_turn > 0:
        accepted = accepted & (jnp.abs(turn) > cfg.min_turn)
    if cfg.max_shift is not None:
        accepted = accepted & (jnp.hypot(*(xyp_best[:2] - init[:2])) <= cfg.max_shift * jnp.hypot(init[0], init[1]))
    out = jnp.where(accepted, out, init)
    conf = jnp.where(accepted, conf, 0.0)
    return AlignResult(out, _planar_pose(out), jnp.zeros(2, jnp.float32), declined, conf, L_best, xyp_all, L, box, accepted,
                       skipped, jnp.where(declined, 0.0, iou0))
