"""Validation metrics in the paper's terms: abs dx, dy (cm) and abs dpsi (deg, wrapped) over
the frames with a robot in view, and detection accuracy (o >= metrics.DETECTION_THRESHOLD) over all frames; also
daxis, the heading error modulo 180 deg, which tells a front/back flip from a wrong axis.
For the zoom stage (task "zoom", whose "x, y" are log range ratio and bearing correction) the
first two are named range_pct (100 |d log r|, about the range error in %) and bearing_deg."""

from __future__ import annotations

import numpy as np

from rhaml_jax.metrics import detection_counts
from rhaml_jax.planar import wrap_angle

__all__ = ["pose_metrics"]


def pose_metrics(pred: dict, observed: np.ndarray, pose: np.ndarray, task: str = "localize") -> dict:
    """pred: decoded outputs (numpy arrays o, x, y, psi); observed (N,), pose (N, 3)."""
    obs = np.asarray(observed) > 0.5
    counts = detection_counts(pred["o"], obs)
    out = {"detection_acc": (counts["tp"] + counts["tn"]) / max(len(obs), 1), **counts}
    if obs.any():
        dx = 100 * np.abs(np.asarray(pred["x"])[obs] - pose[obs, 0])
        dy = 100 * np.abs(np.asarray(pred["y"])[obs] - pose[obs, 1])
        d = np.asarray(pred["psi"])[obs] - pose[obs, 2]
        dpsi = np.degrees(np.abs(wrap_angle(d)))
        axis = np.minimum(dpsi, 180.0 - dpsi)  # the error of the heading's axis (front and back alike)
        if task == "zoom":
            names = (("range_pct", dx), ("bearing_deg", np.degrees(dy / 100)))
        else:
            names = (("dx_cm", dx), ("dy_cm", dy))
        for name, v in names + (("dpsi_deg", dpsi), ("daxis_deg", axis)):
            out[name] = float(np.mean(v))
            out[name + "_std"] = float(np.std(v))
    return out
