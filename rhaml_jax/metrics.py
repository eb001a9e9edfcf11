"""The paper's error measures: absolute planar errors and ATE (eq. 12).

Inputs are metres and radians; `summarize` reports cm and degrees as the paper's tables do.
"""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax.frames import se3_from_xypsi, wrap_angle

__all__ = ["DETECTION_THRESHOLD", "FLIP_DEG", "VIEWS_DEG", "abs_errors", "ate", "detection_counts", "flipped", "flips_by_view",
           "frame_summary", "summarize", "view_deg"]

DETECTION_THRESHOLD = 0.5  # o >= this: the robot is called in view (everywhere: evaluate, training metrics)
FLIP_DEG = 90.0  # a heading error beyond this is a front/back flip (every table and calibration)


def flipped(est_psi, gt_psi) -> np.ndarray:
    """(N,) bool: the estimate's heading is off by more than FLIP_DEG."""
    d = np.angle(np.exp(1j * (np.asarray(est_psi, np.float64) - np.asarray(gt_psi, np.float64))))
    return np.abs(d) > np.deg2rad(FLIP_DEG)


VIEWS_DEG = {"back": (0.0, 30.0), "side": (30.0, 150.0), "front": (150.0, 180.0)}
"""the observed robot's view (the angle between its heading and the line of sight from the camera:
0 deg, its back faces the camera; 180 deg, its front) -> [lo, hi) (the last closed)"""


def view_deg(gt_xypsi) -> np.ndarray:
    """(N,) the view (VIEWS_DEG) of observed robots at planar poses (N, 3) in the observer's frame."""
    g = np.asarray(gt_xypsi, np.float64).reshape(-1, 3)
    return np.degrees(np.abs(np.angle(np.exp(1j * (g[:, 2] - np.arctan2(g[:, 1], g[:, 0]))))))


def flips_by_view(est_psi, gt_xypsi) -> dict:
    """{"back" | "side" | "front": [flips, frames]}: where the front/back flips are. Networks that
    read the robot's front from its paint flip its back views under a paint they never saw
    (BENCHMARKS.md, "Where the held-out flips are"), which the total alone hides."""
    flip, view = flipped(est_psi, np.asarray(gt_xypsi, np.float64).reshape(-1, 3)[:, 2]), view_deg(gt_xypsi)
    out = {}
    for name, (lo, hi) in VIEWS_DEG.items():
        sel = (view >= lo) & ((view < hi) | (hi == 180.0))
        out[name] = [int(flip[sel].sum()), int(sel.sum())]
    return out


def detection_counts(o, observed) -> dict:
    """Confusion counts of the in-view calls `o >= DETECTION_THRESHOLD` against the truth `observed`."""
    called = np.asarray(o) >= DETECTION_THRESHOLD
    observed = np.asarray(observed, bool)
    return {"tp": int((called & observed).sum()), "fp": int((called & ~observed).sum()),
            "fn": int((~called & observed).sum()), "tn": int((~called & ~observed).sum())}


def abs_errors(est_xypsi: jnp.ndarray, gt_xypsi: jnp.ndarray) -> jnp.ndarray:
    """(..., 3) |dx| (m), |dy| (m), |dpsi| (rad, wrapped to [0, pi])."""
    d = jnp.asarray(est_xypsi) - jnp.asarray(gt_xypsi)
    return jnp.stack([jnp.abs(d[..., 0]), jnp.abs(d[..., 1]), jnp.abs(wrap_angle(d[..., 2]))], -1)


def ate(T_est: jaxlie.SE3 | jnp.ndarray, T_gt: jaxlie.SE3 | jnp.ndarray) -> jnp.ndarray:
    """Eq. 12: sqrt(mean_i ||log(T_gt,i^-1 T_est,i)^vee||^2) over the batch axis.

    Accepts SE3 objects with one batch axis, or (N, 3) planar poses (lifted to SE3 on the
    ground plane). The twist is jaxlie's (v, omega), in metres and radians.
    """
    if not isinstance(T_est, jaxlie.SE3):
        T_est = se3_from_xypsi(T_est)
    if not isinstance(T_gt, jaxlie.SE3):
        T_gt = se3_from_xypsi(T_gt)
    twist = (T_gt.inverse() @ T_est).log()
    ms = jnp.mean(jnp.sum(twist**2, axis=-1))
    # Guard: d sqrt(x)/dx is infinite at x = 0 (a perfect estimate); the double `where` keeps
    # the gradient finite (zero) there without changing the value. A non-finite estimate stays
    # NaN (testing `ms > 0` instead would report it as a perfect 0).
    zero = ms == 0
    return jnp.where(zero, 0.0, jnp.sqrt(jnp.where(zero, 1.0, ms)))


def summarize(est_xypsi, gt_xypsi) -> dict:
    """Mean and std of |dx|, |dy| (cm), |dpsi| (deg) and the ATE, as plain floats."""
    est = jnp.asarray(est_xypsi, dtype=jnp.float32).reshape(-1, 3)
    gt = jnp.asarray(gt_xypsi, dtype=jnp.float32).reshape(-1, 3)
    if est.shape[0] == 0:
        nan = [float("nan"), float("nan")]
        return {"dx_cm": nan, "dy_cm": nan, "dpsi_deg": nan, "ate": float("nan"), "n": 0}
    e = np.asarray(abs_errors(est, gt), dtype=np.float64) * np.array([100.0, 100.0, 180.0 / np.pi])
    ms = lambda c: [float(e[:, c].mean()), float(e[:, c].std())]  # noqa: E731
    return {"dx_cm": ms(0), "dy_cm": ms(1), "dpsi_deg": ms(2), "ate": float(ate(est, gt)), "n": int(est.shape[0])}


def frame_summary(frames: list[dict], detected_only: bool = True) -> dict:
    """The robustness figures of evaluate's per-frame JSON rows (DESIGN.md section 5), over the
    frames with the robot in view that have an estimate (and, with `detected_only`, were
    detected): |dx|, |dy| (cm), |dpsi| (deg) as [mean, std, median], ATE, flips (|dpsi| > 90
    deg), the median estimated / true range, n; and the detection counts over every frame."""
    used = [f for f in frames if f["observed"] and f["est"] is not None and (f.get("detected", True) or not detected_only)]
    called = np.array([bool(f.get("detected", f["est"] is not None)) for f in frames])
    row = {"frames": len(frames), "detection": detection_counts(called.astype(float), [f["observed"] for f in frames]),
           "n": len(used)}
    if not used:
        return row
    est, gt = np.array([f["est"] for f in used], np.float64), np.array([f["gt"] for f in used], np.float64)
    e = np.asarray(abs_errors(est, gt), np.float64) * np.array([100.0, 100.0, 180.0 / np.pi])
    for k, name in enumerate(("dx_cm", "dy_cm", "dpsi_deg")):
        row[name] = [float(e[:, k].mean()), float(e[:, k].std()), float(np.median(e[:, k]))]
    row["ate"] = float(summarize(est, gt)["ate"])
    row["flips"] = int(flipped(est[:, 2], gt[:, 2]).sum())
    row["median_range_ratio"] = float(np.median(np.hypot(est[:, 0], est[:, 1]) / np.hypot(gt[:, 0], gt[:, 1])))
    return row
