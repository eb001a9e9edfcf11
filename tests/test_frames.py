"""Round trips of the frame conversions, the camera model and the error measures."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rhaml_jax import camera, frames, metrics

finite = dict(allow_nan=False, allow_infinity=False)
xs = st.floats(-20, 20, **finite)
angles = st.floats(-10, 10, **finite)
heights = st.floats(0.05, 2.0, **finite)
SETTINGS = settings(max_examples=30, deadline=None)


def _close_angle(a, b, tol=1e-4):
    assert abs(float(frames.wrap_angle(jnp.asarray(a - b)))) < tol


@SETTINGS
@given(xs, xs, angles)
def test_se2_se3_round_trip(x, y, psi):
    p = jnp.array([x, y, psi])
    for back in (frames.xypsi_from_se3(frames.se3_from_xypsi(p)), frames.xypsi_from_se2(frames.se2_from_xypsi(p))):
        np.testing.assert_allclose(back[:2], p[:2], atol=1e-4)
        _close_angle(back[2], psi)


@SETTINGS
@given(xs, xs, angles)
def test_se3_lift_is_planar(x, y, psi):
    T = frames.se3_from_xypsi(jnp.array([x, y, psi]))
    rpy = frames.roll_pitch_yaw(T)
    np.testing.assert_allclose(rpy[:2], 0.0, atol=1e-6)
    _close_angle(rpy[2], psi)
    assert abs(float(T.translation()[2])) < 1e-7


@SETTINGS
@given(st.floats(-1.5, 1.5, **finite), st.floats(-1.4, 1.4, **finite), angles)
def test_roll_pitch_yaw_matches_jaxlie(r, p, y):
    T = jaxlie.SE3.from_rotation(jaxlie.SO3.from_rpy_radians(r, p, y))
    np.testing.assert_allclose(frames.roll_pitch_yaw(T), [r, p, frames.wrap_angle(y)], atol=1e-4)


@SETTINGS
@given(st.floats(0.5, 15, **finite), xs, angles, heights)
def test_bop_round_trip(x, y, psi, h):
    p = jnp.array([x, y, psi])
    R, t = frames.bop_from_pose(frames.se3_from_xypsi(p), h)
    assert R.shape == (9,) and t.shape == (3,)
    np.testing.assert_allclose(np.linalg.det(R.reshape(3, 3)), 1.0, atol=1e-5)
    back = frames.xypsi_from_se3(frames.pose_from_bop(R, t, h))
    np.testing.assert_allclose(back[:2], p[:2], atol=1e-3)
    _close_angle(back[2], psi, 1e-3)


def test_bop_convention_known_pose():
    """A robot 3 m ahead, 1 m left, facing the camera's right: camera x = -1 m, y = +h, z = 3 m."""
    R, t = frames.bop_from_pose(frames.se3_from_xypsi(jnp.array([3.0, 1.0, 0.0])), 0.3)
    np.testing.assert_allclose(t, [-1000.0, 300.0, 3000.0], atol=1e-3)
    # The model's x axis (forward) is the camera's z axis (depth).
    np.testing.assert_allclose(R.reshape(3, 3)[:, 0], [0, 0, 1], atol=1e-6)


@SETTINGS
@given(st.floats(-3, 3, **finite), st.floats(-3, 3, **finite), st.floats(0.2, 30, **finite))
def test_project_backproject_round_trip(px, py, z):
    K = jnp.asarray(camera.DEFAULT_CAMERA.K, jnp.float32)
    p = jnp.array([px, py, z])
    uv, depth = camera.project(K, p)
    np.testing.assert_allclose(camera.backproject(K, uv, depth), p, rtol=1e-4, atol=1e-4)


def test_camera_extrinsic_axes():
    T = camera.T_cam_robot(0.3)
    # A point 2 m ahead at camera height is on the optical axis; one to the left is at -x; one above at -y.
    np.testing.assert_allclose(T @ jnp.array([2.0, 0.0, 0.3]), [0, 0, 2], atol=1e-6)
    np.testing.assert_allclose(T @ jnp.array([2.0, 1.0, 0.3]), [-1, 0, 2], atol=1e-6)
    np.testing.assert_allclose(T @ jnp.array([2.0, 0.0, 1.3]), [0, -1, 2], atol=1e-6)
    batch = camera.T_cam_robot(jnp.array([0.25, 0.35]))
    assert batch.get_batch_axes() == (2,)


@SETTINGS
@given(st.integers(16, 1280), st.integers(16, 960), st.floats(-2, 2, **finite), st.floats(-2, 2, **finite))
def test_resize_intrinsics_maps_pixels_like_cv2(w1, h1, px, py):
    """A 3D point lands at the resized pixel cv2.resize would put it: (u + 0.5) * s - 0.5."""
    cam = camera.DEFAULT_CAMERA
    K1 = camera.resize_intrinsics(cam.K, (cam.width, cam.height), (w1, h1))
    p = jnp.array([px, py, 3.0])
    uv0, _ = camera.project(cam.K, p)
    uv1, _ = camera.project(K1, p)
    np.testing.assert_allclose(uv1, (uv0 + 0.5) * jnp.array([w1 / cam.width, h1 / cam.height]) - 0.5, rtol=1e-4, atol=1e-3)


def test_crop_intrinsics_full_image_is_identity_and_corners_map():
    cam = camera.DEFAULT_CAMERA
    K = camera.crop_intrinsics(cam.K, jnp.array([-0.5, -0.5, cam.width - 0.5, cam.height - 0.5]), cam.width, cam.height)
    np.testing.assert_allclose(K, cam.K, atol=1e-4)
    # Crop (100, 50)-(164, 114) to 32 x 32: the crop's pixel (0, 0) centre is full-image (100.5 + 0.5, ...)
    box = jnp.array([100.0, 50.0, 164.0, 114.0])
    Kc = camera.crop_intrinsics(cam.K, box, 32, 32)
    p = camera.backproject(cam.K, jnp.array([101.0, 51.0]), 4.0)
    uv, _ = camera.project(Kc, p)
    np.testing.assert_allclose(uv, [0.0, 0.0], atol=1e-3)
    assert jax.jit(camera.crop_intrinsics, static_argnums=(2, 3))(cam.K, box[None], 32, 32).shape == (1, 3, 3)


def test_camera_from_K_rejects_bad_shape():
    import pytest

    from rhaml_jax.errors import RhamlError

    with pytest.raises(RhamlError, match="cam_K"):
        camera.Camera.from_K(np.eye(4), 640, 480)
    with pytest.raises(RhamlError, match="focal"):
        camera.Camera(fx=-1.0)


@SETTINGS
@given(st.lists(st.tuples(xs, xs, angles, st.floats(-1, 1, **finite), st.floats(-1, 1, **finite), st.floats(-3, 3, **finite)), min_size=1, max_size=8))
def test_ate_matches_direct_computation(rows):
    a = np.array(rows, np.float64)
    gt, est = a[:, :3], a[:, :3] + a[:, 3:]
    # Direct: SE(3) log of gt^-1 est via scipy's rotation log and the SE(3) V^-1 matrix.
    from scipy.spatial.transform import Rotation

    sq = []
    for g, e in zip(gt, est):
        Tg, Te = np.eye(4), np.eye(4)
        for T, p in ((Tg, g), (Te, e)):
            T[:3, :3] = Rotation.from_euler("z", p[2]).as_matrix()
            T[:3, 3] = [p[0], p[1], 0]
        D = np.linalg.inv(Tg) @ Te
        w = Rotation.from_matrix(D[:3, :3]).as_rotvec()
        th = np.linalg.norm(w)
        W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        if th < 1e-4:  # series limit of the coefficient below: 1/12
            Vinv = np.eye(3) - 0.5 * W + W @ W / 12.0
        else:
            Vinv = np.eye(3) - 0.5 * W + (1 - th * np.sin(th) / (2 * (1 - np.cos(th)))) / th**2 * W @ W
        v = Vinv @ D[:3, 3]
        sq.append(v @ v + w @ w)
    want = np.sqrt(np.mean(sq))
    got = float(metrics.ate(jnp.asarray(est, jnp.float32), jnp.asarray(gt, jnp.float32)))
    np.testing.assert_allclose(got, want, rtol=2e-3, atol=2e-3)


def test_abs_errors_wrap_angle_and_summary_units():
    e = metrics.abs_errors(jnp.array([[1.0, 2.0, np.pi - 0.01]]), jnp.array([[1.02, 1.9, -np.pi + 0.01]]))
    np.testing.assert_allclose(e[0], [0.02, 0.1, 0.02], atol=1e-5)
    s = metrics.summarize(jnp.array([[1.0, 2.0, 0.1]]), jnp.array([[1.02, 1.9, 0.0]]))
    np.testing.assert_allclose([s["dx_cm"][0], s["dy_cm"][0], s["dpsi_deg"][0]], [2.0, 10.0, np.degrees(0.1)], rtol=1e-4)


def test_gradients_finite_at_zero_and_wrap():
    """Grad of the ATE and the planar errors at a perfect estimate: finite (no NaN at zero angle)."""
    gt = jnp.array([[2.0, 0.5, 0.0], [3.0, -1.0, np.pi]])
    g = jax.grad(lambda e: metrics.ate(e, gt))(gt)
    assert np.all(np.isfinite(g))
    g = jax.grad(lambda e: metrics.abs_errors(e, gt).sum())(gt + 1e-3)
    assert np.all(np.isfinite(g))
    g = jax.grad(lambda p: frames.roll_pitch_yaw(frames.se3_from_xypsi(p)).sum())(jnp.zeros(3))
    assert np.all(np.isfinite(g))


def test_ate_of_a_non_finite_estimate_is_nan_not_zero():
    gt = jnp.array([[2.0, 0.5, 0.0], [3.0, -1.0, 0.5]])
    assert np.isnan(float(metrics.ate(gt.at[1, 0].set(jnp.nan), gt)))
    assert float(metrics.ate(gt, gt)) == 0.0
