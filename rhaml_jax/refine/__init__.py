"""Iterative refinement (the paper's IR): a learned DeepIM-style refiner, then multi-hypothesis
silhouette alignment through our differentiable renderer.

Public API:
- `refine(refiner, mesh, image, K, init_xypsi, cfg, mask=None, segmenter=None, scorer=None, fine=None) -> RefineResult`:
  the pipeline's entry point (pure JAX, jit-able with cfg and the nets static, vmappable over frames);
- `load_stage(...) -> (RefineConfig, StageParams)`, `refine_stage(cfg, stage, image, K, init_xypsi)`:
  the default IR stage's networks, and `refine` with them;
- `load_refiner(ckpt_dir, model=None) -> Refiner` (a checkpoint of another robot is refused);
- `load_segmenter(ckpt_dir, model=None) -> Segmenter`, `observed_mask`: the robot's mask in a crop
  of the image, the alignment's target (rhaml_jax.refine.segmenter);
- `align`, `align_to`, `align_crop`, `AlignConfig`, `AlignResult`: the alignment alone (rhaml_jax.refine.alignment);
- `RefinerConfig`, `get_refiner_config`: the learned refiner's configs (rhaml_jax.refine.net).

Camera: the observer's camera sits at (0, 0, h) in its robot frame and looks along +x with no
tilt (DESIGN.md section 2; `camera.T_cam_robot(h)`), h = `RefineConfig.camera_height_m`
(nominal 0.30 m); poses in and out are the observed robot's in the observer's robot frame.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax import crop as _crop
from rhaml_jax import frames, render
from rhaml_jax.camera import T_cam_robot
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine.alignment import AlignConfig, AlignResult, _corners, align, align_crop, align_to, check_init
from rhaml_jax.refine.net import RefinerConfig, get_refiner_config
from rhaml_jax.refine.scorer import Scorer, ScorerConfig, load_scorer
from rhaml_jax.refine.segmenter import Segmenter, SegmenterConfig, alignment_target, load_segmenter, observed_mask

__all__ = ["DEFAULT_REFINER", "DEFAULT_FINE_REFINERS", "DEFAULT_MIRROR", "DEFAULT_SCORER", "DEFAULT_FLIP_THRESHOLD", "DEFAULT_SEGMENTER", "SEGMENTER_ALIGN", "load_stage", "AlignConfig", "AlignResult", "align", "align_crop", "RefinerConfig", "get_refiner_config", "Refiner",
           "RefineConfig", "RefineResult", "refine", "load_refiner", "export_refiner", "shipped_refiner",
           "StageParams", "refine_stage", "heading_search", "view_starts", "check_ensemble", "mirror_update", "Scorer", "ScorerConfig", "load_scorer", "Segmenter", "SegmenterConfig", "load_segmenter", "observed_mask", "align_to"]


# The corners of the cube of (log range, bearing, heading) offsets in signs, ordered in antipodal
# pairs so that the first V of them (V even) average to zero offset; an odd count of views adds
# the pose itself (`view_starts`).
_VIEW_SIGNS = np.array([(1, 1, 1), (-1, -1, -1), (1, -1, -1), (-1, 1, 1),
                        (-1, 1, -1), (1, -1, 1), (-1, -1, 1), (1, 1, -1)], np.float32)


@functools.partial(jax.tree_util.register_dataclass, data_fields=["params"], meta_fields=["cfg"])
@dataclasses.dataclass(frozen=True)
class Refiner:
    """A trained refiner: params (a plain pytree: the pytree's leaves) and its static config
    (pytree metadata), so a Refiner passes through jit / vmap / grad as an argument."""

    params: dict
    cfg: RefinerConfig


@dataclasses.dataclass(frozen=True)
class RefineConfig:
    camera_height_m: float = 0.30
    """observer camera height h"""
    align: AlignConfig | None = None
    """the alignment after the learned iterations, to the refiner's predicted mask (None: learned
    iterations only; the shipped refiner's mask head is too coarse for it: BENCHMARKS.md). Without a
    refiner the alignment always runs (AlignConfig() when None)"""
    n_iter: int | None = None
    """learned iterations (None: the refiner's config, 4)"""
    flip_threshold: float = 0.5
    """the scorer turns the heading by about 180 deg only if its softmax mass on the other side exceeds this"""
    scorer_mirror: bool = False
    """the scorer also reads its input mirrored left-right and its logits are averaged with the
    plain read's (test-time mirroring, as `mirror` for the refiners): a side that only one of the
    two reads prefers gets less than the threshold. Only for left-right symmetric robots"""
    post_iter: int = 1
    """learned iterations after the scorer's heading search (the position, re-read at the new heading)"""
    fine_iter: int = 2
    """iterations of the fine refiner (`StageParams.fine`, a cascade's second stage trained from
    the small errors the first leaves: `RefinerConfig.starts`), after every other learned iteration.
    With the default fine refiner the second iteration takes 12 % off |dpsi| from the paper's noise
    and the pipeline's IML+IR position 2 % on the validation looks (session 29's fine refiner drifted
    after its first: BENCHMARKS.md, "How many iterations of each refiner")"""
    fine_views: int = 1
    """the fine refiner runs from this many starts around the pose and its answers are averaged
    (`view_starts`: 1 = the pose alone; at most 8). Measured: 8 views take 11 % off |dx| on
    validation, 2 % on the test set, for twice the time (BENCHMARKS.md, "Test-time views")"""
    fine_spread: tuple[float, float, float] = (0.01, float(np.deg2rad(0.2)), float(np.deg2rad(2.0)))
    """the views' offsets: log range, bearing (rad), heading (rad); the fine refiner's training
    starts' smaller spreads (`RefinerConfig.starts` "fine")"""
    mirror: str = "none"
    """test-time mirroring of the learned iterations: "none", "fine" (the fine refiner's) or "all":
    each such iteration also reads its input (observed crop and render) mirrored left-right and
    averages the two updates (`mirror_update`), as `IMLConfig.zoom_mirror` does for the zoom
    stage. Only for left-right symmetric robots (`iml.check_mirror_symmetric`), so not by default
    here; `load_stage`, which knows the robot, sets `DEFAULT_MIRROR` for a symmetric one"""
    max_final_step: float | None = 0.01
    """the cascade has converged when its last coarse learned iteration moved the range by at most
    this fraction (|log r_n / r_(n-1)|; needs n_iter >= 2; None: no check). An unconverged cascade
    (RefineResult.converged False) keeps the initial pose, as a declined one does: on images whose
    look the refiner does not read its iterations keep moving (on the validation looks its last
    coarse step moved the range by a median 0.14-0.19 % on ours, far more on one-paint robots), and
    the pose graph fuses such frames better from the IML's estimate (BENCHMARKS.md, "A convergence
    check for the refiner")"""
    fine_after_align: int = 0
    """iterations of the fine refiner after the alignment (with a fine refiner and an alignment): the
    alignment reads the heading from the outline, the fine refiner the position at that heading"""
    mask_threshold: float = 0.4
    """a segmenter's mask is thresholded here for the alignment: at 0.4 the shipped segmenter_fine_cpu's
    masks have the true area on the validation looks' 1.4x crops (area ratio 0.995-1.023 over four
    looks; 1.016-1.041 at 0.3; BENCHMARKS.md, "A segmenter for the cascade's end")"""

    def __post_init__(self):
        from rhaml_jax.errors import RhamlError

        if self.max_final_step is not None and not self.max_final_step > 0:
            raise RhamlError(f"RefineConfig.max_final_step must be > 0 or None, got {self.max_final_step}")
        if self.n_iter is not None and self.n_iter < 1:
            raise RhamlError(f"RefineConfig.n_iter must be >= 1 or None, got {self.n_iter}")
        if not 0 <= self.flip_threshold <= 1:
            raise RhamlError(f"RefineConfig.flip_threshold must be in [0, 1], got {self.flip_threshold}")
        if self.post_iter < 0:
            raise RhamlError(f"RefineConfig.post_iter must be >= 0, got {self.post_iter}")
        if self.fine_after_align < 0:
            raise RhamlError(f"RefineConfig.fine_after_align must be >= 0, got {self.fine_after_align}")
        if self.fine_iter < 0:
            raise RhamlError(f"RefineConfig.fine_iter must be >= 0, got {self.fine_iter}")
        if not 1 <= self.fine_views <= len(_VIEW_SIGNS):
            raise RhamlError(f"RefineConfig.fine_views must be in 1..{len(_VIEW_SIGNS)}, got {self.fine_views}")
        if self.mirror not in ("none", "fine", "all"):
            raise RhamlError(f"RefineConfig.mirror must be 'none', 'fine' or 'all', got {self.mirror!r}")
        if len(self.fine_spread) != 3 or min(self.fine_spread) < 0:
            raise RhamlError(f"RefineConfig.fine_spread must be 3 spreads >= 0 (log range, bearing, heading), got {self.fine_spread}")


class RefineResult(NamedTuple):
    pose: jax.Array  # (7,) SE3 wxyz_xyz, the observed robot in the observer's robot frame
    xypsi: jax.Array  # (3,) its planar pose
    roll_pitch: jax.Array  # (2,) roll, pitch (rad) of the learned refiner's last SE(3) estimate
    #                        (0 without a refiner): large values flag an erroneous observation
    declined: jax.Array  # () bool: the initial pose is behind the camera / projects outside the image
    flip_confidence: jax.Array  # () the alignment's margin over the best other-facing hypothesis, [0, 1]
    #                             (with a scorer and no alignment: 2 P(same side) - 1, clipped at 0)
    score: jax.Array  # () the alignment's final loss (0 without alignment)
    iterates: jax.Array  # (n_iter + 1, 3) planar pose after each learned iteration (row 0: the initial one);
    #                      with a scorer (n_iter + 2 + post_iter, 3): then the heading search, then the post iterations;
    #                      with a fine refiner fine_iter more rows: its iterations (and after the
    #                      alignment fine_after_align more)
    flip_prob: jax.Array  # () the scorer's probability that the heading faces the other way (-1: no scorer ran)
    converged: jax.Array  # () bool: the learned iterations settled (RefineConfig.max_final_step); if not, the
    #                       initial pose is returned as for a declined start (always True without a refiner)
    align_skipped: jax.Array  # () bool: the alignment was skipped, its start already fitting the mask
    #                           (`AlignConfig.skip_iou`; False where no alignment ran)
    mask_iou: jax.Array  # () IoU of the alignment's observed mask (a segmenter's) and the hard silhouette at the
    #                      alignment's start, the learned iterations' end with `SEGMENTER_ALIGN` (`AlignResult.start_iou`;
    #                      -1 where no alignment ran, 0 where declined)


def _T_cam(xypsi, h):
    return T_cam_robot(h) @ frames.se3_from_xypsi(xypsi)


def refine(refiner: Refiner | None, mesh, image, K, init_xypsi, cfg: RefineConfig = RefineConfig(), mask=None,
           segmenter: Segmenter | None = None, scorer: Scorer | None = None,
           fine: Refiner | tuple[Refiner, ...] | None = None) -> RefineResult:
    """Refines the planar estimate `init_xypsi` (3,) of the robot seen in `image` (H, W, 3)
    float32 in [0, 1] through intrinsics K (3, 3).

    With a refiner: n_iter learned iterations (re-rendering at each new pose); with a `scorer`
    too, then the heading search (`refine.scorer`: the best of rendered heading hypotheses, flips
    included) and cfg.post_iter more learned iterations at the new heading; with a `fine` refiner,
    then cfg.fine_iter iterations of it (a DeepIM cascade; a tuple of fine refiners is an ensemble
    whose updates each iteration averages, `check_ensemble`). Then the silhouette
    alignment (cfg.align, AlignConfig() when None): with a `segmenter`, to its mask of the
    image (always run); else with a refiner, to the refiner's mask head (only if cfg.align);
    else to the observed mask `mask` (H, W) in [0, 1] (then required); then cfg.fine_after_align
    more iterations of the fine refiner, if any. A declined start (behind the
    camera, projecting outside the image, non-finite) returns the initial pose, never NaN; so does
    an unconverged one (cfg.max_final_step: its last coarse iteration still moved the range).
    Differentiable wrt init_xypsi and the refiner's params (the alignment's increments are
    straight-through, see rhaml_jax.refine.alignment)."""
    from rhaml_jax.errors import RhamlError
    from rhaml_jax.refine import net as N
    from rhaml_jax.refine.train import render_input

    mesh = render.as_mesh(mesh)
    K = jnp.asarray(K, jnp.float32)
    init = jnp.asarray(init_xypsi, jnp.float32)
    image = jnp.asarray(image, jnp.float32)
    Hh, Ww = image.shape[:2]
    h = cfg.camera_height_m
    a = cfg.align if cfg.align is not None or (refiner is not None and segmenter is None) else AlignConfig()
    acfg = None if a is None else dataclasses.replace(a, camera_height_m=h)
    declined = check_init(mesh, K, init, Ww, Hh, acfg or AlignConfig(camera_height_m=h))
    safe = jnp.where(declined, jnp.array([3.0, 0.0, 0.0], jnp.float32), init)  # guard: no NaN downstream
    iterates = [init]
    roll_pitch = jnp.zeros(2, jnp.float32)
    xyp = safe
    target = box = None
    flip_prob = jnp.float32(-1.0)
    conf = jnp.float32(0.0)
    converged = jnp.bool_(True)
    if refiner is not None:
        rc = refiner.cfg
        n_iter = rc.n_iter if cfg.n_iter is None else cfg.n_iter
        corners = _corners(mesh)

        def learned(xyp, n, net=refiner, mirror=cfg.mirror == "all"):
            """n iterations of `net` from the planar pose xyp: (planar pose, roll and pitch); each
            iterate is kept as a row of `iterates`."""
            xyp, rp, its = _iterate(net, mesh, corners, image, K, h, xyp, n, mirror)
            iterates.extend(its)
            return xyp, rp

        xyp, roll_pitch = learned(safe, n_iter)
        if cfg.max_final_step is not None and n_iter >= 2:
            converged = _final_step(iterates[-2], iterates[-1]) <= cfg.max_final_step
        if scorer is not None:
            xyp, flip_prob, conf = _heading_search(scorer, mesh, corners, image, K, xyp, h, cfg.flip_threshold,
                                                   cfg.scorer_mirror)
            iterates.append(xyp)
            if cfg.post_iter:
                xyp, roll_pitch = learned(xyp, cfg.post_iter)
        if isinstance(fine, tuple):
            fine = check_ensemble(fine)
        if fine is not None and cfg.fine_iter:
            if cfg.fine_views > 1:
                xyp, roll_pitch, its = _multi_view(fine, mesh, corners, image, K, h, xyp, cfg.fine_iter, cfg.fine_views,
                                                   cfg.fine_spread, cfg.mirror != "none")
                iterates.extend(its)
            else:
                xyp, roll_pitch = learned(xyp, cfg.fine_iter, fine, cfg.mirror != "none")
        if acfg is not None and segmenter is None:  # the mask head at the final pose, in the alignment's crop
            box = jax.lax.stop_gradient(_crop.object_box(K, _T_cam(xyp, h) @ corners, margin=acfg.margin))
            obs = _crop.crop_image(image, box, rc.crop, rc.crop)
            T1 = _T_cam(xyp, h)
            x = render_input(mesh, rc, obs[None], jaxlie.SE3(T1.wxyz_xyz[None]), K, box)
            logits = N.apply(rc, refiner.params, x).mask_logits[0]
            target = jax.image.resize(jax.nn.sigmoid(logits), (acfg.crop, acfg.crop), "bilinear")
    elif mask is None and segmenter is None:
        raise RhamlError("refine: without a refiner, pass the observed mask (mask=...) or a segmenter for the alignment")
    score = jnp.float32(0.0)
    skipped, iou = jnp.bool_(False), jnp.float32(-1.0)
    if acfg is not None:
        if segmenter is not None:
            r = align_to(mesh, lambda b: alignment_target(segmenter, image, b, acfg.crop, cfg.mask_threshold), K, xyp,
                         Ww, Hh, acfg)
        elif target is None:
            r = align(mesh, mask, K, xyp, acfg)
        else:
            r = align_crop(mesh, target, box, K, xyp, Ww, Hh, acfg)
        flip_prob = _flip_prob_after(flip_prob, xyp[2], r.xypsi[2])
        xyp, score, conf, skipped, iou = r.xypsi, r.score, r.flip_confidence, r.skipped, r.start_iou
        if refiner is not None and fine is not None and cfg.fine_after_align:
            xyp, roll_pitch = learned(xyp, cfg.fine_after_align, fine, cfg.mirror != "none")
    keep_init = declined | ~converged
    xyp = jnp.where(keep_init, init, xyp)
    its = jnp.stack(iterates)
    its = jnp.where(declined, init[None], its)  # an unconverged run's iterates stay, to inspect
    roll_pitch = jnp.where(keep_init, 0.0, roll_pitch)
    T = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_rpy_radians(roll_pitch[0], roll_pitch[1], xyp[2]),
        jnp.stack([xyp[0], xyp[1], jnp.zeros_like(xyp[0])]))
    return RefineResult(T.wxyz_xyz, xyp, roll_pitch, declined, jnp.where(keep_init, 0.0, conf), score, its,
                        jnp.where(keep_init, -1.0, flip_prob), converged | declined, skipped & ~keep_init,
                        jnp.where(declined, 0.0, iou))


def _flip_prob_after(flip_prob, psi_before, psi_after):
    """The scorer's P(the heading faces the other way) (-1: no scorer ran) for the heading after
    the alignment: where the alignment turned it by more than 90 deg, the other way is the scorer's
    side, so 1 - flip_prob."""
    turned = jnp.abs(wrap_angle(psi_after - psi_before)) > jnp.pi / 2
    return jnp.where((flip_prob >= 0) & turned, 1.0 - flip_prob, flip_prob)


def _final_step(a, b):
    """|log(r_b / r_a)|: how far the range moved from planar pose a (3,) to b (3,)."""
    ra = jnp.maximum(jnp.hypot(a[0], a[1]), 1e-6)  # guard: no log(0) (check_init declines such starts)
    rb = jnp.maximum(jnp.hypot(b[0], b[1]), 1e-6)
    return jnp.abs(jnp.log(rb / ra))


def mirror_update(update):
    """(..., 6) the update read from left-right mirrored crops, mapped back: the image is mirrored
    about a vertical line, i.e. the camera frame's x axis reflected (M = diag(-1, 1, 1)); v_x
    changes sign, and the rotation vector, an axial vector, becomes det(M) M r = (r_x, -r_y, -r_z)."""
    return update * jnp.asarray([-1.0, 1.0, 1.0, 1.0, -1.0, -1.0], update.dtype)


def _iterate(net: Refiner | tuple[Refiner, ...], mesh, corners, image, K, h, xyp, n: int, mirror: bool = False):
    """n learned iterations of `net` from the planar pose xyp (3,), re-rendering between them:
    (planar pose (3,), roll and pitch (2,), the n iterates as a list of (3,)). `mirror`: each
    update is the average of the input's and its mirror image's (`RefineConfig.mirror`). A tuple
    of refiners is an ensemble (`check_ensemble`): each iteration averages their updates."""
    from rhaml_jax.refine import net as N
    from rhaml_jax.refine.train import render_input

    nets = net if isinstance(net, tuple) else (net,)
    nc = nets[0].cfg  # the crop and margin every member shares
    T_back = T_cam_robot(h).inverse()
    T = _T_cam(xyp, h)
    its = []
    for _ in range(n):
        T1 = jaxlie.SE3(T.wxyz_xyz[None])
        bx = jax.lax.stop_gradient(_crop.object_box(K, T @ corners, margin=nc.margin))
        obs = _crop.crop_image(image, bx, nc.crop, nc.crop)
        updates = []
        for m in nets:
            x = render_input(mesh, m.cfg, obs[None], T1, K, bx)  # (1, S, S, 7 or 3)
            update = N.apply(m.cfg, m.params, x).update
            if mirror:  # the mirrored scene's render, lit from the same side as every render it trained on
                lx, ly, lz = render.DEFAULT_LIGHT
                xm = render_input(mesh, m.cfg, obs[None], T1, K, bx, light_dir=(-lx, ly, lz))[:, :, ::-1]
                update = 0.5 * (update + mirror_update(N.apply(m.cfg, m.params, xm).update))
            updates.append(update)
        update = sum(updates) / len(updates)
        T = jaxlie.SE3(N.apply_update(T1, update, K, bx).wxyz_xyz[0])
        its.append(frames.xypsi_from_se3(T_back @ T))
    return frames.xypsi_from_se3(T_back @ T), frames.roll_pitch_yaw(T_back @ T)[:2], its


def check_ensemble(nets: tuple[Refiner, ...]) -> Refiner | tuple[Refiner, ...]:
    """`nets` as a fine refiner: the tuple (an ensemble), or its one member alone; refused
    (RhamlError) unless they can be averaged: at least one, all reading the same crop (side and
    margin), so that their updates live in the same box."""
    from rhaml_jax.errors import RhamlError

    if not nets:
        raise RhamlError("an ensemble of refiners needs at least one refiner")
    crops = {(m.cfg.crop, m.cfg.margin) for m in nets}
    if len(crops) > 1:
        names = ", ".join(f"{m.cfg.name} (crop {m.cfg.crop}, margin {m.cfg.margin})" for m in nets)
        raise RhamlError(f"an ensemble's refiners must share crop and margin: {names}")
    return nets[0] if len(nets) == 1 else nets


def view_starts(xyp, views: int, spread) -> jax.Array:
    """`views` starting poses (views, 3) around the planar pose xyp (3,): the range scaled by
    exp(+-spread[0]), the bearing and the heading turned by +-spread[1] and +-spread[2] (rad), the
    signs the corners of a cube in antipodal pairs; an odd count starts with xyp itself (1 view: xyp
    alone). Every count is centred on xyp."""
    if not 1 <= views <= len(_VIEW_SIGNS):
        from rhaml_jax.errors import RhamlError

        raise RhamlError(f"view_starts: views must be in 1..{len(_VIEW_SIGNS)}, got {views}")
    signs = _VIEW_SIGNS[: views - views % 2]
    if views % 2:
        signs = np.concatenate([np.zeros((1, 3), np.float32), signs])
    d = jnp.asarray(signs) * jnp.asarray(spread, jnp.float32)  # (V, 3)
    r = jnp.hypot(xyp[0], xyp[1])  # > 0: check_init declines starts at the camera
    b = jnp.arctan2(xyp[1], xyp[0])
    rv, bv = r * jnp.exp(d[:, 0]), b + d[:, 1]
    return jnp.stack([rv * jnp.cos(bv), rv * jnp.sin(bv), xyp[2] + d[:, 2]], 1)


def _circular_mean(p):
    """The mean over axis 0 of planar poses p (V, 3), the heading as the direction of the mean unit vector."""
    return jnp.concatenate([p[:, :2].mean(0), jnp.arctan2(jnp.sin(p[:, 2]).mean(0), jnp.cos(p[:, 2]).mean(0))[None]])


def _multi_view(net: Refiner | tuple[Refiner, ...], mesh, corners, image, K, h, xyp, n: int, views: int, spread, mirror: bool = False):
    """`_iterate` from each of `view_starts` at once, averaged (test-time augmentation: each start
    crops and renders the robot a little differently, so the network's per-crop errors average out)."""
    run = jax.vmap(lambda s: _iterate(net, mesh, corners, image, K, h, s, n, mirror))
    p, rp, its = run(view_starts(xyp, views, spread))  # (V, 3), (V, 2), n x (V, 3)
    return _circular_mean(p), rp.mean(0), [_circular_mean(i) for i in its]


def heading_search(scorer: Scorer, mesh, image, K, xypsi, h: float, flip_threshold: float, mirror: bool = False):
    """The scorer's heading search alone at the planar pose xypsi (3,) in `image` (H, W, 3) in
    [0, 1]: (planar pose, probability that the answer faces the wrong way, flip confidence); `h`
    the camera height (`RefineConfig.camera_height_m`). With `flip_threshold` 1 the pose is kept
    and the probability is that of the other side. `mirror`: `RefineConfig.scorer_mirror`."""
    return _heading_search(scorer, mesh, _corners(mesh), image, K, xypsi, h, flip_threshold, mirror)


def _heading_search(scorer: Scorer, mesh, corners, image, K, xyp, h, flip_threshold: float, mirror: bool = False):
    """The scorer's heading at the position of xyp (3,): (planar pose, flip probability, flip
    confidence). Straight-through in the heading (d result / d xyp = identity): the search is an
    argmax. `mirror`: the logits are the mean of the input's and its left-right mirror image's."""
    from rhaml_jax.refine import scorer as S

    sc = scorer.cfg
    box = jax.lax.stop_gradient(_crop.object_box(K, _T_cam(xyp, h) @ corners, margin=sc.margin))
    obs = _crop.crop_image(image, box, sc.crop, sc.crop)
    x0 = jax.lax.stop_gradient(xyp)
    pivot = jnp.asarray(S.pivot_xy(sc, corners), xyp.dtype)  # the box's corners span the model's box

    def score(headings):
        T = jaxlie.SE3(jax.vmap(lambda p: _T_cam(S.turned(x0, p - x0[2], pivot), h).wxyz_xyz)(headings))
        logits = S.apply(sc, scorer.params, S.score_input(mesh, sc, obs, T, K, box))
        if not mirror:
            return logits
        # the mirrored scene, lit from the mirrored side, as the refiners' mirrored reads (`_iterate`)
        lx, ly, lz = render.DEFAULT_LIGHT
        xm = S.score_input(mesh, sc, obs, T, K, box, light_dir=(-lx, ly, lz))[:, :, ::-1]  # (N, S, S, 3), width flipped
        return 0.5 * (logits + S.apply(sc, scorer.params, xm))

    r = S.search_heading(score, x0[2], sc.grid, sc.fine, float(np.deg2rad(sc.fine_step_deg)), flip_threshold)
    turn = wrap_angle(r.psi - x0[2])
    # straight-through: the turn (and the pivot's shift) is added as a constant
    step = jax.lax.stop_gradient(S.turned(x0, turn, pivot) - x0)
    return xyp + step, 1.0 - r.flip_confidence, jnp.clip(2.0 * r.flip_confidence - 1.0, 0.0, 1.0)


def load_refiner(ckpt_dir: str | Path, model=None) -> Refiner:
    """The refiner in an Orbax run folder (rebuilt from its stored config). With `model` (a
    RobotModel), a checkpoint trained for a robot of other extents is refused (RhamlError)."""
    from rhaml_jax.refine import net as N
    from rhaml_jax.refine._checkpoint import load_params

    return Refiner(*load_params(ckpt_dir, "refiner", model, N.config_from_dict, N.init_params))


def export_refiner(run_dir: str | Path, out_dir: str | Path) -> Path:
    """Writes the latest weights of a refiner run (no optimizer state) as a checkpoint folder
    that `load_refiner` reads; returns `out_dir`."""
    from rhaml_jax.refine._checkpoint import export_params

    return export_params(run_dir, out_dir, load_refiner(run_dir).params)


DEFAULT_REFINER = "refiner_paint_cpu"
"""the shipped refiner that `load_stage`, `evaluate` and the demo use unless given another:
`refiner_cpu` fine-tuned with its renders repainted half the time (`RefinerConfig.paint_prob`), so
that its update rests less on the model's paint matching the robot's. Chosen on validation
(BENCHMARKS.md, "Refiners trained on repainted renders"); `refiner_cpu`, the default until session
46, ships beside it, as do `refiner_fit167_cpu` and `refiner_fit180_cpu`, the from-scratch `fit` runs'"""


DEFAULT_FINE_REFINERS = ("refiner_fine_paint_cpu", "refiner_fine_native_cpu")
"""the shipped cascade's fine refiners, run after `DEFAULT_REFINER` unless another refiner is given:
an ensemble whose fine iterations average the two updates (`check_ensemble`). `refiner_fine_paint_cpu`
(`refiner_fine_more_cpu` fine-tuned with repainted renders, config `refiner_fine_paint_cpu`; session
46) and `refiner_fine_native_cpu` (trained from `refiner_fine_more_cpu` on renders at the image's pixel
centres, `RefinerConfig.native`). The ensemble was chosen on validation in session 43 (BENCHMARKS.md,
"An ensemble of fine refiners"), its first member replaced in session 46 ("Refiners trained on
repainted renders"). The fine refiners they were trained from ship beside them: `refiner_fine_more_cpu`
("The fine refiner on twice the images"), `refiner_fine_long_cpu` ("The fine refiner trained longer")
and session 29's `refiner_fine_cpu` ("A fine refiner")"""


DEFAULT_MIRROR = "fine"
"""`RefineConfig.mirror` that `load_stage` (so `evaluate`, the pipeline and the demo) sets for a
left-right symmetric robot: the fine refiner's iterations also read their crops mirrored. On
validation it takes 9 % off |dx| and 8 % off the ATE from the paper's noise, and the IML+IR
position 2 % over the validation looks; mirroring the coarse iterations too gains less
(BENCHMARKS.md, "What one image tells about the range, and mirrored crops")"""


DEFAULT_SCORER = "scorer_flip_wide_cpu"
"""the shipped front/back scorer that `load_stage` runs after the default refiner's coarse
iterations (`heading_search`), at `DEFAULT_FLIP_THRESHOLD` and no coarse iteration after it
(`RefineConfig.post_iter` 0): trained from estimates near the truth and anywhere, its renders
repainted (`ScorerConfig.paint_prob`). Chosen on validation (BENCHMARKS.md, "A front/back scorer
for the estimates IR leaves"); session 44's `scorer_flip_cpu`, trained within 6 deg, ships beside it"""


DEFAULT_FLIP_THRESHOLD = 0.8
"""`RefineConfig.flip_threshold` that `load_stage` sets with `DEFAULT_SCORER` (chosen on the validation looks' offline sweep)"""


DEFAULT_SEGMENTER = "segmenter_fine_cpu"
"""the shipped observed-mask segmenter that `load_stage` runs after the default cascade: the
silhouette alignment to its mask (`SEGMENTER_ALIGN`), which reads the heading of a robot whose
paint the refiners do not know from its outline (BENCHMARKS.md, "A segmenter for the cascade's
end" and "The alignment by default": chosen on validation in session 48)"""


SEGMENTER_ALIGN = AlignConfig(coarse_stages=(), stages=((2.0, 4), (4.0, 4), (8.0, 3), (8.0, 3)), min_turn=float(np.deg2rad(4.0)),
                              max_shift=0.03, fd="forward", skip_iou=0.95)
"""`RefineConfig.align` that `load_stage` sets with a segmenter: the alignment from the cascade's
end (its position within centimetres, no coarse pass) in 14 steps instead of the default's 35,
kept only where it turns the heading by more than 4 deg (`AlignConfig.min_turn`: where the
cascade read the heading, it reads the position better than the alignment) and moves the
position by at most 3 % of the range (`AlignConfig.max_shift`: a longer move follows a wrong
mask); both chosen on the validation runs (BENCHMARKS.md). Measured from the
default cascade's end (BENCHMARKS.md, "A segmenter for the cascade's end"): to ground-truth masks,
|dx| 1.9 cm, 0 flips on the OOD validation circle (the default schedule: 1.5 cm, 0 flips); to the
segmenter's masks, the OOD circle's |dpsi| 17.5 -> 3.5 deg, our circle's untouched. Forward
differences (`AlignConfig.fd`): 1.4-1.75x faster than central ones, and the gated stage with them
passed the validation rule (BENCHMARKS.md, "The alignment by default"). Skipped where the segmenter's
mask and the cascade's silhouette already agree at IoU 0.95 (`AlignConfig.skip_iou`): on the
validation looks 42 % of our look's frames and 2-3 % of the others', where the gates kept 15 of
6,116 alignments; every validation row level (BENCHMARKS.md, "Skipping the alignment")"""


def shipped_refiner(model=None) -> Refiner:
    """The default refiner shipped in the package (rhaml_jax/checkpoints/`DEFAULT_REFINER`), for the built-in robot."""
    from rhaml_jax.amlnet.checkpoint import shipped_checkpoint

    return load_refiner(shipped_checkpoint(DEFAULT_REFINER), model)


class StageParams(NamedTuple):
    """The IR stage's arrays (`pipeline.PipelineParams.refiner`): a pytree, None fields empty."""

    refiner: Refiner | None  # the learned refiner
    mesh: render.Mesh  # the robot's model
    segmenter: Segmenter | None = None  # the alignment's observed-mask network (None: no alignment)
    scorer: Scorer | None = None  # the heading scorer (None: the learned iterations keep the heading)
    fine: Refiner | tuple[Refiner, ...] | None = None  # a cascade's fine refiner (`RefinerConfig.starts` "fine";
    #                                                     a tuple: an ensemble, updates averaged; None: none)


def refine_stage(cfg: RefineConfig, stage: StageParams, image, K, init_xypsi) -> RefineResult:
    """`refine` with the stage's networks (`load_stage`'s pair): the pipeline's IR on one frame.
    image (H, W, 3) uint8 or float in [0, 255], as the pipeline's frames and `iml` take them."""
    image = jnp.asarray(image).astype(jnp.float32) / 255.0
    return refine(stage.refiner, stage.mesh, image, K, init_xypsi, cfg, segmenter=stage.segmenter,
                  scorer=stage.scorer, fine=stage.fine)


def load_stage(ckpt_dir: str | Path | None = None, data_dir: str | Path | None = None, check_robot: bool = True,
               segmenter: str | Path | None = None, scorer: str | Path | None = None,
               fine: str | Path | tuple[str | Path, ...] | None = None, mirror: str | None = None):
    """The pipeline's IR stage: (RefineConfig, StageParams) for `pipeline.PipelineModel.refiner`
    and `PipelineParams.refiner`. The robot is the BOP data set's model (`models/obj_000001.ply`)
    when `data_dir` has one, else the built-in robot; a checkpoint made for another robot is
    refused (unless not `check_robot`: a deliberate transfer test). Default refiner: the shipped
    `DEFAULT_REFINER`, with the shipped `DEFAULT_SCORER` after its coarse iterations and then the
    shipped `DEFAULT_FINE_REFINERS`, then the alignment to the shipped `DEFAULT_SEGMENTER`'s masks
    (`scorer`, `fine` or `segmenter` "none": without them; given another refiner, a scorer, fine
    refiner or segmenter runs only if named); with `segmenter` (a checkpoint folder) the learned iterations are followed by the
    silhouette alignment to its masks (`SEGMENTER_ALIGN`); with `scorer` (a checkpoint folder) by the heading search;
    with `fine` (a refiner checkpoint folder, or several: an ensemble) by that refiner's iterations (a cascade). `mirror`:
    `RefineConfig.mirror` (None: `DEFAULT_MIRROR` for a left-right symmetric robot, "none" for
    another; mirroring named for an asymmetric robot is refused)."""
    from rhaml_jax.amlnet.checkpoint import shipped_checkpoint
    from rhaml_jax.data import bop_model_path, load_bop_model
    from rhaml_jax.robots import load_robot

    robot = load_bop_model(data_dir) if data_dir is not None and bop_model_path(data_dir).exists() else load_robot("pioneer3dx")
    check = robot if check_robot else None
    refiner = load_refiner(ckpt_dir or shipped_checkpoint(DEFAULT_REFINER), check)
    if segmenter is None and ckpt_dir is None:
        segmenter = shipped_checkpoint(DEFAULT_SEGMENTER)
    seg = None if segmenter is None or str(segmenter) == "none" else load_segmenter(segmenter, check)
    cfg = RefineConfig(mirror=_mirror_setting(robot, mirror), align=None if seg is None else SEGMENTER_ALIGN)
    if scorer is None and ckpt_dir is None:
        scorer = shipped_checkpoint(DEFAULT_SCORER)
        cfg = dataclasses.replace(cfg, flip_threshold=DEFAULT_FLIP_THRESHOLD, post_iter=0)
    sc = None if scorer is None or str(scorer) == "none" else load_scorer(scorer, check)
    if fine is None and ckpt_dir is None:
        fine = tuple(shipped_checkpoint(n) for n in DEFAULT_FINE_REFINERS)
    fines = [] if fine is None else [fine] if isinstance(fine, (str, Path)) else list(fine)
    fines = [f for f in fines if str(f) != "none"]
    fn = check_ensemble(tuple(load_refiner(f, check) for f in fines)) if fines else None
    return cfg, StageParams(refiner, render.as_mesh(robot), seg, sc, fn)


def _mirror_setting(robot, mirror: str | None) -> str:
    """`RefineConfig.mirror` for this robot: `mirror`, or `DEFAULT_MIRROR` where the robot is left-right
    symmetric ("none" where not); a mirroring named for an asymmetric robot raises RhamlError."""
    from rhaml_jax.errors import RhamlError
    from rhaml_jax.iml import check_mirror_symmetric

    if mirror is None:
        try:
            check_mirror_symmetric(robot, robot.name)
        except RhamlError:
            return "none"
        return DEFAULT_MIRROR
    RefineConfig(mirror=mirror)  # refuses an unknown setting
    if mirror != "none":
        check_mirror_symmetric(robot, robot.name, "--refine-mirror")
    return mirror
