"""The four module combinations' figures from stored per-frame estimates (no network runs here).

  python experiments/pipeline_from_json.py --set LABEL EVAL.json DATA [EVAL.json DATA ...] [--set ...]
      [--thresholds 0.5 0.4 0.3] [--metric KEY JSON ...] [--out OUT.json]

Each EVAL.json is an `evaluate --modules iml,ir,pgo --json` run on the BOP scene DATA (or
`--modules iml`: then the IML and IML+PGO rows only). Per set (its
scenes pooled): IML and IML+IR from the stored `iml_est` / `ir_est`, IML+PGO and IML+IR+PGO refitted
through the pipeline's own fusion (`pipeline.fuse_estimates`, batch or online as the run's was): mean abs
dx / dy (cm) over the detected frames, median abs dpsi (deg), ATE (as `evaluate` scores it), flips
(> 90 deg) and detected of observed frames, median est/true range. With --thresholds, IML+PGO
again with a frame called detected at o >= t (the pipeline's threshold is 0.5). Also how well the
stored IML flip probability predicts IML's flips over the detected frames (`zoom.calibration_metrics`:
Brier score, calibration error, ROC area), one line per set. `--metric KEY JSON` refits the pose-graph
rows with the runs' stored metric KEY set to that value (e.g. `--metric range_window null`: one
range-model transform for the whole sequence, `PipelineConfig.range_window`; `--metric
range_window_max_scale 0.02`; `--metric track_iou 0.7`: of the frames the graph's second look joined,
only those whose mask IoU reaches 0.7). The second look (`evaluate --track-iou`) is part of
IML+IR+PGO only: the other rows count the frames it joined as not detected, as their pipelines would.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import pgo, pipeline
from rhaml_jax.data import read_bop
from rhaml_jax.evaluate import score
from rhaml_jax.iml import Estimate
from rhaml_jax.metrics import flipped
from rhaml_jax.sequence import group_scenes, load_scene
from rhaml_jax.zoom import calibration_metrics

FUSE = jax.jit(pipeline.fuse_estimates, static_argnums=0)


def pgo_config(metrics: dict | None, refined: bool = False) -> pipeline.PipelineConfig:
    """The pose graph an evaluate run used on IML's (or, `refined`, IR's) estimates, from its stored
    metrics (an `--modules iml` run, or a run older than these fields: batch fusion with range
    calibration, one range-model transform for the whole sequence)."""
    m = metrics or {}
    return pipeline.PipelineConfig(modules=("iml", "ir", "pgo") if refined else ("iml", "pgo"),
                                   pgo_mode=m.get("pgo_mode", "batch"),
                                   fusion=pgo.FusionConfig(information=m.get("information", "noise_model")),
                                   calibrate_range=m.get("range_calibration", True), range_window=m.get("range_window"),
                                   range_window_max_scale=m.get("range_window_max_scale"))


def second_look(rows: list[dict], metrics: dict | None = None) -> np.ndarray:
    """(N,) bool: the frames the graph's second look joined (`evaluate --track-iou`; none without
    it). With `metrics` "track_iou" above the run's own, only those whose mask IoU reaches it: the
    run of a stricter threshold, constructed."""
    t = (metrics or {}).get("track_iou") or 0.0
    return np.array([bool(r.get("second_look", {}).get("joined")) and r["second_look"]["mask_iou"] >= t for r in rows])


def detections(rows: list[dict], metrics: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(detected without the second look, detected with it) (N,) bool: the IML, IML+PGO and IML+IR
    rows are pipelines without it (it needs IR and the pose graph); IML+IR+PGO's is the second."""
    det, joined = np.array([r["detected"] for r in rows]), second_look(rows, metrics)
    first = det & ~np.array([bool(r.get("second_look", {}).get("joined")) for r in rows])
    return first, first | joined


def fused(rows: list[dict], scene, key: str, detected: np.ndarray, metrics: dict | None = None) -> np.ndarray:
    """The pipeline's fused estimates (N, 3) of the stored `key` estimates (`pipeline.fuse_estimates`
    as the run's `metrics` say it fused, planar observations as the stored rows give them; for
    "ir_est", the second look's where it joined)."""
    seq = scene.seq
    joined = second_look(rows, metrics) if key == "ir_est" else np.zeros(len(rows), bool)
    xypsi = jnp.asarray([r["second_look"]["est"] if j else r[key] for r, j in zip(rows, joined)], jnp.float32)
    flip = jnp.asarray([r["second_look"]["flip_prob"] if j else r["ir_flip_prob" if key == "ir_est" else "iml_flip_prob"]
                        for r, j in zip(rows, joined)], jnp.float32)
    n = len(rows)
    est = Estimate(xypsi=xypsi, o=jnp.ones(n, jnp.float32), flip_prob=flip, roll_pitch=jnp.zeros((n, 2), jnp.float32))
    fusion, _ = FUSE(pgo_config(metrics, key == "ir_est"), est, jnp.asarray(detected), seq.odom_a, seq.odom_b, seq.a_observes)
    return np.asarray(fusion.relative)


def summary(parts) -> dict:
    est, det, obs, gt = (np.concatenate([q[i] for q in parts]) for i in range(4))
    m, k = score(est, det, obs, gt), det & obs
    dpsi = np.degrees(np.abs((est[k, 2] - gt[k, 2] + np.pi) % (2 * np.pi) - np.pi))
    ratio = np.hypot(*est[k, :2].T) / np.hypot(*gt[k, :2].T)
    return {"dx_cm": m["dx_cm"][0], "dy_cm": m["dy_cm"][0], "median_dpsi_deg": float(np.median(dpsi)) if k.any() else None,
            "ate": m["ate"], "flips": int(np.sum(flipped(est[k, 2], gt[k, 2]))), "detected": int(k.sum()),
            "observed": int(obs.sum()), "median_range_ratio": float(np.median(ratio)) if k.any() else None}


def metric_overrides(ap: argparse.ArgumentParser, flag: str, pairs: list[list[str]]) -> dict:
    """`flag KEY JSON` pairs -> {KEY: value} (stored metrics to override: `pgo_config` and
    `second_look` read them); an unknown key or a value that is not JSON ends the script with one line."""
    known = ("pgo_mode", "information", "range_calibration", "range_window", "range_window_max_scale", "track_iou")
    out = {}
    for key, value in pairs:
        if key not in known:
            ap.error(f"{flag} {key}: not a pose-graph metric (one of {', '.join(known)})")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            ap.error(f"{flag} {key} {value}: the value is not JSON (null, 0.02, \"auto\", ...)")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", nargs="+", action="append", required=True, metavar="LABEL EVAL.json DATA",
                    help="a label, then pairs of evaluate --json output and its BOP data folder")
    ap.add_argument("--thresholds", nargs="+", type=float, default=())
    ap.add_argument("--metric", nargs=2, action="append", default=[], metavar=("KEY", "JSON"),
                    help="the runs' stored metric KEY set to the JSON value before the pose-graph rows are refitted; repeatable")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    override = metric_overrides(ap, "--metric", a.metric)
    out = {}
    for label, *rest in a.set:
        if not rest or len(rest) % 2:
            ap.error(f"--set {label}: expected pairs EVAL.json DATA")
        acc: dict[str, list] = {}
        flip_prob, is_flip = [], []
        for js, data in zip(rest[::2], rest[1::2]):
            run = json.loads(Path(js).read_text())
            rows, metrics = run["frames"], run["metrics"] | override
            if "iml_est" not in rows[0]:
                ap.error(f"{js}: no iml_est rows (run evaluate --modules iml[,ir,pgo])")
            scene = load_scene(list(group_scenes(read_bop(Path(data))).values())[0])
            (det, det_all), o = detections(rows, metrics), np.array([r["o"] for r in rows])
            add = lambda k, est, d=det: acc.setdefault(k, []).append((est, d, scene.observed, scene.gt))  # noqa: E731
            add("IML", np.array([r["iml_est"] for r in rows]))
            add("IML+PGO", fused(rows, scene, "iml_est", det, metrics))
            if "ir_est" in rows[0]:  # an `evaluate --modules iml` run has IML's rows only
                add("IML+IR", np.array([r["ir_est"] for r in rows]))
                add("IML+IR+PGO", fused(rows, scene, "ir_est", det_all, metrics), det_all)
            for t in a.thresholds:
                add(f"IML+PGO, o >= {t}", fused(rows, scene, "iml_est", o >= t, metrics), o >= t)
            k = det & scene.observed
            flip_prob.append(np.array([r["iml_flip_prob"] for r in rows])[k])
            is_flip.append(flipped(np.array([r["iml_est"] for r in rows])[k, 2], np.asarray(scene.gt)[k, 2]))
        out[label] = {k: summary(v) for k, v in acc.items()}
        for k, m in out[label].items():
            print(f"| {label} | {k} | {m['dx_cm']:.1f} / {m['dy_cm']:.1f} | {m['median_dpsi_deg'] or float('nan'):.1f} | "
                  f"{m['ate']:.3f} | {m['flips']} | {m['detected']} / {m['observed']} | {m['median_range_ratio'] or float('nan'):.3f} |",
                  flush=True)
        out[label]["IML flip calibration"] = cal = calibration_metrics(np.concatenate(flip_prob), np.concatenate(is_flip))
        print(f"{label}: IML flip probability against IML's flips, {cal['flips']} of {cal['frames']}: Brier "
              f"{cal['brier']:.4f}, calibration error {cal['ece']:.4f}, ROC area {cal['auroc'] or float('nan'):.3f}", flush=True)
    if a.out:
        a.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
