"""`python -m rhaml_jax.evaluate`: runs the pipeline's modules on a BOP data set and prints the
paper's metrics (DESIGN.md section 5).

  python -m rhaml_jax.evaluate --data DIR [--scene ID] [--split S] --modules iml[,ir][,pgo] --json OUT
      [--amlnet CKPT] [--zoom CKPT | --no-zoom] [--zoom-mirror] [--refiner CKPT] [--fine-refiner CKPT] [--segmenter CKPT] [--scorer CKPT] [--pgo-mode batch|online]
      [--paper-information]

Each scene is one rendezvous sequence (`rhaml_jax.sequence.load_scene`: its images and, for
pgo, its TUM odometry) and goes through the jitted pipeline (`rhaml_jax.pipeline.run`). Prints a
table and one JSON line: mean and std of |dx|, |dy| (cm), |dpsi| (deg) and the ATE (eq. 12) over
the frames with the robot in view, frames per second of the compiled pipeline, and the detection
counts over all frames (o >= metrics.DETECTION_THRESHOLD); `--json` also writes the per-frame
estimates. Images of any size and intrinsics are resampled into the networks' camera inside the
pipeline, so data sets of other tools work.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from rhaml_jax.allocator import tune_allocator
from rhaml_jax.errors import RhamlError, run_cli

__all__ = ["Args", "frame_rows", "main", "run", "score"]


@dataclass(frozen=True)
class Args:
    data: Path
    """BOP data set folder (ours or another tool's)"""
    modules: str = "iml"
    """comma-separated pipeline modules: iml (AMLNet + zoom stage), ir (refinement), pgo (pose graph)"""
    scene: int | None = None
    """evaluate only this scene id (default: every scene of every split)"""
    split: str | None = None
    """evaluate only this split (e.g. val, test)"""
    json: Path | None = None
    """write metrics and per-frame estimates here"""
    amlnet: Path | None = None
    """AMLNet checkpoint folder (default: the shipped heat_nocart_cpu, `iml.DEFAULT_AMLNET`)"""
    zoom: Path | None = None
    """AMLNet's zoom-in stage checkpoint folder (default: the shipped zoom_fit_cpu with the shipped AMLNet)"""
    no_zoom: bool = False
    """report AMLNet alone, without its zoom-in stage"""
    zoom_mirror: bool = False
    """also run the zoom-in stage on each crop mirrored left-right and average the two answers
    (`zoom.mirror_average`); only for a left-right symmetric robot, as the built-in one is"""
    amlnet_mirror: bool = False
    """also run a heatmap AMLNet on each image mirrored left-right and average the two maps
    (`iml.mirror_heatmap`); only for a left-right symmetric robot, as the built-in one is"""
    white_balance: bool = False
    """IML sees each image grey-world balanced (`colour.grey_world`): a global tint of the light undone"""
    refiner: Path | None = None
    """refiner checkpoint folder (the ir module; default: the shipped `refine.DEFAULT_REFINER`)"""
    segmenter: Path | None = None
    """segmenter checkpoint folder (`train --stage segmenter`; the ir module: after the learned
    iterations, the silhouette alignment to its masks of the image, `refine.SEGMENTER_ALIGN`, then
    `RefineConfig.fine_after_align` fine iterations; "none": without; default: the shipped
    `refine.DEFAULT_SEGMENTER` when --refiner is not given, else none)"""
    fine_after_align: int | None = None
    """with a segmenter (the default one too): the fine refiner's iterations after the alignment (`RefineConfig.fine_after_align`; None: its default)"""
    mask_threshold: float | None = None
    """with a segmenter: its mask is thresholded here (`RefineConfig.mask_threshold`; None: its default)"""
    align_gates: bool = True
    """with a segmenter: keep the alignment's result only where it turns the heading and stays near
    (`refine.SEGMENTER_ALIGN`'s `min_turn` and `max_shift`), and skip it where the start already
    fits the mask (its `skip_iou`); --no-align-gates: it always runs and stands"""
    scorer: Path | None = None
    """heading scorer checkpoint folder (`train --stage scorer`; the ir module: after the learned
    iterations, the best of rendered heading hypotheses, flips included; "none": without; default: the
    shipped `refine.DEFAULT_SCORER` at `refine.DEFAULT_FLIP_THRESHOLD` when --refiner is not given, else none)"""
    flip_threshold: float | None = None
    """with --scorer: the scorer's probability of the other side needed to turn the heading
    (`RefineConfig.flip_threshold`; None: its default)"""
    scorer_mirror: bool = False
    """with --scorer: it also reads its input mirrored left-right and averages the two reads
    (`RefineConfig.scorer_mirror`); only for a left-right symmetric robot"""
    post_iter: int | None = None
    """with --scorer: learned iterations of the refiner after the heading search (`RefineConfig.post_iter`; None: its default)"""
    fine_refiner: tuple[Path, ...] | None = None
    """a cascade's fine refiner checkpoint folder (`train --stage refiner --config refiner_fine_cpu`;
    the ir module: `RefineConfig.fine_iter` iterations of it after the refiner's; several folders: an
    ensemble, their updates averaged; "none": without; default: the shipped `refine.DEFAULT_FINE_REFINERS`
    when --refiner is not given, else none)"""
    fine_iter: int | None = None
    """the ir module's iterations of the fine refiner (`RefineConfig.fine_iter`; None: its default)"""
    refine_mirror: Literal["none", "fine", "all"] | None = None
    """the ir module's test-time mirroring (`RefineConfig.mirror`: which learned iterations also read
    their crops mirrored left-right; None: `refine.DEFAULT_MIRROR` for a symmetric robot)"""
    max_final_step: float | None = 0.01
    """the ir module's convergence check (`RefineConfig.max_final_step`): where the refiner's last
    coarse iteration moves the range by more than this fraction, IML's estimate stands; None: off"""
    pgo_mode: Literal["batch", "online"] = "batch"
    """pgo: fuse the whole sequence (batch, as the paper evaluates) or each frame from the frames before it (online)"""
    paper_information: bool = False
    """pgo: the paper's constant information (kappa = 100, eqs. 9-10) instead of the odometry noise model"""
    redetect_threshold: float | None = 0.2
    """pgo: a second objectness threshold under 0.5; frames scored between the two are refined
    and called detected where their estimate agrees with the pose graph of the confident frames
    (online: the frames before it that joined; `PipelineConfig.redetect_threshold`); None: off"""
    track_iou: float | None = None
    """pgo (batch) with ir and a segmenter: the graph's second look (`PipelineConfig.track_iou`): frames
    not detected are refined from the graph's answer and join where the segmenter's mask and the
    refined silhouette agree at this IoU or more; None: off"""
    no_range_calibration: bool = False
    """pgo (batch): fuse the observations as they are, without calibrating their range error from
    odometry (`pgo.fuse_calibrated`) and fusing again"""
    range_window: int | None | Literal["auto"] = "auto"
    """pgo (batch): rows per transform of the range calibration (`PipelineConfig.range_window`;
    auto: 200 for refined estimates, the whole sequence for IML's; None: the whole sequence)"""
    range_window_max_scale: float | None = 0.02
    """pgo (batch), with a range window: the window only where the whole sequence's calibration finds
    the range off by less than this (`PipelineConfig.range_window_max_scale`); None: always"""
    batch: int = 32
    """frames per network call"""
    ir_batch: int = 1
    """frames per IR call (`PipelineConfig.ir_chunk`: at 1 a frame skips the work it does not need)"""
    allow_other_robot: bool = False
    """run networks made for another robot than the data set's (a deliberate transfer test; by
    default that is refused, comparing the robot fingerprints the checkpoints store)"""
    raw_flip_ranking: bool = False
    """IML's flip_prob as the zoom stage's raw front/back ranking, ignoring the zoom checkpoint's
    calibration (what `calibrate_flips` fits on)"""


def _table(m: dict) -> str:
    f = lambda v: "-" if v is None else f"{v[0]:.1f} +- {v[1]:.1f}"  # noqa: E731
    d = m["detection"]
    ate = "-" if m["ate"] is None else f"{m['ate']:.3f}"
    fps = "-" if m["fps"] is None else f"{m['fps']:.1f}"
    return (f"{'+'.join(x.upper() for x in m['modules']):<12} abs dx {f(m['dx_cm'])} cm   abs dy {f(m['dy_cm'])} cm   "
            f"abs dpsi {f(m['dpsi_deg'])} deg   ATE {ate}   {fps} FPS   "
            f"detection tp {d['tp']} fp {d['fp']} fn {d['fn']} tn {d['tn']} ({m['frames']} frames)")


def score(est: np.ndarray, called: np.ndarray, observed: np.ndarray, gt: np.ndarray) -> dict:
    """The paper's metrics of per-frame estimates (N, 3) (scored where `observed`, whatever
    the detection) and the detection counts of `called` against `observed`."""
    from rhaml_jax import metrics

    if observed.any():
        s = metrics.summarize(est[observed], gt[observed])
        pose = {k: s[k] for k in ("dx_cm", "dy_cm", "dpsi_deg", "ate")}
    else:
        pose = {"dx_cm": None, "dy_cm": None, "dpsi_deg": None, "ate": None}
    counts = metrics.detection_counts(called.astype(float), observed)
    return pose | {"detection": counts, "detection_accuracy": float((called == observed).mean()),
                   "frames": len(observed), "observed_frames": int(observed.sum())}


def _data_robot(args: Args):
    """The data set's robot model (models/obj_000001.ply), or None (with a warning) without one;
    --zoom-mirror is refused for a robot that is not left-right symmetric."""
    from rhaml_jax.data import bop_model_path, load_bop_model

    path = bop_model_path(args.data)
    if not path.exists():
        print(f"rhaml_jax.evaluate: warning: {path} not found: cannot check the data set's robot "
              "(its size, its symmetry for --zoom-mirror)", file=sys.stderr)
        return None, path
    model = load_bop_model(args.data)
    if args.zoom_mirror or args.amlnet_mirror:
        from rhaml_jax.iml import check_mirror_symmetric

        check_mirror_symmetric(model, path, "--zoom-mirror" if args.zoom_mirror else "--amlnet-mirror")
    return model, path


def _load(args: Args, modules):
    from rhaml_jax import iml, pgo, pipeline

    robot, path = _data_robot(args)
    check = None if args.allow_other_robot else robot
    iml_model, iml_params = iml.load_iml(args.amlnet, args.zoom, args.no_zoom, args.zoom_mirror, check, str(path),
                                         calibrated=not args.raw_flip_ranking, white_balance=args.white_balance,
                                         amlnet_mirror=args.amlnet_mirror)
    refiner = refiner_params = None
    if "ir" in modules:
        from rhaml_jax import refine

        refiner, refiner_params = refine.load_stage(args.refiner, args.data, check_robot=not args.allow_other_robot,
                                                    segmenter=args.segmenter, scorer=args.scorer, fine=args.fine_refiner,
                                                    mirror=args.refine_mirror)
        given = {k: v for k, v in (("fine_iter", args.fine_iter), ("flip_threshold", args.flip_threshold),
                                   ("post_iter", args.post_iter), ("fine_after_align", args.fine_after_align),
                                   ("mask_threshold", args.mask_threshold)) if v is not None}
        if args.scorer_mirror:
            iml.check_mirror_symmetric(robot, path, "--scorer-mirror")
            given["scorer_mirror"] = True
        if not args.align_gates and refiner.align is not None:
            given["align"] = dataclasses.replace(refiner.align, min_turn=0.0, max_shift=None, skip_iou=None)
        refiner = dataclasses.replace(refiner, max_final_step=args.max_final_step, **given)
    fusion = pgo.FusionConfig(information="paper" if args.paper_information else "noise_model")
    cfg = pipeline.PipelineConfig(modules=modules, pgo_mode=args.pgo_mode, fusion=fusion, chunk=args.batch,
                                  ir_chunk=args.ir_batch,
                                  calibrate_range=not args.no_range_calibration, range_window=args.range_window,
                                  range_window_max_scale=args.range_window_max_scale, redetect_threshold=args.redetect_threshold,
                                  track_iou=args.track_iou)
    return (pipeline.PipelineModel(iml_model, cfg, refiner), pipeline.PipelineParams(iml_params, refiner_params))


def run(args: Args) -> dict:
    from rhaml_jax import pipeline
    from rhaml_jax.data import read_bop
    from rhaml_jax.sequence import group_scenes, run_scenes

    modules = pipeline.parse_modules(args.modules)
    if args.batch < 1 or args.ir_batch < 1:
        raise RhamlError(f"--batch {args.batch}, --ir-batch {args.ir_batch}: both must be positive")
    frames = read_bop(args.data, args.split, args.scene)
    model, params = _load(args, modules)
    runs, compile_s, seconds = run_scenes(model, params, list(group_scenes(frames).values()))
    m = score(np.concatenate([r.result.xypsi for r in runs]), np.concatenate([r.result.detected for r in runs]),
              np.concatenate([r.data.observed for r in runs]), np.concatenate([r.data.gt for r in runs]))
    m |= {"fps": len(frames) / seconds if seconds > 0 else None, "compile_seconds": round(compile_s, 2),
          "modules": list(modules), "zoom": model.iml.zoom is not None, "zoom_mirror": args.zoom_mirror,
          "white_balance": args.white_balance, "amlnet_mirror": args.amlnet_mirror,
          "scenes": len(runs)}
    rows = [row for r in runs for row in frame_rows(r, "pgo" in modules)]
    from rhaml_jax.metrics import flipped, flips_by_view

    seen = [r for r in rows if r["observed"] and r["detected"]]  # IML's flips: where, and how well flip_prob predicts them
    m["iml_flips_by_view"] = flips_by_view([r["iml_est"][2] for r in seen], [r["gt"] for r in seen])
    if model.iml.zoom is not None:  # (zoom.calibration_metrics)
        from rhaml_jax.zoom import calibration_metrics

        m["iml_flip"] = calibration_metrics([r["iml_flip_prob"] for r in seen],
                                            flipped([r["iml_est"][2] for r in seen], [r["gt"][2] for r in seen]))
        m["iml_flip"]["calibrated"] = model.iml.flip_calibration is not None
    if "ir" in modules:  # detected frames where IR's estimate stands (else it declined or did not converge)
        m["ir_applied"] = int(sum(r["ir_applied"] for r in rows if r["detected"]))
    if "pgo" in modules:
        m |= {"pgo_mode": args.pgo_mode, "redetect_threshold": args.redetect_threshold, "track_iou": args.track_iou,
              "information": "paper" if args.paper_information else "noise_model",
              "range_calibration": not args.no_range_calibration, "range_window": args.range_window,
              "range_window_max_scale": args.range_window_max_scale,
              "pgo_rejected": int(sum(r["detected"] and not r["pgo_inlier"] for r in rows)),
              "range_model": [[float(v) for v in r.result.range_model] for r in runs]}
    return {"metrics": m, "frames": rows}


def frame_rows(run, fused: bool) -> list[dict]:
    """Per-frame JSON rows of one scene (DESIGN.md section 5, plus o, detected, IML's estimate
    and flip probability, with ir the refined estimate, its roll and pitch (rad) and flip probability
    and whether it was applied (False where the refiner declined or did not converge, or nothing was
    detected: IML's estimate stands), with pgo, whether the pose graph kept the observation and turned it by 180 deg, and
    where the graph's second look tried the frame (`--track-iou`), its estimate, flip probability and mask IoU and
    whether it joined; `detected` includes the frames it joined)."""
    res, data = run.result, run.data
    rows = []
    for i, f in enumerate(data.frames):
        shown = fused or res.detected[i]  # the pose graph places the robot at every frame
        row = {"scene_id": f.scene_id, "im_id": f.im_id, "observed": bool(f.observed),
               "est": [float(v) for v in res.xypsi[i]] if shown else None,
               "gt": [float(v) for v in data.gt[i]] if f.observed else None,
               "o": float(res.iml.o[i]), "detected": bool(res.detected[i]),
               "iml_est": [float(v) for v in res.iml.xypsi[i]], "iml_flip_prob": float(res.iml.flip_prob[i])}
        if res.ir is not None:
            row |= {"ir_est": [float(v) for v in res.ir.xypsi[i]], "ir_roll_pitch": [float(v) for v in res.ir.roll_pitch[i]],
                    "ir_flip_prob": float(res.ir.flip_prob[i]),
                    "ir_applied": bool(np.any(np.asarray(res.ir.xypsi[i]) != np.asarray(res.iml.xypsi[i])))}
        if res.fusion is not None:
            row |= {"pgo_inlier": bool(res.fusion.inlier[i]), "pgo_flipped": bool(res.fusion.flipped[i])}
        look = res.second_look
        if look is not None and look.tried[i]:  # the graph's second look (`--track-iou`)
            row["second_look"] = {"est": [float(v) for v in look.estimate.xypsi[i]], "flip_prob": float(look.estimate.flip_prob[i]),
                                  "mask_iou": float(look.mask_iou[i]), "joined": bool(look.joined[i])}
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    tune_allocator()  # before JAX starts its threads; see rhaml_jax.allocator
    res = run(args)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res))
    print(_table(res["metrics"]), file=sys.stderr)
    print(json.dumps(res["metrics"]))
    return res


if __name__ == "__main__":
    run_cli(main)
