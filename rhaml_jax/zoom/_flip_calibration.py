"""A calibrated flip probability for the zoom stage (Platt scaling of its front/back ranking).

The zoom stage's direction outputs are the shorter the more it is torn between a heading and
its opposite (`ZoomCorrection.sure`); IML turns that into the ranking r = (1 - sure) / 2 in
[0, 0.5], which orders frames by how likely their heading is flipped but is no probability (a
frame at r = 0.2 may be flipped one time in a hundred or one in three, depending on the network
and the images). The pose graph weighs each observation's two heading hypotheses by IML's
flip probability (`pgo.fuse(flip_prob=...)`), so it should be one:

    P(flip | r) = sigmoid(a + b r)

with (a, b) fitted by logistic regression on a validation split (robot frames that were
detected; flipped: |dpsi| > 90 deg), with Platt's smoothed targets (N+ + 1) / (N+ + 2) and
1 / (N- + 2), which keep (a, b) finite when the split has no flip at all. Host-side NumPy: fitted
once, stored in the zoom checkpoint's meta (`flip_calibration`), applied by `iml.localize`.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from rhaml_jax.errors import RhamlError


class FlipCalibration(NamedTuple):
    """P(flip) = sigmoid(a + b * ranking), and what it was fitted on."""

    a: float
    b: float
    frames: int  # detected robot frames it was fitted on
    flips: int  # of which flipped
    source: str  # the data (folder and split)
    zoom_mirror: bool  # whether IML mirrored the crops (the ranking's spread depends on it)

    def to_dict(self) -> dict:
        return self._asdict()

    @classmethod
    def from_dict(cls, d: dict, where: str = "flip_calibration") -> "FlipCalibration":
        try:
            cal = cls(float(d["a"]), float(d["b"]), int(d["frames"]), int(d["flips"]), str(d["source"]), bool(d["zoom_mirror"]))
        except (KeyError, TypeError, ValueError) as e:
            raise RhamlError(f"{where}: not a flip calibration ({d!r}: {e})") from None
        if not (np.isfinite(cal.a) and np.isfinite(cal.b)):
            raise RhamlError(f"{where}: a = {cal.a}, b = {cal.b} must be finite")
        return cal


def fit_flip_calibration(ranking, is_flipped, zoom_mirror: bool, source: str = "", iterations: int = 50) -> FlipCalibration:
    """(a, b) by Newton's method on the cross-entropy against Platt's smoothed targets."""
    r = np.asarray(ranking, np.float64).ravel()
    y = np.asarray(is_flipped, bool).ravel()
    if r.shape != y.shape or r.size < 2:
        raise RhamlError(f"flip calibration: need at least 2 frames with a ranking and a flip label each "
                         f"(got {r.size} rankings, {y.size} labels)")
    if not np.all(np.isfinite(r)):
        raise RhamlError("flip calibration: the rankings hold NaN or inf")
    n_pos = int(y.sum())
    t = np.where(y, (n_pos + 1.0) / (n_pos + 2.0), 1.0 / (r.size - n_pos + 2.0))
    X = np.stack([np.ones_like(r), r], -1)
    w = np.array([np.log((n_pos + 1.0) / (r.size - n_pos + 1.0)), 0.0])  # the base rate
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-(X @ w)))
        g = X.T @ (p - t)
        # a tiny ridge keeps the Hessian invertible when every ranking is the same
        H = (X * (p * (1 - p))[:, None]).T @ X + 1e-9 * np.eye(2)
        step = np.linalg.solve(H, g)
        w = w - step
        if np.max(np.abs(step)) < 1e-10:
            break
    return FlipCalibration(float(w[0]), float(w[1]), int(r.size), n_pos, source, bool(zoom_mirror))


def write_flip_calibration(zoom_dir: str | Path, cal: FlipCalibration) -> Path:
    """Stores `cal` in the zoom checkpoint folder's meta: the weights are exported again beside
    it with the new meta, then swapped in by renames (the old folder is kept until the new one
    is complete)."""
    import shutil

    from rhaml_jax.amlnet.checkpoint import checkpoint_meta, export_weights

    zoom_dir = Path(zoom_dir)
    tmp, old = zoom_dir.with_name(zoom_dir.name + ".calibrating"), zoom_dir.with_name(zoom_dir.name + ".uncalibrated")
    if not zoom_dir.exists() and old.exists():  # a call interrupted between its two renames
        old.rename(zoom_dir)
    for p in (tmp, old):  # leftovers of an interrupted call
        if p.exists():
            shutil.rmtree(p)
    meta = checkpoint_meta(zoom_dir)
    if meta.get("model_config", {}).get("task") != "zoom":
        raise RhamlError(f"{zoom_dir}: not a zoom-in stage checkpoint (config {meta.get('model_config', {}).get('name')!r})")
    export_weights(zoom_dir, tmp, extra_meta={"exported_from": meta.get("exported_from", str(zoom_dir)),
                                              "flip_calibration": cal.to_dict()})
    zoom_dir.rename(old)
    tmp.rename(zoom_dir)
    shutil.rmtree(old)
    return zoom_dir


def flip_probability(ranking, cal: FlipCalibration | tuple[float, float]):
    """P(flip) for rankings (NumPy or JAX arrays alike)."""
    import jax.numpy as jnp

    a, b = cal[0], cal[1]
    xp = np if isinstance(ranking, np.ndarray) else jnp
    z = a + b * ranking
    return 1.0 / (1.0 + xp.exp(-z))


def calibration_metrics(prob, is_flipped, bins: int = 10) -> dict:
    """How well probabilities `prob` (N,) of a flip match the flips: Brier score, mean negative
    log-likelihood (nats), expected calibration error over `bins` equal-width bins, and the
    area under the ROC curve (how well they rank; 0.5 is chance, None without both classes)."""
    p = np.clip(np.asarray(prob, np.float64).ravel(), 1e-12, 1 - 1e-12)
    y = np.asarray(is_flipped, bool).ravel()
    if p.size == 0:
        return {"frames": 0, "flips": 0, "brier": None, "nll": None, "ece": None, "auroc": None}
    idx = np.minimum((p * bins).astype(int), bins - 1)
    ece = sum(abs(p[idx == k].mean() - y[idx == k].mean()) * np.mean(idx == k) for k in range(bins) if np.any(idx == k))
    n_pos, n_neg = int(y.sum()), int((~y).sum())
    auroc = None
    if n_pos and n_neg:  # Mann-Whitney U over average ranks (ties count half)
        from scipy.stats import rankdata

        auroc = float((rankdata(p)[y].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))
    return {"frames": int(p.size), "flips": n_pos, "mean_prob": float(p.mean()),
            "brier": float(np.mean((p - y) ** 2)),
            "nll": float(-np.mean(np.where(y, np.log(p), np.log(1 - p)))), "ece": float(ece), "auroc": auroc}
