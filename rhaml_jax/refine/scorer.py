"""The heading scorer: a learned render-and-compare verifier that chooses the robot's heading
among hypotheses rendered side by side (after MegaPose's coarse scoring), so that refinement
resolves front/back flips and sets the heading to about a degree.

Why: the learned refiner's rotation output does not learn the sign of a heading error
(BENCHMARKS.md, "Refinement"), and a flip (180 deg) is beyond any regressed update. Comparing
renders is easier than regressing a turn: the scorer sees the observed crop beside one render
and says how well they agree; a softmax over a crop's hypotheses, trained with soft targets
(a Gaussian of each hypothesis' heading error), makes its logits peaked and smooth in the heading,
so the best of a coarse grid plus a parabola through its neighbours gives the heading between
grid points.

Input per hypothesis (S, S, 3): the observed crop's luminance, the render's luminance and the
render's mask (no hue: a repainted robot must score alike). One crop box for every hypothesis of
a frame: the model's box at the estimate (`crop.object_box`) times `margin`.

Test time (`search_heading`): `grid` headings evenly spaced from the estimate's; the side
(facing as the estimate or the other way) with the larger softmax mass, the other way only if its
mass reaches a threshold (`RefineConfig.flip_threshold`: a converged estimate is not turned on a
doubt); the best heading on that side, then `fine` headings spaced `fine_step_deg` around it, each
peak refined by a parabola. The flip confidence is the coarse softmax's mass within 90 deg of
the answer.

The front/back scorer (`scorer_flip_cpu`) asks the one question the learned refiners cannot
answer: two hypotheses only, the estimate and it turned by 180 deg about the centre of the model's
box (`pivot` "centre"), where a refined estimate facing the wrong way keeps its outline; trained
from estimates a few centimetres and degrees from the truth, as the coarse refiner leaves them; at
test time it turns the heading where the other side's probability exceeds the threshold.

Pure functions over a params pytree; the `Scorer` pytree (params + static cfg) passes through
jit / vmap like `refine.Refiner`.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax import render
from rhaml_jax.errors import RhamlError
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine.net import config_to_dict, dataclass_from_dict, encode, encoder_init, luminance, named_config
from rhaml_jax.refine.train import CropSource, _se3_params

__all__ = ["ScorerConfig", "SCORER_CONFIGS", "get_scorer_config", "Scorer", "init_params", "apply", "score_input",
           "scorer_loss", "ScorerBatch", "ScorerSource", "scorer_task", "HeadingSearch", "search_heading",
           "train_offsets_deg", "load_scorer", "export_scorer"]

@dataclasses.dataclass(frozen=True)
class ScorerConfig:
    name: str = "scorer_cpu"
    crop: int = 64
    """input side (px)"""
    widths: tuple[int, ...] = (32, 64, 96, 128)
    """stride-2 3x3 conv stages"""
    hidden: int = 128
    """fully connected layer before the score"""
    margin: float = 1.4
    """crop box = projected model box at the estimate times this (DeepIM)"""
    sigma_deg: float = 7.5
    """training target: softmax over a crop's hypotheses of -err^2 / (2 sigma^2)"""
    pos_sigma_m: float = 0.04
    """training estimates: position noise along and across the line of sight (the refiner's residual)"""
    grid: int = 24
    """test time: coarse headings, evenly spaced over the circle (15 deg apart)"""
    fine: int = 5
    """test time: headings around the coarse peak"""
    fine_step_deg: float = 5.0
    """their spacing"""
    offsets_deg: tuple[float, ...] = ()
    """training hypotheses: headings relative to the drawn estimate (empty: `train_offsets_deg`'s grid neighbours and flips)"""
    near_deg: float | None = None
    """training estimates: heading drawn uniformly within this of the truth (None: half a grid step)..."""
    far_prob: float = 0.25
    """...or anywhere, this often"""
    pivot: str = "origin"
    """hypotheses turn about the robot frame's origin ("origin") or the centre of the model's box in
    the floor plane ("centre": a robot turned front to back about it keeps its outline's place,
    as a refined flipped estimate does)"""
    paint_prob: float = 0.0
    """training: the render's parts repainted this often (`data.sample_paint`: half in one paint),
    so that the scores do not rest on the model's paint matching the robot's: a user's CAD colours
    are not the robot's, and a robot in one paint is rendered in one paint"""

    def __post_init__(self):
        if self.pivot not in ("origin", "centre"):
            raise RhamlError(f"ScorerConfig.pivot: {self.pivot!r} is neither 'origin' nor 'centre'")
        if self.grid < 2 or self.fine < 1:
            raise RhamlError(f"ScorerConfig: grid must be >= 2 and fine >= 1, got {self.grid} and {self.fine}")
        for name in ("far_prob", "paint_prob"):
            if not 0 <= getattr(self, name) <= 1:
                raise RhamlError(f"ScorerConfig.{name} must be in [0, 1], got {getattr(self, name)}")


SCORER_CONFIGS = {"scorer_cpu": ScorerConfig(),
                  "scorer_micro": ScorerConfig(name="scorer_micro", crop=32, widths=(8, 16), hidden=16, grid=8, fine=3),
                  # front or back only: the estimate and its flip about the box centre, at the fine refiners' margin
                  "scorer_flip_cpu": ScorerConfig(name="scorer_flip_cpu", crop=96, widths=(32, 64, 96, 128, 128), margin=1.2,
                                                  grid=2, fine=1, offsets_deg=(0.0, 180.0), near_deg=6.0, far_prob=0.0,
                                                  pivot="centre"),
                  # the same network for the estimates IR leaves on unfamiliar looks (half of them anywhere: often
                  # tens of degrees off, where the side nearer the truth is the answer and about 90 deg off there
                  # is none, so a wide target), its renders repainted half the time
                  "scorer_flip_wide_cpu": ScorerConfig(name="scorer_flip_wide_cpu", crop=96, widths=(32, 64, 96, 128, 128),
                                                       margin=1.2, grid=2, fine=1, offsets_deg=(0.0, 180.0), near_deg=6.0,
                                                       far_prob=0.5, sigma_deg=30.0, pivot="centre", paint_prob=0.5),
                  "scorer_flip_micro": ScorerConfig(name="scorer_flip_micro", crop=32, widths=(8, 16), hidden=16, grid=2,
                                                    fine=1, offsets_deg=(0.0, 180.0), near_deg=6.0, far_prob=0.0,
                                                    pivot="centre")}

# scorer_flip_wide_cpu's two changes apart (session 46): estimates anywhere with the wide target only, repainted renders only
SCORER_CONFIGS["scorer_flip_far_cpu"] = dataclasses.replace(SCORER_CONFIGS["scorer_flip_wide_cpu"], name="scorer_flip_far_cpu",
                                                            paint_prob=0.0)
SCORER_CONFIGS["scorer_flip_paint_cpu"] = dataclasses.replace(SCORER_CONFIGS["scorer_flip_wide_cpu"], name="scorer_flip_paint_cpu",
                                                              far_prob=0.0, sigma_deg=ScorerConfig.sigma_deg)


def get_scorer_config(name: str) -> ScorerConfig:
    return named_config(SCORER_CONFIGS, name, "scorer")


def config_from_dict(d: dict) -> ScorerConfig:
    return dataclass_from_dict(ScorerConfig, d)


def pivot_xy(cfg: ScorerConfig, vertices):
    """(2,) the point in the robot's floor plane (model frame) that the hypotheses turn about;
    `vertices` (N, 3), NumPy or JAX (the result is of the same kind)."""
    c = 0.5 * (vertices.min(0) + vertices.max(0))[:2]
    return c * 0 if cfg.pivot == "origin" else c


def turned(xypsi, angle, pivot):
    """The planar pose (3,) turned by `angle` about the model-frame point `pivot` (2,): the
    heading changes by `angle`, the position so that the pivot stays where it was."""
    x, y, psi = xypsi[0], xypsi[1], xypsi[2]
    c0, s0, c1, s1 = jnp.cos(psi), jnp.sin(psi), jnp.cos(psi + angle), jnp.sin(psi + angle)
    px, py = pivot[0], pivot[1]
    return jnp.stack([x + c0 * px - s0 * py - (c1 * px - s1 * py), y + s0 * px + c0 * py - (s1 * px + c1 * py), psi + angle])


@functools.partial(jax.tree_util.register_dataclass, data_fields=["params"], meta_fields=["cfg"])
@dataclasses.dataclass(frozen=True)
class Scorer:
    """A trained scorer: params (pytree leaves) and its static config (pytree metadata)."""

    params: dict
    cfg: ScorerConfig


# ------------------------------------------------------------------------------ the network


def init_params(cfg: ScorerConfig, key) -> dict:
    keys = jax.random.split(key, len(cfg.widths) + 2)
    convs, fc = encoder_init(keys[:len(cfg.widths)], keys[-2], 3, cfg.widths, cfg.crop, cfg.hidden)
    out = {"w": jnp.zeros((cfg.hidden, 1)), "b": jnp.zeros((1,))}  # zero init: every hypothesis alike at first
    return {"convs": convs, "fc": fc, "out": out}


def apply(cfg: ScorerConfig, params: dict, x):
    """x (..., S, S, 3) in [0, 1] -> score logits (...,)."""
    lead = x.shape[:-3]
    z, _ = encode(params["convs"], params["fc"], x.reshape((-1,) + x.shape[-3:]))
    return (z @ params["out"]["w"] + params["out"]["b"])[:, 0].reshape(lead)


def score_input(mesh, cfg: ScorerConfig, obs, T_cam: jaxlie.SE3, K, box, light_dir=render.DEFAULT_LIGHT):
    """(H, S, S, 3) scorer input for H hypotheses T_cam (H,) of one crop: obs (S, S, 3) RGB in
    [0, 1], K (3, 3), box (4,). The render is an input (no gradient), as the refiner's."""
    S = cfg.crop
    H = T_cam.wxyz_xyz.shape[0]
    out = render.render(mesh, T_cam, K, S, S, box=box, light_dir=light_dir)  # one K and box for all H hypotheses
    rend = jax.lax.stop_gradient(jnp.stack([luminance(out.rgb), out.mask.astype(obs.dtype)], -1))
    o = jnp.broadcast_to(luminance(obs)[None, ..., None], (H, S, S, 1))
    return jnp.concatenate([o, rend], -1)


# ------------------------------------------------------------------------------ training


def train_offsets_deg(cfg: ScorerConfig) -> np.ndarray:
    """The training hypotheses' headings relative to a drawn one near the truth: `cfg.offsets_deg`,
    or by default the coarse grid's neighbours (+-1, +-2 steps), the flip and its neighbours, so
    that the softmax contrasts a turn to the left with one to the right and the front with the back."""
    if cfg.offsets_deg:
        return np.asarray(cfg.offsets_deg, np.float64)
    step = 360.0 / cfg.grid
    return np.array([0.0, step, -step, 2 * step, -2 * step, 180.0, 180.0 + step, 180.0 - step])


class ScorerBatch(NamedTuple):
    obs: np.ndarray  # (B, S, S, 3) float32 [0, 1] observed crop
    box: np.ndarray  # (B, 4) crop box, full-image px
    K: np.ndarray  # (B, 3, 3)
    T_hyp: np.ndarray  # (B, H, 7) T_cam_model wxyz_xyz of each hypothesis
    err: np.ndarray  # (B, H) float32 heading error of each hypothesis (rad, wrapped)
    paint: np.ndarray  # (B, F, 3) float32 the render's face colours (the model's, or repainted: paint_prob)


class ScorerSource(CropSource):
    """batch(step) of B examples (a pure function of (seed, step)): a frame of a BOP set, an
    estimate at the true position plus N(0, pos_sigma_m) along and across the line of sight with a
    heading drawn near the truth (uniform within `near_deg`) or anywhere (`far_prob`), its crop,
    and the hypotheses: that estimate turned by `train_offsets_deg` about the config's pivot; the
    render's face colours (`CropSource.paint`)."""

    def initial(self, xypsi, rng):
        x, y, psi = xypsi
        r0, b = np.hypot(x, y), np.arctan2(y, x)
        s = self.cfg.pos_sigma_m
        along, across = rng.normal(0, s), rng.normal(0, s)
        r = max(r0 + along, 0.3)
        b = b + across / max(r0, 0.3)
        half = np.pi / self.cfg.grid if self.cfg.near_deg is None else np.deg2rad(self.cfg.near_deg)
        dpsi = rng.uniform(-half, half) if rng.random() >= self.cfg.far_prob else rng.uniform(-np.pi, np.pi)
        return np.array([r * np.cos(b), r * np.sin(b), psi + dpsi])

    def example(self, index: int):
        f, T_init, box, obs, _ = self.drawn(index)
        offs = np.deg2rad(train_offsets_deg(self.cfg))
        c, s = np.cos(offs), np.sin(offs)
        Rz = np.zeros((len(offs), 4, 4))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1] = c, -s, s, c
        Rz[:, 2, 2] = Rz[:, 3, 3] = 1
        P = np.eye(4)
        P[:2, 3] = pivot_xy(self.cfg, self.model.vertices)
        T_hyp = T_init[None] @ P @ Rz @ np.linalg.inv(P)  # the heading turned about the pivot's vertical axis
        # heading error of each hypothesis: the rotation between hypothesis and truth about the robot's vertical
        R_rel = np.einsum("ji,hjk->hik", f.T_m2c[:3, :3], T_hyp[:, :3, :3])
        err = np.arctan2(R_rel[:, 1, 0], R_rel[:, 0, 0])
        return (obs, box.astype(np.float32), f.K.astype(np.float32), np.stack([_se3_params(T) for T in T_hyp]),
                err.astype(np.float32), self.paint(index))

    def __call__(self, step: int) -> ScorerBatch:
        ex = [self.example(step * self.batch + j) for j in range(self.batch)]
        return ScorerBatch(*(np.stack([e[k] for e in ex]) for k in range(len(ScorerBatch._fields))))


def scorer_loss(cfg: ScorerConfig, mesh, params, b):
    """Softmax cross-entropy over each crop's hypotheses against soft targets, and metrics:
    `top1` (the best-scored hypothesis is the one nearest the truth), `flip` (it faces the other
    way, |error| > 90 deg), `err_deg` (its |heading error|)."""
    obs, box, K, T_hyp, err, paint = b
    x = jax.vmap(lambda o, T, k, bx, c: score_input(mesh._replace(face_colors=c), cfg, o, jaxlie.SE3(T), k, bx))(
        obs, T_hyp, K, box, paint)
    logits = apply(cfg, params, x)  # (B, H)
    sig = np.deg2rad(cfg.sigma_deg)
    target = jax.nn.softmax(-0.5 * (err / sig) ** 2, -1)
    ce = -jnp.sum(target * jax.nn.log_softmax(logits, -1), -1)
    best = jnp.argmax(logits, -1)
    e_best = jnp.abs(jnp.take_along_axis(err, best[:, None], -1)[:, 0])
    parts = {"loss": jnp.mean(ce), "top1": jnp.mean(best == jnp.argmin(jnp.abs(err), -1)),
             "flip": jnp.mean(e_best > np.pi / 2), "err_deg": jnp.rad2deg(jnp.mean(e_best))}
    return parts["loss"], parts


def check_scorer_batch(cfg: ScorerConfig, b, size: int, where: str, faces: int) -> None:
    from rhaml_jax.refine._task import check_fields

    S, H = cfg.crop, len(train_offsets_deg(cfg))
    check_fields(b, {"obs": (size, S, S, 3), "box": (size, 4), "K": (size, 3, 3), "T_hyp": (size, H, 7),
                     "err": (size, H), "paint": (size, faces, 3)}, "ScorerBatch", where)


def scorer_task(cfg: ScorerConfig, tc, model, val_source=None, num_devices=None):
    """(the `rhaml_jax.training.Task` of the scorer, its shardings); `model`: the RobotModel
    rendered and fingerprinted."""
    from rhaml_jax.refine._task import network_task

    mesh = render.as_mesh(model)
    return network_task("scorer", cfg, tc, model, init_params=init_params, config_to_dict=config_to_dict,
                        config_from_dict=config_from_dict,
                        loss=lambda params, *b: scorer_loss(cfg, mesh, params, b), n_fields=len(ScorerBatch._fields),
                        check_batch=lambda b, size, where: check_scorer_batch(cfg, b, size, where, len(mesh.faces)),
                        val_source=val_source, num_devices=num_devices)


# ------------------------------------------------------------------------------ test time


class HeadingSearch(NamedTuple):
    psi: jax.Array  # () the chosen heading (rad, wrapped)
    flip_confidence: jax.Array  # () coarse softmax mass within 90 deg of psi, [0, 1]
    flipped: jax.Array  # () bool: the answer faces the other way from psi0
    coarse_logits: jax.Array  # (grid,) scores of psi0 + 2 pi k / grid


def _peak(logits, step):
    """(best index, offset of the parabola through the best score and its two cyclic neighbours,
    within half a step: in units of `step` times step)."""
    k = jnp.argmax(logits)
    n = logits.shape[0]
    lm, l0, lp = logits[(k - 1) % n], logits[k], logits[(k + 1) % n]
    den = lm - 2 * l0 + lp
    # guard: a flat top (den = 0) would divide by zero; the peak is then the best point itself
    d = jnp.where(den < -1e-6, 0.5 * (lm - lp) / jnp.where(den < -1e-6, den, -1.0), 0.0)
    return k, jnp.clip(d, -0.5, 0.5) * step


def search_heading(score: Callable, psi0, grid: int, fine: int, fine_step: float,
                   flip_threshold: float = 0.5) -> HeadingSearch:
    """The heading that `score(headings (N,)) -> logits (N,)` rates best: a coarse grid of
    `grid` headings from psi0; the side (facing as psi0 or the other way) whose softmax mass is
    larger, the other way only if its mass exceeds `flip_threshold`; the best coarse heading on
    that side, then `fine` headings `fine_step` apart around it, each peak refined by a parabola
    (the fine grid's own ends are not interpolated past)."""
    step = 2 * np.pi / grid
    coarse = psi0 + step * jnp.arange(grid)
    lc = score(coarse)
    p = jax.nn.softmax(lc)
    # weight of each coarse heading on psi0's side: 1 within 90 deg, 0 beyond, 1/2 at 90 deg (a
    # flat score then puts half its mass on either side)
    turn = np.minimum(np.arange(grid), grid - np.arange(grid)) * step
    w_same = jnp.asarray(np.where(turn < np.pi / 2 - 1e-6, 1.0, np.where(turn > np.pi / 2 + 1e-6, 0.0, 0.5)), lc.dtype)
    p_same = jnp.sum(p * w_same)
    flipped = (1.0 - p_same) > flip_threshold
    side = jnp.where(flipped, w_same < 1, w_same > 0)
    # the other side's scores pushed below every score on this side (finite: the parabola reads them)
    k, d = _peak(jnp.where(side, lc, jnp.min(lc) - 10.0), step)
    psi_c = coarse[k] + d
    if fine > 1:
        offs = fine_step * (jnp.arange(fine) - (fine - 1) / 2)
        lf = score(psi_c + offs)
        kf = jnp.argmax(lf - 1e-6 * jnp.abs(offs))  # a tie goes to the centre
        inner = (kf > 0) & (kf < fine - 1)
        _, df = _peak(lf, fine_step)
        psi_c = psi_c + offs[kf] + jnp.where(inner, df, 0.0)
    psi = wrap_angle(psi_c)
    return HeadingSearch(psi, jnp.sum(jnp.where(jnp.cos(coarse - psi) > 0, p, 0.0)), flipped, lc)


# ------------------------------------------------------------------------------ checkpoints


def load_scorer(ckpt_dir: str | Path, model=None) -> Scorer:
    """The scorer in an Orbax run folder; with `model` (a RobotModel) a checkpoint made for
    another robot is refused (RhamlError)."""
    from rhaml_jax.refine._checkpoint import load_params

    return Scorer(*load_params(ckpt_dir, "scorer", model, config_from_dict, init_params))


def export_scorer(run_dir: str | Path, out_dir: str | Path) -> Path:
    """Writes the latest weights of a scorer run (no optimizer state) as a checkpoint folder."""
    from rhaml_jax.refine._checkpoint import export_params

    return export_params(run_dir, out_dir, load_scorer(run_dir).params)
