"""rhaml_jax.crop: one box gives the crop's pixels and its intrinsics; JAX and OpenCV crops agree."""

from __future__ import annotations

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import camera, crop
from rhaml_jax.amlnet import get_config
from rhaml_jax.zoom import crop_transform

K = camera.DEFAULT_CAMERA.K


def _image(seed=0, h=480, w=640):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (h // 8, w // 8, 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)  # smooth, so resamplers can agree


def test_box_affine_matches_crop_intrinsics():
    box = np.array([200.3, 150.7, 330.1, 260.2])
    A = crop.box_affine(box, 64, 48)
    Kc = np.asarray(camera.crop_intrinsics(K, box, 64, 48))
    p = np.array([0.4, -0.2, 3.0])  # a point in the optical frame
    uv = (K @ p)[:2] / p[2]
    uvc = (Kc @ p)[:2] / p[2]
    np.testing.assert_allclose(A @ np.r_[uv, 1.0], uvc, atol=1e-9)


def test_zoom_box_is_the_zoom_stages_crop():
    cfg = get_config("zoom_cpu")
    S = cfg.input_hw[0]
    for guess in ([3.0, 0.4], [6.5, -1.2], [0.2, 0.1]):
        x = max(guess[0], crop.MIN_RANGE_M)
        u, v = 320 + 400 * -guess[1] / x, 240 + 400 * (0.30 - cfg.zoom_centre_z_m) / x
        s = S / (cfg.zoom_factor * cfg.zoom_length_m * 400 / x)  # the zoom stage's own definition
        ref = np.array([[s, 0, (S - 1) / 2 - s * u], [0, s, (S - 1) / 2 - s * v]])
        np.testing.assert_allclose(crop_transform(K, np.array(guess), cfg), ref, atol=1e-9)


def test_the_nearest_range_follows_the_robots_length():
    """0.5 m for the Pioneer's 0.455 m exactly (the shipped zoom stage's crops are unchanged); a
    TurtleBot3-length (0.138 m) zoom crop stays sized by its range down to 0.15 m, where its world
    (training depths from 0.39 m) still has robots."""
    assert crop.min_range_m(get_config("zoom_cpu").zoom_length_m) == crop.MIN_RANGE_M == 0.5
    small = crop.min_range_m(0.138)
    assert abs(small - 0.5 * 0.138 / 0.455) < 1e-12
    K = np.asarray(camera.DEFAULT_CAMERA.K)
    near = crop.zoom_box(K, np.array([0.4, 0.0]), 0.138, 2.0, 0.1)
    far = crop.zoom_box(K, np.array([0.8, 0.0]), 0.138, 2.0, 0.1)
    np.testing.assert_allclose((near[2] - near[0]) / (far[2] - far[0]), 2.0, rtol=1e-9)  # not clamped at 0.5 m
    clamped = crop.zoom_box(K, np.array([0.05, 0.0]), 0.138, 2.0, 0.1)
    at_min = crop.zoom_box(K, np.array([small, 0.0]), 0.138, 2.0, 0.1)
    np.testing.assert_allclose(clamped, at_min)


def test_network_box_of_the_default_camera_is_the_whole_image():
    net_K = np.asarray(camera.DEFAULT_CAMERA.resized(160, 128).K)
    np.testing.assert_allclose(crop.network_box(K, (640, 480), net_K, (160, 128)), [-0.5, -0.5, 639.5, 479.5], atol=1e-3)


def test_jax_crop_agrees_with_opencv():
    img = _image()
    ref = cv2.resize(img, (160, 128), interpolation=cv2.INTER_AREA).astype(np.float32)  # AMLNet's input
    got = np.asarray(crop.resample(jnp.asarray(img), jnp.array([-0.5, -0.5, 639.5, 479.5]), 160, 128))
    assert np.abs(got - ref).max() <= 0.51  # OpenCV rounds to 8 bits
    for box, size in (([-0.5, -0.5, 639.5, 479.5], (160, 128)),  # whole image, through the crop path
                      ([250.0, 180.0, 390.0, 320.0], (64, 64)),  # a zoom crop, shrinking
                      ([300.0, 220.0, 340.0, 260.0], (64, 64)),  # enlarging
                      ([600.0, 400.0, 700.0, 500.0], (64, 64))):  # leaving the image (border repeated)
        ref = crop.crop_image_host(img, np.array(box), *size).astype(np.float32)
        got = np.asarray(crop.crop_image(jnp.asarray(img), jnp.asarray(box), *size))
        assert got.shape == ref.shape
        assert np.abs(got - ref).mean() < 0.6 and np.abs(got - ref).max() < 2.0, (box, np.abs(got - ref).max())


def test_identity_crop_and_gradient():
    img = _image(1, 48, 64).astype(np.float32)
    same = crop.crop_image(jnp.asarray(img), jnp.array([-0.5, -0.5, 63.5, 47.5]), 64, 48)
    np.testing.assert_allclose(np.asarray(same), img, atol=1e-3)
    g = jax.grad(lambda b: crop.crop_image(jnp.asarray(img), b, 16, 16).mean())(jnp.array([10.0, 8.0, 40.0, 30.0]))
    assert np.all(np.isfinite(g)) and np.any(g != 0)


def test_object_box_contains_the_projected_points():
    pts = np.array([[-0.2, -0.1, 3.0], [0.25, 0.15, 3.4], [0.0, 0.2, 2.8]])
    b = crop.object_box(K, pts, margin=1.4)
    uv = (K @ pts.T).T
    uv = uv[:, :2] / uv[:, 2:]
    assert np.all(uv[:, 0] > b[0]) and np.all(uv[:, 0] < b[2]) and np.all(uv[:, 1] > b[1]) and np.all(uv[:, 1] < b[3])
    np.testing.assert_allclose(b[2] - b[0], b[3] - b[1])  # square (aspect 1)
