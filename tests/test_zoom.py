"""AMLNet's zoom-in stage: crop geometry against projected points, the correction round trip,
deterministic training examples, and evaluate's composition of the two networks."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rhaml_jax.amlnet import decode, get_config, load_model
from rhaml_jax.zoom import ZoomSource, apply_correction, correction_targets, mirror_average, zoom_crop
from rhaml_jax.camera import DEFAULT_CAMERA, NOMINAL_HEIGHT_M
from rhaml_jax.data import load_rgb, network_image, read_bop
from rhaml_jax.data import write_training_set
from rhaml_jax.errors import RhamlError
from rhaml_jax.evaluate import main
from tests.conftest import random_checkpoint

CFG = get_config("zoom_cpu")


@settings(max_examples=50, deadline=None)
@given(x=st.floats(0.6, 9.0), y=st.floats(-4.0, 4.0), psi=st.floats(-3.14, 3.14),
       gx=st.floats(0.6, 9.0), gy=st.floats(-4.0, 4.0), scale=st.sampled_from([1.0, 0.3]))
def test_correction_round_trip(x, y, psi, gx, gy, scale):
    """Also in a TurtleBot-sized world (distances x 0.3, the nearest range clamp with them)."""
    from rhaml_jax.crop import min_range_m

    x, y, gx, gy = x * scale, y * scale, gx * scale, gy * scale
    m = min_range_m(0.455 * scale)
    t = correction_targets([x, y, psi], [gx, gy], m)
    back = apply_correction([gx, gy], t, m)
    np.testing.assert_allclose(back[:2], [x, y], atol=1e-9)
    assert abs(np.sin(back[2] - psi)) < 1e-9 and np.cos(back[2] - psi) > 0


@settings(max_examples=30, deadline=None)
@given(t=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.3, 0.3), st.floats(-3.1, 3.1)),
       noise=st.tuples(st.floats(-0.05, 0.05), st.floats(-0.02, 0.02), st.floats(-0.3, 0.3)))
def test_mirror_average_of_mirror_images(t, noise):
    t, noise = np.array(t), np.array(noise)
    # The mirrored crop's answer for a pose is the mirrored answer: the average is the answer.
    np.testing.assert_allclose(mirror_average(t, t * [1, -1, -1]), t, atol=1e-12)
    # Two looks that disagree by +-noise (mirrored) average to the middle.
    avg = mirror_average(t + noise, (t - noise) * [1, -1, -1])
    np.testing.assert_allclose(avg[:2], t[:2], atol=1e-12)
    assert abs(np.sin(avg[2] - t[2])) < 1e-9 and np.cos(avg[2] - t[2]) > 0


@pytest.mark.parametrize("psi", [0.4, 1.2, 2.5])
def test_mirrored_crop_is_the_crop_of_the_mirrored_pose(psi):
    """What `mirror_average` relies on: for an estimate on the optical axis, the crop mirrored
    left-right is the crop of the pose reflected about that axis (y, psi -> -y, -psi), here
    with the built-in robot's rendered mask."""
    from rhaml_jax import camera, frames, render, robots

    mesh = render.as_mesh(robots.load_robot("pioneer3dx"))
    K = DEFAULT_CAMERA.K

    def crop(xypsi):
        T = camera.T_cam_robot(NOMINAL_HEIGHT_M) @ frames.se3_from_xypsi(np.array(xypsi))
        mask = np.asarray(render.render(mesh, T, K, 640, 480).mask)
        img = np.repeat((mask * 255).astype(np.uint8)[..., None], 3, -1)
        return zoom_crop(img, K, [3.0, 0.0], CFG)[..., 0] > 127

    a, b = crop([3.0, 0.05, psi])[:, ::-1], crop([3.0, -0.05, -psi])
    assert (a & b).sum() / (a | b).sum() > 0.97


def _blobs(K, points, W=640, H=480, sigma=2.0):
    """An image with a Gaussian blob at the projection of each robot-frame point."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    img = np.zeros((H, W))
    for x, y, z in points:
        pu, pv = K[0, 2] - K[0, 0] * y / x, K[1, 2] + K[1, 1] * (NOMINAL_HEIGHT_M - z) / x
        img += np.exp(-((u - pu) ** 2 + (v - pv) ** 2) / (2 * sigma**2))
    return np.repeat((255 * img / img.max())[..., None], 3, -1).astype(np.uint8)


def _centroids(crop):
    """Centroids (u, v) of the left and right halves' brightness."""
    g = crop[..., 0].astype(np.float64)
    g = np.where(g > 0.2 * g.max(), g, 0.0)
    out = []
    for half in (slice(0, g.shape[1] // 2), slice(g.shape[1] // 2, None)):
        h = np.zeros_like(g)
        h[:, half] = g[:, half]
        v, u = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
        out.append(((h * u).sum() / h.sum(), (h * v).sum() / h.sum()))
    return np.array(out)


@pytest.mark.parametrize("x,y", [(1.5, 0.3), (4.5, -1.0), (7.0, 1.2)])
def test_crop_centres_and_scales_the_estimate(x, y):
    """Two points a quarter robot length either side of the estimate's centre point land
    symmetric about the crop centre, S / (2 zoom_factor) apart (near: area-shrunk crop; far:
    enlarged); holds for a camera with fx != fy too."""
    S = CFG.input_hw[0]
    half = 0.25 * CFG.zoom_length_m
    z = CFG.zoom_centre_z_m
    for cam in (DEFAULT_CAMERA, DEFAULT_CAMERA.resized(320, 256)):
        K = cam.K
        img = _blobs(K, [(x, y + half, z), (x, y - half, z)], cam.width, cam.height, sigma=1.5 * cam.width / 640)
        c = _centroids(zoom_crop(img, K, (x, y), CFG))
        np.testing.assert_allclose(c.mean(0), [(S - 1) / 2, (S - 1) / 2], atol=0.35)
        np.testing.assert_allclose(c[1, 0] - c[0, 0], S / (2 * CFG.zoom_factor), rtol=0.03)


@pytest.fixture(scope="module")
def bop_set(tmp_path_factory):
    """A small BOP set: 6 images with the robot (val: 1, test: 1, train: 4) and 1 without."""
    root = tmp_path_factory.mktemp("zoom") / "set"
    write_training_set(root, "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=3, num=6, negatives=1, workers=1)
    return root


def test_zoom_source_is_a_pure_function_of_seed_and_index(bop_set):
    a = ZoomSource(bop_set, "train", CFG, seed=1)
    b = ZoomSource(bop_set, "train", CFG, seed=1)
    n = len(a.frames)
    assert a.size == 8 * n and all(f.observed for f in a.frames)
    for i in (0, 3, n + 1):
        (ca, oa, ta), (cb, _, tb) = a.example(i), b.example(i)
        np.testing.assert_array_equal(ca, cb)
        np.testing.assert_array_equal(ta, tb)
        assert ca.shape == (64, 64, 3) and ca.dtype == np.uint8 and oa == 1.0
        f = a.frames[i % n]
        np.testing.assert_allclose(apply_correction(a.guess(i), ta)[:2], f.xypsi[:2], atol=1e-5)
    assert not np.allclose(a.guess(0), a.guess(n))  # another draw for the same image
    t = np.stack([a.example(i)[2] for i in range(a.size)])
    assert np.abs(t[:, 0]).max() <= 3 * 0.12 + 1e-6 and np.abs(t[:, 1]).max() <= np.deg2rad(7.5) + 1e-6
    with pytest.raises(RhamlError, match="task='zoom'"):
        ZoomSource(bop_set, "train", get_config("micro"))


def test_train_cli_runs_the_zoom_stage(bop_set, tmp_path):
    from rhaml_jax.train import main as train_main

    res = train_main(["--stage", "zoom", "--config", "tiny_zoom", "--data", str(bop_set), "--out", str(tmp_path / "run"),
                      "--steps", "2", "--batch", "4", "--val-every", "2", "--val-batches", "1", "--no-progress"])
    assert res["step"] == 2 and np.isfinite(res["loss"])
    assert {"range_pct", "bearing_deg", "dpsi_deg", "daxis_deg"} <= set(res["val"]) and "dx_cm" not in res["val"]
    net, _, _ = load_model(tmp_path / "run")
    assert net.cfg == get_config("tiny_zoom")


def test_evaluate_composes_amlnet_and_zoom(bop_set, tmp_path):
    random_checkpoint(tmp_path / "amlnet", "micro")
    random_checkpoint(tmp_path / "zoom", "tiny_zoom")
    out = tmp_path / "eval.json"
    main(["--data", str(bop_set), "--amlnet", str(tmp_path / "amlnet"), "--zoom", str(tmp_path / "zoom"),
          "--json", str(out), "--batch", "4"])
    res = json.loads(out.read_text())
    assert res["metrics"]["zoom"] is True
    frames = read_bop(bop_set)
    (a, ap, as_), (z, zp, zs) = load_model(tmp_path / "amlnet"), load_model(tmp_path / "zoom")
    full = [load_rgb(f.rgb) for f in frames]
    imgs = np.stack([network_image(im, f.K, a.cfg.input_hw) for im, f in zip(full, frames)]).astype(np.float32) / 255
    d = decode(a.apply(ap, as_, imgs), a.cfg.angle_head)
    guess = np.stack([d["x"], d["y"]], 1)
    crops = np.stack([zoom_crop(im, f.K, g, z.cfg) for im, f, g in zip(full, frames, guess)]).astype(np.float32) / 255
    dz = decode(z.apply(zp, zs, crops), z.cfg.angle_head)
    est = apply_correction(guess, np.stack([dz["x"], dz["y"], dz["psi"]], 1))
    for row, e, o in zip(res["frames"], est, np.asarray(d["o"])):
        if o >= 0.5:
            # 1e-3 (m, rad): evaluate batches frames through jitted convs, this reference runs them
            # eagerly; float32 sums in another order differed by 1.0e-4 rad on the CI machine
            np.testing.assert_allclose(row["est"], e, atol=1e-3)
    # --zoom-mirror: the zoom stage also on the mirrored crops, the two averaged
    main(["--data", str(bop_set), "--amlnet", str(tmp_path / "amlnet"), "--zoom", str(tmp_path / "zoom"),
          "--json", str(out), "--batch", "4", "--zoom-mirror"])
    res = json.loads(out.read_text())
    assert res["metrics"]["zoom_mirror"] is True
    dm = decode(z.apply(zp, zs, np.ascontiguousarray(crops[:, :, ::-1])), z.cfg.angle_head)
    t = mirror_average(np.stack([dz["x"], dz["y"], dz["psi"]], 1), np.stack([dm["x"], dm["y"], dm["psi"]], 1))
    est = apply_correction(guess, t)
    for row, e, o in zip(res["frames"], est, np.asarray(d["o"])):
        if o >= 0.5:
            # 1e-3 (m, rad): evaluate batches frames through jitted convs, this reference runs them
            # eagerly; float32 sums in another order differed by 1.0e-4 rad on the CI machine
            np.testing.assert_allclose(row["est"], e, atol=1e-3)
    with pytest.raises(RhamlError, match="not a zoom-in stage"):
        main(["--data", str(bop_set), "--amlnet", str(tmp_path / "amlnet"), "--zoom", str(tmp_path / "amlnet")])
    with pytest.raises(RhamlError, match="--zoom-mirror"):
        main(["--data", str(bop_set), "--amlnet", str(tmp_path / "amlnet"), "--zoom-mirror"])
    # A data set whose robot is not left-right symmetric is refused by name.
    import dataclasses
    import shutil

    from rhaml_jax.data._bop import write_dataset_header
    from rhaml_jax.robots import load_robot

    lopsided = tmp_path / "lopsided"
    shutil.copytree(bop_set, lopsided)
    m = load_robot("pioneer3dx")
    write_dataset_header(lopsided, dataclasses.replace(m, vertices=m.vertices + np.float32([0, 0.05, 0])), DEFAULT_CAMERA)
    with pytest.raises(RhamlError, match="obj_000001.ply is not left-right symmetric"):
        main(["--data", str(lopsided), "--amlnet", str(tmp_path / "amlnet"), "--zoom", str(tmp_path / "zoom"),
              "--zoom-mirror"])


def test_bad_input_is_named():
    img = np.zeros((48, 64, 3), np.uint8)
    K = DEFAULT_CAMERA.resized(64, 48).K
    with pytest.raises(RhamlError, match="not finite"):
        zoom_crop(img, K, (np.nan, 0.0), CFG)
    with pytest.raises(RhamlError, match=r"\(H, W, 3\)"):
        zoom_crop(img[..., 0], K, (3.0, 0.0), CFG)
    assert zoom_crop(img, K, (-2.0, 0.0), CFG).shape == (64, 64, 3)  # behind the camera: cropped at 0.5 m


def test_config_rules():
    with pytest.raises(RhamlError, match="square input"):
        dataclasses.replace(CFG, input_hw=(64, 96))
    with pytest.raises(RhamlError, match="task must be"):
        dataclasses.replace(CFG, task="track")
