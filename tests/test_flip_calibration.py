"""The zoom stage's flip calibration (rhaml_jax.zoom._flip_calibration): the fit against an
independent optimiser, the metrics against their definitions, and the checkpoint round trip
through load_iml and evaluate."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

from rhaml_jax.errors import RhamlError
from rhaml_jax.metrics import flipped
from rhaml_jax.zoom import FlipCalibration, calibration_metrics, fit_flip_calibration, flip_probability, write_flip_calibration
from tests.conftest import random_checkpoint


def _platt_objective(w, r, t):
    z = w[0] + w[1] * r
    return np.sum(np.logaddexp(0.0, z) - t * z)  # cross-entropy against soft targets t


def test_fit_matches_an_independent_optimiser_and_recovers_the_model():
    from scipy.optimize import minimize

    rng = np.random.default_rng(0)
    r = rng.uniform(0.0, 0.5, 20_000)
    y = rng.uniform(size=r.size) < 1 / (1 + np.exp(-(-4.0 + 12.0 * r)))
    cal = fit_flip_calibration(r, y, zoom_mirror=True, source="synthetic")
    n = int(y.sum())
    t = np.where(y, (n + 1) / (n + 2), 1 / (r.size - n + 2))
    ref = minimize(_platt_objective, np.zeros(2), args=(r, t), method="BFGS", options={"gtol": 1e-8}).x
    np.testing.assert_allclose([cal.a, cal.b], ref, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose([cal.a, cal.b], [-4.0, 12.0], rtol=0.1)
    assert (cal.frames, cal.flips, cal.zoom_mirror) == (20_000, n, True)
    assert FlipCalibration.from_dict(json.loads(json.dumps(cal.to_dict()))) == cal


def test_no_flip_at_all_stays_finite_and_unlikely():
    r = np.linspace(0.0, 0.5, 400)
    cal = fit_flip_calibration(r, np.zeros(r.size, bool), zoom_mirror=False)
    p = flip_probability(r, cal)
    assert np.isfinite([cal.a, cal.b]).all() and p.max() < 0.02
    # one ranking for every frame: the base rate (of Platt's smoothed targets), whatever the labels
    cal = fit_flip_calibration(np.full(100, 0.3), np.arange(100) < 25, zoom_mirror=False)
    np.testing.assert_allclose(flip_probability(np.array([0.3]), cal), (25 * 26 / 27 + 75 / 77) / 100, rtol=1e-6)


def test_metrics_match_their_definitions():
    rng = np.random.default_rng(1)
    p = rng.uniform(size=60).round(1)  # ties on purpose
    y = rng.uniform(size=60) < p
    m = calibration_metrics(p, y)
    pairs = [(1.0 if a > b else 0.5 if a == b else 0.0) for a in p[y] for b in p[~y]]
    assert m["auroc"] == pytest.approx(np.mean(pairs))
    assert m["brier"] == pytest.approx(np.mean((p - y) ** 2))
    assert calibration_metrics(np.array([0.2, 0.8]), np.array([False, True]))["auroc"] == 1.0
    assert calibration_metrics(np.full(5, 0.1), np.zeros(5, bool))["auroc"] is None
    assert calibration_metrics(np.full(10, 0.3), np.arange(10) < 3)["ece"] == pytest.approx(0.0)
    assert flipped([0.0, 3.0, -3.0], [0.0, 0.0, 3.0]).tolist() == [False, True, False]


def test_bad_input_is_named():
    with pytest.raises(RhamlError, match="at least 2 frames"):
        fit_flip_calibration([0.1], [True], zoom_mirror=False)
    with pytest.raises(RhamlError, match="NaN"):
        fit_flip_calibration([0.1, np.nan], [True, False], zoom_mirror=False)
    with pytest.raises(RhamlError, match="flip_calibration: not a flip calibration"):
        FlipCalibration.from_dict({"a": 1.0})
    with pytest.raises(RhamlError, match="must be finite"):
        FlipCalibration.from_dict({"a": float("nan"), "b": 1, "frames": 3, "flips": 1, "source": "", "zoom_mirror": False})


@pytest.fixture(scope="module")
def nets(tmp_path_factory):
    """A tiny BOP set and random-weight micro AMLNet + tiny_zoom checkpoints."""
    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import write_training_set

    root = tmp_path_factory.mktemp("flipcal")
    write_training_set(root / "set", "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=3, num=6, negatives=1, workers=1)
    random_checkpoint(root / "amlnet", "micro")
    random_checkpoint(root / "zoom", "tiny_zoom")
    return root


def test_a_stored_calibration_is_what_iml_applies(nets):
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta
    from rhaml_jax.data import load_rgb, read_bop
    from rhaml_jax.evaluate import main as evaluate_main
    from rhaml_jax.iml import load_iml, localize_jit

    zoom = nets / "zoom_cal"
    import shutil

    shutil.copytree(nets / "zoom", zoom)
    cal = FlipCalibration(-3.0, 10.0, 100, 7, "test", True)
    write_flip_calibration(zoom, cal)
    assert checkpoint_meta(zoom)["flip_calibration"] == cal.to_dict()
    assert not (nets / "zoom_cal.uncalibrated").exists() and not (nets / "zoom_cal.calibrating").exists()
    # killed between its two renames: the next call restores the folder and finishes
    (nets / "zoom_cal").rename(nets / "zoom_cal.uncalibrated")
    (nets / "zoom_cal.calibrating").mkdir()
    write_flip_calibration(zoom, cal)
    assert checkpoint_meta(zoom)["flip_calibration"] == cal.to_dict()
    assert not (nets / "zoom_cal.uncalibrated").exists() and not (nets / "zoom_cal.calibrating").exists()
    frames = read_bop(nets / "set")
    images = jnp.asarray(np.stack([load_rgb(f.rgb) for f in frames]))
    K = jnp.asarray(frames[0].K)
    raw_m, raw_p = load_iml(nets / "amlnet", zoom, zoom_mirror=True, calibrated=False)
    cal_m, cal_p = load_iml(nets / "amlnet", zoom, zoom_mirror=True)
    assert raw_m.flip_calibration is None and cal_m.flip_calibration == (-3.0, 10.0)
    raw, done = localize_jit(raw_m, raw_p, images, K), localize_jit(cal_m, cal_p, images, K)
    np.testing.assert_allclose(done.flip_prob, 1 / (1 + np.exp(3.0 - 10.0 * np.asarray(raw.flip_prob))), rtol=1e-5)
    np.testing.assert_array_equal(done.xypsi, raw.xypsi)  # the weights are the same
    # a calibration fitted with mirroring is not applied without it (said, not silently wrong)
    with pytest.warns(UserWarning, match="fitted with --zoom-mirror"):
        assert load_iml(nets / "amlnet", zoom)[0].flip_calibration is None
    # evaluate reports how well flip_prob predicts the flips, and says whether it is calibrated
    out = nets / "eval.json"
    evaluate_main(["--data", str(nets / "set"), "--amlnet", str(nets / "amlnet"), "--zoom", str(zoom), "--zoom-mirror",
                   "--json", str(out), "--batch", "4"])
    res = json.loads(out.read_text())
    assert res["metrics"]["iml_flip"]["calibrated"] is True
    seen = [r for r in res["frames"] if r["observed"] and r["detected"]]
    assert res["metrics"]["iml_flip"]["frames"] == len(seen)
    assert all(0.0 <= r["iml_flip_prob"] <= 1.0 for r in res["frames"])


def test_calibrate_flips_needs_enough_frames_and_a_zoom_checkpoint(nets):
    from rhaml_jax.calibrate_flips import main

    with pytest.raises(RhamlError, match="a calibration needs at least 20"):
        main(["--data", str(nets / "set"), "--amlnet", str(nets / "amlnet"), "--zoom", str(nets / "zoom"), "--split", "train",
              "--dry-run"])
    with pytest.raises(RhamlError, match="not a checkpoint folder"):
        main(["--data", str(nets / "set"), "--zoom", str(nets / "set")])
    with pytest.raises(RhamlError, match="not a zoom-in stage checkpoint"):
        write_flip_calibration(nets / "amlnet", FlipCalibration(0.0, 1.0, 2, 1, "", False))
