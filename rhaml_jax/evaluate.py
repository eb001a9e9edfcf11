"""`python -m rhaml_jax.evaluate`: runs the pipeline's modules on a BOP data set and prints the
paper's metrics (DESIGN.md section 5).

  python -m rhaml_jax.evaluate --data DIR [--scene ID] [--split S] --modules iml --json OUT [--amlnet CKPT]
      [--zoom CKPT | --no-zoom] [--zoom-mirror]

Prints one JSON line: mean and std of |dx|, |dy| (cm), |dpsi| (deg) and the ATE (eq. 12) over
the frames with the robot in view, frames per second, and the detection counts over all frames
(threshold 0.5 on o); `--json` also writes the per-frame estimates. Every image goes through
`rhaml_jax.data.network_image` (the network's camera) first, so data sets of other tools and
other image sizes work. This build runs the `iml` module: AMLNet, then (by default) its zoom-in
stage on a crop of the full-resolution image around AMLNet's estimate (`rhaml_jax.amlnet.zoom`);
`ir` (refinement) and `pgo` (pose-graph fusion) come with the pipeline.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro

from rhaml_jax.allocator import tune_allocator
from rhaml_jax.errors import RhamlError, run_cli

__all__ = ["Args", "evaluate_iml", "main"]

MODULES = ("iml", "ir", "pgo")


@dataclass(frozen=True)
class Args:
    data: Path
    """BOP data set folder (ours or another tool's)"""
    modules: str = "iml"
    """comma-separated pipeline modules: iml (AMLNet), ir (refinement), pgo (pose graph)"""
    scene: int | None = None
    """evaluate only this scene id (default: every scene of every split)"""
    split: str | None = None
    """evaluate only this split (e.g. val, test)"""
    json: Path | None = None
    """write metrics and per-frame estimates here"""
    amlnet: Path | None = None
    """AMLNet checkpoint folder (default: the shipped amlnet_cpu)"""
    zoom: Path | None = None
    """AMLNet's zoom-in stage checkpoint folder (default: the shipped zoom_cpu with the shipped AMLNet)"""
    no_zoom: bool = False
    """report AMLNet alone, without its zoom-in stage"""
    zoom_mirror: bool = False
    """also run the zoom-in stage on each crop mirrored left-right and average the two answers
    (`zoom.mirror_average`); only for a left-right symmetric robot, as the built-in one is"""
    refiner: Path | None = None
    """refiner checkpoint folder (the ir module)"""
    batch: int = 32
    """images per network call"""


def evaluate_iml(frames, net, params, stats, batch: int = 32, zoom=None,
                 zoom_mirror: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """AMLNet on BOP frames, then its zoom-in stage if `zoom` = (net, params, batch_stats) is
    given (with `zoom_mirror`, also on the mirrored crops, see `zoom.mirror_average`):
    (estimates (N, 3) x, y, psi; o probabilities (N,); seconds per frame)."""
    import jax

    from rhaml_jax.amlnet import decode
    from rhaml_jax.amlnet.zoom import apply_correction, mirror_average, zoom_crop
    from rhaml_jax.data import load_rgb, network_image

    h, w = net.cfg.input_hw
    predict = jax.jit(lambda p, s, x: decode(net.apply(p, s, x), net.cfg.angle_head))
    if zoom is not None:
        znet, zparams, zstats = zoom
        zpredict = jax.jit(lambda p, s, x: decode(znet.apply(p, s, x), znet.cfg.angle_head))
    est, prob = [], []
    seconds = 0.0

    def pad(x):  # one shape for every call
        return np.concatenate([x, np.zeros((batch - len(x),) + x.shape[1:], x.dtype)])

    for i in range(0, len(frames), batch):
        chunk = frames[i : i + batch]
        full = [load_rgb(f.rgb) for f in chunk]
        t = time.perf_counter()
        imgs = np.stack([network_image(im, f.K, (h, w)) for im, f in zip(full, chunk)]).astype(np.float32) / 255.0
        out = jax.device_get(predict(params, stats, pad(imgs)))
        e = np.stack([out["x"], out["y"], out["psi"]], 1)[: len(chunk)]
        if zoom is not None:
            crops = np.stack([zoom_crop(im, f.K, g[:2], znet.cfg) for im, f, g in zip(full, chunk, e)])
            crops = crops.astype(np.float32) / 255.0

            def correct(c):
                z = jax.device_get(zpredict(zparams, zstats, pad(c)))
                return np.stack([z["x"], z["y"], z["psi"]], 1)[: len(chunk)]

            corr = correct(crops)
            if zoom_mirror:
                corr = mirror_average(corr, correct(np.ascontiguousarray(crops[:, :, ::-1])))
            e = apply_correction(e[:, :2], corr)
        if i:  # the first call compiles
            seconds += time.perf_counter() - t
        est.append(e)
        prob.append(out["o"][: len(chunk)])
    n_timed = max(len(frames) - min(batch, len(frames)), 0)
    return np.concatenate(est), np.concatenate(prob), (seconds / n_timed if n_timed else float("nan"))


MAX_MIRROR_SHAPE = 0.02  # of the robot's length
MAX_MIRROR_COLOUR = 0.05  # of its surface


def check_mirror_symmetric(data: Path) -> None:
    """`--zoom-mirror` averages the pose seen in a crop and in its mirror image: right only for
    a left-right symmetric robot. Checks the data set's BOP model (RobotModel.mirror_asymmetry)."""
    import sys

    from rhaml_jax.data import load_bop_model
    from rhaml_jax.data._bop import MODEL_FILE, OBJ_ID

    path = Path(data) / "models" / MODEL_FILE.format(OBJ_ID)
    if not path.exists():
        print(f"rhaml_jax.evaluate: warning: {path} not found: cannot check that the robot is left-right "
              "symmetric, which --zoom-mirror assumes", file=sys.stderr)
        return
    model = load_bop_model(data)
    shape, colour = model.mirror_asymmetry()
    length = float(model.extents.max())
    if shape > MAX_MIRROR_SHAPE * length or colour > MAX_MIRROR_COLOUR:
        raise RhamlError(f"--zoom-mirror: the robot model {path} is not left-right symmetric (its mirror image is "
                         f"{100 * shape:.1f} cm off, {100 * colour:.0f} % of its surface another colour; limits "
                         f"{100 * MAX_MIRROR_SHAPE:.0f} % of its {100 * length:.0f} cm length and "
                         f"{100 * MAX_MIRROR_COLOUR:.0f} %): mirrored crops would show another robot")


def run(args: Args) -> dict:
    from rhaml_jax import metrics
    from rhaml_jax.amlnet import load_model, shipped_checkpoint
    from rhaml_jax.data import read_bop

    modules = [m for m in args.modules.split(",") if m]
    unknown = [m for m in modules if m not in MODULES]
    if unknown or not modules:
        raise RhamlError(f"--modules {args.modules}: expected a comma-separated subset of {', '.join(MODULES)}")
    if modules != ["iml"]:
        raise RhamlError(f"--modules {args.modules}: this build evaluates iml alone; ir and pgo come with the pipeline")
    if args.batch < 1:
        raise RhamlError(f"--batch {args.batch}: must be positive")
    frames = read_bop(args.data, args.split, args.scene)
    net, params, stats = load_model(args.amlnet or shipped_checkpoint("amlnet_cpu"))
    zoom_dir = args.zoom
    if zoom_dir is None and args.amlnet is None and not args.no_zoom:
        zoom_dir = shipped_checkpoint("zoom_cpu")  # the shipped AMLNet's own zoom stage
    zoom = None if args.no_zoom or zoom_dir is None else load_model(zoom_dir)
    if zoom is not None and zoom[0].cfg.task != "zoom":
        raise RhamlError(f"--zoom {zoom_dir}: holds a {zoom[0].cfg.name} network, not a zoom-in stage")
    if args.zoom_mirror:
        if zoom is None:
            raise RhamlError("--zoom-mirror: there is no zoom-in stage to mirror (--no-zoom, or --amlnet without --zoom)")
        check_mirror_symmetric(args.data)
    est, prob, s_per_frame = evaluate_iml(frames, net, params, stats, args.batch, zoom, args.zoom_mirror)
    observed = np.array([f.observed for f in frames])
    gt = np.array([f.xypsi if f.observed else np.zeros(3) for f in frames])
    det = prob >= 0.5
    if observed.any():
        s = metrics.summarize(est[observed], gt[observed])
        pose = {k: s[k] for k in ("dx_cm", "dy_cm", "dpsi_deg", "ate")}
    else:
        pose = {"dx_cm": None, "dy_cm": None, "dpsi_deg": None, "ate": None}
    m = pose | {
        "fps": 1.0 / s_per_frame if s_per_frame > 0 else None,
        "detection": {"tp": int((det & observed).sum()), "fp": int((det & ~observed).sum()),
                      "fn": int((~det & observed).sum()), "tn": int((~det & ~observed).sum())},
        "detection_accuracy": float((det == observed).mean()),
        "frames": len(frames), "observed_frames": int(observed.sum()), "modules": modules,
        "zoom": zoom is not None, "zoom_mirror": args.zoom_mirror,
    }
    per_frame = [{"scene_id": f.scene_id, "im_id": f.im_id, "observed": bool(f.observed),
                  "est": [float(v) for v in e] if d else None, "gt": [float(v) for v in g] if f.observed else None}
                 for f, e, d, g in zip(frames, est, det, gt)]
    return {"metrics": m, "frames": per_frame}


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    tune_allocator()  # before JAX starts its threads; see rhaml_jax.allocator
    res = run(args)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res))
    print(json.dumps(res["metrics"]))
    return res


if __name__ == "__main__":
    run_cli(main)
