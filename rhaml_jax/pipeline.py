"""The RHAML pipeline (the paper's Algorithm 2) as one pure function over a rendezvous sequence.

    run(model, params, seq) -> PipelineResult          (run_jit: the shared compiled form)

A `Sequence` holds N frames, each one camera image in which one robot may see the other, with
both robots' odometry at that instant (static shapes: pad with `valid` False). The modules,
chosen in `PipelineConfig.modules` as the paper's flexible architecture allows, are

- `iml`: AMLNet and its zoom-in stage on every frame (`rhaml_jax.iml.localize`);
- `ir`: render-and-compare refinement of every detected frame (`rhaml_jax.refine`);
- `pgo`: the robust pose graph over the detected frames with both odometries
  (`rhaml_jax.pgo.fuse`: batch, the whole sequence, as the paper evaluates; or
  `pgo.fuse_online`: frame k fused from frames <= k only, compiled once for the length N);
  with a second, lower detection threshold (`redetect`: frames scored just under it join the
  graph where they agree with the graph of the confident frames; online, in the same pass), and
  optionally the graph's second look (`track`: the frames the detection left out refined from the
  graph's answer, joining where a segmenter's mask confirms the robot is there).

Everything between the images and the fused poses is traced: the function jits, vmaps over
sequences (same N), shards over devices (`shard_sequences`) and differentiates end to end
(gradients reach the networks' parameters through the pose graph). Image decoding and files
stay on the host (`rhaml_jax.sequence`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp

from rhaml_jax import pgo
from rhaml_jax.errors import RhamlError
from rhaml_jax.iml import Estimate, IMLModel, IMLParams, localize
from rhaml_jax.metrics import DETECTION_THRESHOLD

__all__ = ["MODULES", "RANGE_WINDOW_MAX_SCALE", "RANGE_WINDOW_REFINED", "REDETECT_HEADING_DEG", "PipelineConfig", "agrees", "fuse_estimates", "redetect", "PipelineModel",
           "PipelineParams", "PipelineResult", "SecondLook", "Sequence", "parse_modules", "run", "run_jit", "shard_sequences", "track"]

MODULES = ("iml", "ir", "pgo")
RANGE_WINDOW_REFINED = 200  # rows per transform of the range model for refined estimates (PipelineConfig.range_window)
MIN_RANGE_WINDOW = 10  # fewer rows per window leave the scale to the prior
# the range window only where the whole sequence's calibration finds the range off by less than
# this (PipelineConfig.range_window_max_scale): our look's refined ranges are within 0.1-0.5 %,
# a look the refiner does not read several percent off (BENCHMARKS.md, "The range window only for
# small scales")
RANGE_WINDOW_MAX_SCALE = 0.02
REDETECT_HEADING_DEG = 30.0  # the re-detection gate's heading tolerance, modulo 180 deg (the graph tries both)


def parse_modules(text: str) -> tuple[str, ...]:
    """'iml,ir,pgo' -> ('iml', 'ir', 'pgo'), or a clear error (unknown, repeated, or without iml)."""
    mods = tuple(m.strip() for m in text.split(",") if m.strip())
    unknown = [m for m in mods if m not in MODULES]
    if unknown:
        raise RhamlError(f"--modules {text}: unknown module {unknown[0]!r} (expected a comma-separated subset of "
                         f"{', '.join(MODULES)})")
    if len(set(mods)) != len(mods):
        raise RhamlError(f"--modules {text}: names a module twice")
    if "iml" not in mods:
        raise RhamlError(f"--modules {text}: the pipeline starts with iml (IR and PGO refine its estimates)")
    return tuple(m for m in MODULES if m in mods)


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Which modules run and how the pose graph fuses them (static under jit)."""

    modules: tuple[str, ...] = ("iml", "pgo")
    pgo_mode: Literal["batch", "online"] = "batch"
    fusion: pgo.FusionConfig = pgo.FusionConfig()
    chunk: int = 32  # frames per network call inside the traced function (bounds activation memory)
    # frames per IR call: at 1 each frame is refined alone, so `jax.lax.cond` skips the work a frame
    # does not need (frames that are not candidates; the alignment where its start already fits the
    # segmenter's mask, `AlignConfig.skip_iou`); vmapped frames run both branches. On this CPU one
    # at a time is faster than 32 vmapped even without a skip (151-152 against 173-176 ms per frame
    # of the default stage, BENCHMARKS.md "Skipping the alignment"); a GPU may want more
    ir_chunk: int = 1
    # batch pgo: calibrate the observations' range error from odometry (pgo.fuse_calibrated), then
    # fuse again with the ranges corrected; its priors keep it near 0 where the path does not tell
    calibrate_range: bool = True
    # batch pgo with calibrate_range: the range model fits one transform between the odometry
    # frames per this many consecutive rows (`pgo.fuse_calibrated`'s window), so that the
    # odometry's drift is not read as a range error (one transform for the whole sequence read
    # ground-truth ranges +0.2 to +0.4 % long on validation sequences); None: one for the whole
    # sequence; "auto": RANGE_WINDOW_REFINED rows for refined estimates (ir in modules), None for
    # IML's own, whose range error grows with the range and needs the whole path to be seen
    # (BENCHMARKS.md, "The range calibration read the odometry's drift")
    range_window: int | None | Literal["auto"] = "auto"
    # batch pgo with a range window: the windowed fit only where the whole sequence's finds the
    # range off by less than this (|c_0|); else the whole sequence's (`pgo.fuse_calibrated`'s
    # window_max_scale; windows take up part of a large scale). None: the window always
    range_window_max_scale: float | None = RANGE_WINDOW_MAX_SCALE
    # pgo: a second, lower objectness threshold. Frames scored in [redetect_threshold,
    # DETECTION_THRESHOLD) are refined (ir) and called detected where their estimate agrees with
    # the pose graph fused from the confident frames (position within redetect_gate of its range,
    # heading within REDETECT_HEADING_DEG of it or its opposite); the graph is then fused again
    # with them. Online, in one pass, frame k is judged by the graph of the frames before it that
    # joined (confident or re-detected), so the answer stays causal. None: off; without pgo there
    # is no graph to agree with and it is unused.
    redetect_threshold: float | None = 0.2
    redetect_gate: float = 0.1
    # batch pgo with ir and a segmenter: the graph's guided second look (`track`). Every valid frame
    # the detection left out, where the graph fused from the detected frames has an answer, is
    # refined again from that answer; it is called detected where the segmenter's mask and the
    # refined pose's silhouette agree at this IoU or more (`refine.RefineResult.mask_iou`: the robot
    # is where the refined pose puts it) and the refined pose agrees with the graph as a re-detected
    # frame must (redetect_gate); the graph is then fused again. None: off
    track_iou: float | None = None

    def __post_init__(self):
        parse_modules(",".join(self.modules))
        if not (self.range_window is None or self.range_window == "auto"
                or (isinstance(self.range_window, int) and self.range_window >= MIN_RANGE_WINDOW)):
            raise RhamlError(f"range_window {self.range_window!r}: expected None, 'auto' or a number of rows >= {MIN_RANGE_WINDOW}")
        if self.range_window_max_scale is not None and not 0.0 < self.range_window_max_scale <= pgo.MAX_LOG_SCALE:
            raise RhamlError(f"range_window_max_scale {self.range_window_max_scale!r}: expected None or a number in (0, {pgo.MAX_LOG_SCALE}]")
        if self.pgo_mode not in ("batch", "online"):
            raise RhamlError(f"pgo_mode {self.pgo_mode!r}: expected 'batch' or 'online'")
        if self.chunk < 1 or self.ir_chunk < 1:
            raise RhamlError(f"chunk {self.chunk}, ir_chunk {self.ir_chunk}: both must be positive")
        if self.redetect_threshold is not None:
            if not 0.0 < self.redetect_threshold < DETECTION_THRESHOLD:
                raise RhamlError(f"redetect_threshold {self.redetect_threshold}: must lie in (0, {DETECTION_THRESHOLD}), "
                                 "under the detection threshold")
            if not self.redetect_gate > 0.0:
                raise RhamlError(f"redetect_gate {self.redetect_gate}: must be positive (a fraction of the range)")
        if self.track_iou is not None:
            if not 0.0 < self.track_iou <= 1.0:
                raise RhamlError(f"track_iou {self.track_iou}: must lie in (0, 1] (an IoU) or be None")
            if not ("ir" in self.modules and "pgo" in self.modules and self.pgo_mode == "batch"):
                raise RhamlError(f"track_iou {self.track_iou}: the graph's second look needs modules ir and pgo with "
                                 f"pgo_mode 'batch' (got modules {','.join(self.modules)}, pgo_mode {self.pgo_mode!r})")

    @property
    def calibration_window(self) -> int | None:
        """`range_window` resolved: rows per transform of the range model (None: the whole sequence)."""
        if self.range_window == "auto":
            return RANGE_WINDOW_REFINED if "ir" in self.modules else None
        return self.range_window


@dataclasses.dataclass(frozen=True, eq=False)
class PipelineModel:
    """Static part: the stages' definitions and the config (hashed by identity: a jit static argument)."""

    iml: IMLModel
    config: PipelineConfig = PipelineConfig()
    refiner: object | None = None  # refine.RefineConfig (from refine.load_stage), needed when "ir" is in the modules


class PipelineParams(NamedTuple):
    iml: IMLParams
    refiner: object | None = None  # refine.StageParams from refine.load_stage, or None without IR


class Sequence(NamedTuple):
    """N frames of a rendezvous sequence (one image each, time order)."""

    images: jax.Array  # (N, H, W, 3) uint8 RGB
    K: jax.Array  # (N, 3, 3) intrinsics of each image
    odom_a: jax.Array  # (N, 3) robot A's odometry (x, y, psi) when the frame was taken
    odom_b: jax.Array  # (N, 3) robot B's odometry
    a_observes: jax.Array  # (N,) bool: the image is A's camera's (B observed); False: B's camera (A observed)
    valid: jax.Array  # (N,) bool: a real frame (False: padding to a static length)


class PipelineResult(NamedTuple):
    iml: Estimate  # (N,) IML's estimates
    ir: Estimate | None  # (N,) after refinement (None without "ir")
    detected: jax.Array  # (N,) bool: valid and o >= DETECTION_THRESHOLD, or re-detected (PipelineConfig.redetect_threshold),
    #                      or joined by the second look (PipelineConfig.track_iou)
    xypsi: jax.Array  # (N, 3) the pipeline's answer: the observed robot in the observer's frame
    fusion: pgo.FusionResult | None  # the pose graph's result (None without "pgo")
    range_model: jax.Array  # (2,) c of the observations' range error rho = r exp(c0 + c1 (r - 4.5 m)) (0: none)
    second_look: SecondLook | None = None  # the graph's second look (PipelineConfig.track_iou; None: off)


class SecondLook(NamedTuple):
    """The graph's second look (`PipelineConfig.track_iou`) over the N frames. `PipelineResult.detected`
    includes the frames it joined, and the pose graph fused their `xypsi`; `PipelineResult.ir` is
    IR's first pass, from IML's estimates."""

    tried: jax.Array  # (N,) bool: refined from the graph's answer (valid, not detected, the graph has an answer)
    estimate: Estimate  # (N,) IR's estimates from there where tried (and IR neither declined nor failed to
    #                     converge), else `PipelineResult.ir`'s
    mask_iou: jax.Array  # (N,) the segmenter's mask against the silhouette at the learned iterations' end
    #                      (refine.RefineResult.mask_iou; -1 where not tried)
    joined: jax.Array  # (N,) bool: called detected by it (`track`)


def _chunked(f, xs, chunk: int):
    """f over the leading axis of the pytree xs, `chunk` frames per call (lax.map). At 1 each call
    sees one unbatched frame: a `jax.lax.cond` in f then runs one branch (lax.map's batch_size,
    even 1, vmaps f, and a vmapped cond runs both)."""
    n = jax.tree.leaves(xs)[0].shape[0]
    return jax.lax.map(f, xs, batch_size=None if chunk == 1 else min(chunk, n))


def run(model: PipelineModel, params: PipelineParams, seq: Sequence) -> PipelineResult:
    cfg = model.config

    def one(frame):
        images, K = frame
        e = localize(model.iml, params.iml, images[None], K[None])
        return jax.tree.map(lambda a: a[0], e)

    est = _chunked(one, (seq.images, seq.K), cfg.chunk)
    detected = seq.valid & (est.o >= DETECTION_THRESHOLD)
    low = cfg.redetect_threshold if "pgo" in cfg.modules else None
    candidates = detected if low is None else seq.valid & (est.o >= low)
    current, ir, look = est, None, None
    if "ir" in cfg.modules:
        ir = _refine(model, params, seq, est, candidates)
        current = ir
    xypsi, fusion, c = current.xypsi, None, jnp.zeros((2,), current.xypsi.dtype)
    if "pgo" in cfg.modules:
        if low is None:
            fusion, c = fuse_estimates(cfg, current, detected, seq.odom_a, seq.odom_b, seq.a_observes)
        else:
            fusion, c, detected = redetect(cfg, current, detected, candidates, seq.odom_a, seq.odom_b, seq.a_observes)
        if cfg.track_iou is not None:
            if params.refiner.segmenter is None:
                raise RhamlError("track_iou: the graph's second look checks the refined pose against a segmenter's "
                                 "mask, and the IR stage has none (refine.load_stage gives the shipped one)")
            # where the graph has no answer there is nothing to look from
            want = seq.valid & ~detected & _batch_answers(fusion, detected)
            second = _refine_frames(model, params, seq, fusion.relative, want)
            joined = track(cfg, want, fusion.relative, second)
            look = SecondLook(want, _merge(ir, second, want),
                              jnp.where(want, second.mask_iou, -1.0), joined)
            detected = detected | joined
            fusion, c = fuse_estimates(cfg, look.estimate, detected, seq.odom_a, seq.odom_b, seq.a_observes)
        xypsi = fusion.relative
    return PipelineResult(est, ir, detected, xypsi, fusion, c, look)


def track(cfg: PipelineConfig, want, predicted, second):
    """`PipelineConfig.track_iou`'s verdict -> (N,) bool: of the frames `want` (N,) refined from the
    graph's answer `predicted` (N, 3) (`second`, a refine.RefineResult over the N frames), those that
    converged, whose segmenter's mask fits the refined pose (mask_iou >= cfg.track_iou: the robot
    is there) and whose pose agrees with the graph as a re-detected frame must."""
    return (want & ~second.declined & second.converged & (second.mask_iou >= cfg.track_iou)
            & agrees(second.xypsi, predicted, cfg.redetect_gate))


def _merge(est: Estimate, out, refined) -> Estimate:
    """The estimates `est` (N,) with IR's `out` (refine.RefineResult (N,)) on the frames `refined`
    (N,) where IR neither declined nor failed to converge."""
    keep = refined & ~out.declined & out.converged
    pick = lambda a, b: jnp.where(keep.reshape(keep.shape + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
    # the scorer's own flip probability replaces IML's (its heading is the scorer's); else the
    # alignment's margin over the other-facing hypothesis (0 when it did not run) lowers IML's doubt
    flip = jnp.where(out.flip_prob >= 0, out.flip_prob, est.flip_prob * (1.0 - out.flip_confidence))
    return Estimate(pick(out.xypsi, est.xypsi), est.o, pick(flip, est.flip_prob), pick(out.roll_pitch, est.roll_pitch))


def redetect(cfg: PipelineConfig, est: Estimate, detected, candidates, odom_a, odom_b, a_observes):
    """The two-threshold detection (`PipelineConfig.redetect_threshold`): the `candidates` (N,)
    among the frames not `detected` are called detected where their estimate agrees with the
    pose graph (`cfg.redetect_gate`, REDETECT_HEADING_DEG) -> (pgo.FusionResult, range model c
    (2,), detected (N,)). Batch: the graph fused from the `detected` frames, then fused again with
    the frames that agree. Online, in one pass (`pgo.fuse_online_redetect`): frame k is judged by
    the graph of the frames before it that joined, confident or re-detected."""
    if cfg.pgo_mode == "online":
        fusion, c, trusted, detected = _fuse(cfg, est, detected, odom_a, odom_b, a_observes, candidates)
        return _fall_back(fusion, trusted, est), c, detected
    fusion, _, trusted, _ = _fuse(cfg, est, detected, odom_a, odom_b, a_observes)
    # guard: where the graph has no answer (no confident rendezvous) a candidate is not judged
    # (the pipeline would answer its own estimate there)
    detected = detected | (trusted & candidates & agrees(est.xypsi, fusion.relative, cfg.redetect_gate))
    fusion, c = fuse_estimates(cfg, est, detected, odom_a, odom_b, a_observes)
    return fusion, c, detected


def agrees(xypsi, fused, gate: float, heading_deg: float = REDETECT_HEADING_DEG):
    """`pgo.agrees` with the pipeline's heading tolerance."""
    return pgo.agrees(xypsi, fused, gate, heading_deg)


def fuse_estimates(cfg: PipelineConfig, est: Estimate, detected, odom_a, odom_b, a_observes):
    """The pgo module on its own: per-frame estimates (N,) with both odometries (N, 3) ->
    (pgo.FusionResult, range model c (2,)); batch mode fuses, calibrates the range error
    and fuses again (`pgo.fuse_calibrated`), online mode fuses each frame from those before it.
    Where the graph has no answer the frame keeps its stage estimate."""
    fusion, c, trusted, _ = _fuse(cfg, est, detected, odom_a, odom_b, a_observes)
    return _fall_back(fusion, trusted, est), c


def _fall_back(fusion, trusted, est: Estimate):
    """The fusion with its rows where the graph has no answer (not `trusted`) set to the estimate."""
    return fusion._replace(relative=jnp.where(trusted[:, None], fusion.relative, est.xypsi))


def _fuse(cfg: PipelineConfig, est: Estimate, detected, odom_a, odom_b, a_observes, candidates=None):
    """`fuse_estimates` before it falls back: (fusion, c (2,), trusted (N,) bool, the rows where the
    graph's answer stands, detected (N,): online with `candidates`, also those that joined)."""
    obs = pgo.observation_from_xy_yaw_rp(est.xypsi, est.roll_pitch)
    rv = pgo.rendezvous_from_frames(odom_a, odom_b, obs, a_observes)
    c = jnp.zeros((2,), est.xypsi.dtype)
    if cfg.pgo_mode == "online":
        if candidates is None:
            fusion = pgo.fuse_online(rv, cfg.fusion, valid=detected, flip_prob=est.flip_prob)
        else:
            fusion, joined = pgo.fuse_online_redetect(rv, cfg.fusion, detected, candidates, cfg.redetect_gate,
                                                      REDETECT_HEADING_DEG, flip_prob=est.flip_prob)
            detected = detected | joined
        # guard: frame k has no answer before a rendezvous at or before it, nor where the
        # one-rendezvous graph of the first rows comes out non-finite (seen on row 0 of the
        # circle under one XLA compilation, not in another: an open numerical issue of fuse_online)
        return fusion, c, (jnp.cumsum(detected) > 0) & jnp.all(jnp.isfinite(fusion.relative), -1), detected
    if cfg.calibrate_range:
        fusion, c = pgo.fuse_calibrated(rv, cfg.fusion, valid=detected, flip_prob=est.flip_prob, window=cfg.calibration_window,
                                        window_max_scale=cfg.range_window_max_scale)
    else:
        fusion = pgo.fuse(rv, cfg.fusion, valid=detected, flip_prob=est.flip_prob)
    return fusion, c, _batch_answers(fusion, detected), detected


def _batch_answers(fusion, detected):
    """(N,) bool: the rows where a batch fusion of the `detected` frames has an answer."""
    # guard: a sequence without one usable rendezvous leaves the transform between the odometry
    # frames undetermined (the fusion answers NaN): then no row has an answer
    return jnp.broadcast_to(jnp.any(fusion.inlier & detected), detected.shape)


def _refine(model: PipelineModel, params: PipelineParams, seq: Sequence, est: Estimate, detected) -> Estimate:
    """IR on every frame (`refine.refine`: the learned iterations, re-rendering between them);
    frames not `detected` (here: the candidates for re-detection too), or where the refiner declines
    (the estimate behind the camera or outside the image) or does not converge
    (`RefineConfig.max_final_step`), keep IML's estimate."""
    if model.refiner is None or params.refiner is None:
        raise RhamlError("modules include ir but the pipeline has no refiner (refine.load_stage gives one)")
    out = _refine_frames(model, params, seq, est.xypsi, detected)
    return _merge(est, out, detected)


def _refine_frames(model: PipelineModel, params: PipelineParams, seq: Sequence, start, which):
    """refine.RefineResult (N,) of IR from the planar poses `start` (N, 3) on the frames `which`
    (N,) bool, one frame at a time (`PipelineConfig.ir_chunk`); the others are not refined
    (declined, their start returned)."""
    from rhaml_jax import refine

    def one(frame):
        image, K, xypsi, candidate = frame

        def run(image, K, xypsi):
            return refine.refine_stage(model.refiner, params.refiner, image, K, xypsi)

        def skip(image, K, xypsi):  # not a candidate: IML's estimate stays (declined), nothing rendered
            out = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(run, image, K, xypsi))
            return out._replace(xypsi=xypsi, declined=jnp.bool_(True))

        return jax.lax.cond(candidate, run, skip, image, K, xypsi)

    return _chunked(one, (seq.images, seq.K, start, which), model.config.ir_chunk)


run_jit = jax.jit(run, static_argnums=0)


def shard_sequences(seqs: Sequence, devices=None) -> Sequence:
    """Places a batch of sequences (leading axis S, as `jax.vmap(run, ...)` takes them) across
    devices along S (S must be a multiple of the device count); run the vmapped pipeline on the
    result and XLA keeps each device's sequences on it."""
    devices = jax.devices() if devices is None else devices
    S = jax.tree.leaves(seqs)[0].shape[0]
    if S % len(devices):
        raise RhamlError(f"{S} sequences cannot be split evenly over {len(devices)} devices")
    mesh = jax.sharding.Mesh(devices, ("seq",))
    spec = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("seq"))
    return jax.device_put(seqs, spec)
