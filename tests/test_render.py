"""Renderer: hard rasterizer against trimesh ray casting, soft silhouette limits, gradients
(custom VJP vs XLA autodiff vs central finite differences in float64), robustness, bad input."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
import trimesh

from rhaml_jax import render as R
from rhaml_jax.camera import Camera, T_cam_robot
from rhaml_jax.errors import RhamlError
from rhaml_jax.robots import load_robot
from tests._render_ref import iou, random_views, raycast
from tests.conftest import shared_path

CAM = Camera(200.0, 200.0, 160.0, 120.0, 320, 240)  # the default camera's view at half size
TINY = Camera(40.0, 40.0, 32.0, 24.0, 64, 48)  # the same view at 64 x 48, for many poses


@functools.lru_cache(maxsize=None)
def builtin() -> R.Mesh:
    return R.as_mesh(load_robot("pioneer3dx"))


def numpy_cam(T: jaxlie.SE3, vertices) -> np.ndarray:
    M = np.asarray(T.as_matrix(), np.float64)
    return np.asarray(vertices, np.float64) @ M[:3, :3].T + M[:3, 3]


def view(x, y, psi, h=0.30, dtype=jnp.float32) -> jaxlie.SE3:
    T_obs = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_z_radians(jnp.asarray(psi, dtype)), jnp.asarray([x, y, 0.0], dtype))
    T = T_cam_robot(h) @ T_obs
    return jaxlie.SE3(T.wxyz_xyz.astype(dtype))


def crop_box(mesh, T, cam=CAM, grow=1.3):
    """Square box around the projected model (as the refiner's zoom-in does)."""
    uv = numpy_cam(T, mesh.vertices) @ np.asarray(cam.K).T
    uv = uv[:, :2] / uv[:, 2:3]
    c, half = (uv.min(0) + uv.max(0)) / 2, grow * (uv.max(0) - uv.min(0)).max() / 2
    return jnp.asarray([c[0] - half, c[1] - half, c[0] + half, c[1] + half], jnp.float32)


# ---------------------------------------------------------------- hard rasterizer vs ray casting


@functools.lru_cache(maxsize=None)
def fifty_views(model_key):
    """(mesh, poses, full renders) of 50 random views; shared so that compilations are too."""
    model = load_robot("pioneer3dx") if model_key == "builtin" else load_robot(model_key)
    mesh = R.as_mesh(model)
    Ts = random_views(50, seed=3)
    return mesh, Ts, R.render(mesh, Ts, CAM.K, CAM.width, CAM.height)


def _against_raycast(model_key):
    mesh, Ts, out = fifty_views(model_key)
    assert int(out.pairs.max()) > 0
    ious, errs = [], []
    for i in range(50):
        ref_mask, ref_depth = raycast(numpy_cam(jaxlie.SE3(Ts.wxyz_xyz[i]), mesh.vertices), mesh.faces, CAM.K,
                                      CAM.width, CAM.height)
        mask = np.asarray(out.mask[i])
        ious.append(iou(mask, ref_mask))
        both = mask & ref_mask
        errs.append(np.abs(np.asarray(out.depth[i])[both] - ref_depth[both]))
    assert min(ious) >= 0.98, f"IoU per view: min {min(ious):.4f}, mean {np.mean(ious):.4f}"
    assert np.median(np.concatenate(errs)) < 1e-3
    rgb = np.asarray(out.rgb)
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0 and rgb.max() <= 1
    assert np.all(rgb[~np.asarray(out.mask)] == 0) and np.all(np.asarray(out.depth)[~np.asarray(out.mask)] == 0)


def test_hard_mask_and_depth_match_raycasting_builtin():
    _against_raycast("builtin")


def test_hard_mask_and_depth_match_raycasting_urdf():
    _against_raycast(str(shared_path("robots", "pioneer3dx", "urdf", "pioneer3dx.urdf")))


def test_model_partly_behind_the_camera_is_clipped_not_lost():
    box = trimesh.creation.box(extents=(0.6, 0.4, 3.0))
    box.apply_translation((0.25, 0.1, 0.5))  # from z = -1 to z = 2: straddles the camera plane
    T = jaxlie.SE3.identity()
    out = R.render((box.vertices, box.faces), T, TINY.K, TINY.width, TINY.height)
    ref_mask, ref_depth = raycast(np.asarray(box.vertices), box.faces, TINY.K, TINY.width, TINY.height)
    mask = np.asarray(out.mask[...])
    assert ref_mask.sum() > 200 and iou(mask, ref_mask) >= 0.98
    both = mask & ref_mask
    assert np.median(np.abs(np.asarray(out.depth)[both] - ref_depth[both])) < 1e-3


def test_lambertian_shading_of_a_square_facing_the_camera():
    v = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    colors = np.array([[1.0, 0.5, 0.0], [1.0, 0.5, 0.0]], np.float32)
    out = R.render((v, f, colors), jaxlie.SE3.identity(), TINY.K, TINY.width, TINY.height, ambient=0.2, diffuse=0.7)
    light = np.asarray(R.DEFAULT_LIGHT) / np.linalg.norm(R.DEFAULT_LIGHT)
    shade = 0.2 + 0.7 * max(0.0, -light[2])  # normal (0, 0, -1), towards the camera
    np.testing.assert_allclose(np.asarray(out.rgb)[24, 32], [shade, 0.5 * shade, 0.0], rtol=1e-5)
    np.testing.assert_allclose(np.asarray(out.depth)[out.mask], 2.0, rtol=1e-5)


def test_crop_equals_the_shifted_full_image():
    mesh, Ts, full = fifty_views("builtin")
    dx, dy = 37, -21  # a crop box with edges on pixel borders, at the same scale, shifted
    box = jnp.asarray([dx - 0.5, dy - 0.5, dx + CAM.width - 0.5, dy + CAM.height - 0.5])
    crop = R.render(mesh, Ts, CAM.K, CAM.width, CAM.height, box=box)
    a = np.asarray(crop.mask)[:, -dy:, : CAM.width - dx]
    b = np.asarray(full.mask)[:, : CAM.height + dy, dx:]
    assert a.sum() > 1000
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(np.asarray(crop.depth)[:, -dy:, : CAM.width - dx],
                               np.asarray(full.depth)[:, : CAM.height + dy, dx:], rtol=2e-5)


# ---------------------------------------------------------------- soft silhouette


def two_views():
    return jaxlie.SE3(jnp.stack([view(2.5, 0.2, 0.3).wxyz_xyz, view(0.8, 0.3, 2.0).wxyz_xyz]))


def test_soft_silhouette_tends_to_the_hard_one():
    mesh, Ts = builtin(), two_views()
    box = jnp.asarray([100.0, 80.0, 220.0, 200.0])
    hard = np.asarray(R.render(mesh, Ts, CAM.K, 32, 32, box=box).mask, np.float32)
    assert hard.sum() > 200
    errs = [float(np.abs(np.asarray(R.silhouette(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=k)) - hard).mean())
            for k in (0.5, 2.0, 8.0, 32.0, 1e4)]
    assert all(a > b for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 1e-3, errs


def test_binning_matches_all_pairs():
    mesh, Ts = builtin(), two_views()
    box = jnp.asarray([100.0, 80.0, 220.0, 200.0])
    a = R.silhouette(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=1.0)
    b = R.silhouette_naive(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=1.0)
    assert float(a.max()) > 0.9
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=2e-5)


def test_closed_winding_agrees_with_trimesh():
    """`Mesh.winding`: +1 for a closed surface wound outwards (trimesh: watertight, consistently
    wound, positive volume), -1 wound inwards, 0 with a face missing, repeated or turned."""
    robot = load_robot("pioneer3dx")
    hull = trimesh.convex.convex_hull(np.random.default_rng(0).normal(size=(40, 3)))
    for m in (hull, trimesh.creation.box(), trimesh.Trimesh(robot.vertices, robot.faces, process=False)):
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0
        v, f = np.asarray(m.vertices), np.asarray(m.faces)
        turned = f.copy()
        turned[0] = turned[0, ::-1]
        assert float(R.as_mesh((v, f)).winding) == 1.0
        assert float(R.as_mesh((v, f[:, ::-1])).winding) == -1.0
        for bad in (f[1:], np.concatenate([f, f[:1]]), turned):
            assert float(R.as_mesh((v, bad)).winding) == 0.0
    assert float(builtin().winding) == 1.0


def test_culled_back_faces_change_no_pixel_of_the_hard_render():
    """A closed mesh's back faces are skipped (fewer pairs) and the mask and depth are the same as
    with them (winding 0) in 50 random views (a camera inside a closed box: the test above)."""
    mesh, Ts, out = fifty_views("builtin")
    kept = R.render(mesh._replace(winding=jnp.float32(0.0)), Ts, CAM.K, CAM.width, CAM.height)
    assert np.median(np.asarray(out.pairs) / np.asarray(kept.pairs)) < 0.7
    np.testing.assert_array_equal(np.asarray(out.mask), np.asarray(kept.mask))
    np.testing.assert_array_equal(np.asarray(out.depth), np.asarray(kept.depth))
    # colours differ only where a back face tied a front one in depth and won on its face id
    assert np.mean(np.any(np.asarray(out.rgb) != np.asarray(kept.rgb), -1)) < 1e-4


def test_a_culled_soft_silhouette_is_binned_right_and_its_edge_nearer_the_hard_one():
    """`RenderConfig.soft_cull`: the binned silhouette equals every pixel against every face (culled
    alike) with fewer pairs visited, and at sharpness 8 per px its area is smaller than the uncut
    one's (whose edges are the union of a front and a back face) and on average nearer the hard
    silhouette's (area coverage; seams between front faces darken a little inside)."""
    mesh, Ts = builtin(), two_views()
    box = jnp.asarray([100.0, 80.0, 220.0, 200.0])
    cull = R.RenderConfig(soft_cull=True)
    a = R.silhouette(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=1.0, config=cull)
    b = R.silhouette_naive(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=1.0, config=cull)
    assert float(a.max()) > 0.9
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=2e-5)
    pairs = [np.asarray(R.pairs_needed(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=1.0, config=c)) for c in (cull, R.RenderConfig())]
    assert np.all(pairs[0] < 0.7 * pairs[1]), pairs
    hard = np.asarray(R.render(mesh, Ts, CAM.K, 128, 128, box=box).mask, np.float32).reshape(2, 32, 4, 32, 4).mean((2, 4))
    area = [np.asarray(R.silhouette(mesh, Ts, CAM.K, 32, 32, box=box, sharpness=8.0, config=c)).sum((1, 2)) / hard.sum((1, 2))
            for c in (cull, R.RenderConfig())]
    assert np.all(area[0] < area[1]) and np.mean(np.abs(area[0] - 1)) < np.mean(np.abs(area[1] - 1)), area


def _loss_fn(mesh, K, sharpness, config):
    def loss(delta, T0, box, target):
        T = T0 @ jaxlie.SE3.exp(delta)
        sil = R.silhouette(mesh, T, K, 32, 32, box=box, sharpness=sharpness, config=config)
        return jnp.sum((sil - target) ** 2)

    return loss


def test_pose_gradient_matches_finite_differences_and_autodiff_float64():
    """Custom VJP vs central finite differences (rel. err <= 1e-2) and vs XLA's reverse mode."""
    with jax.enable_x64(True):
        mesh = R.as_mesh(load_robot("pioneer3dx"), dtype=jnp.float64)
        K = jnp.asarray(CAM.K, jnp.float64)
        loss = jax.jit(_loss_fn(mesh, K, 1.0, R.RenderConfig()))
        grad = jax.jit(jax.grad(loss))
        # XLA's reverse mode needs a loop of fixed length: room for every pair of these views.
        # (4 px blocks as the custom VJP's backward pass; its forward uses 8 px blocks.)
        auto = R.RenderConfig(vjp="autodiff", capacity=12288, soft_block=4)
        grad_auto = jax.jit(jax.grad(_loss_fn(mesh, K, 1.0, auto)))
        for i, (x, y, psi) in enumerate([(2.0, 0.2, 0.6), (4.5, -0.8, 2.5), (1.2, 0.1, -1.3)]):
            T0 = view(x, y, psi, dtype=jnp.float64)
            box = crop_box(mesh, T0).astype(jnp.float64)
            target = R.silhouette(mesh, view(x + 0.05, y - 0.04, psi + 0.1, dtype=jnp.float64), K, 32, 32, box=box)
            g = np.asarray(grad(jnp.zeros(6), T0, box, target))
            h = 1e-6
            fd = np.array([(loss(h * e, T0, box, target) - loss(-h * e, T0, box, target)) / (2 * h) for e in np.eye(6)])
            rel = np.linalg.norm(g - fd) / np.linalg.norm(fd)
            assert rel <= 1e-2, (g, fd, rel)
            if i == 0:
                assert int(R.pairs_needed(mesh, T0, K, 32, 32, box=box, sharpness=1.0, config=auto)) <= 12288
                g_auto = np.asarray(grad_auto(jnp.zeros(6), T0, box, target))
                np.testing.assert_allclose(g, g_auto, rtol=1e-6, atol=1e-9 * np.abs(g_auto).max())


def _degenerate_model():
    m = load_robot("pioneer3dx")
    v = np.concatenate([m.vertices, [[0.1, 0.0, 0.1], [0.2, 0.0, 0.1], [0.3, 0.0, 0.1]]]).astype(np.float32)
    n = len(m.vertices)
    extra = np.array([[n, n, n + 1], [n, n + 1, n + 2], [n + 2, n + 2, n + 2]])  # zero-area faces
    return (v, np.concatenate([m.faces, extra]))


def _hard_poses(n, seed):
    """Random rotations and positions around the camera: behind it, straddling it, partly out of
    view, far; plus views with the camera in the plane of the top plate (edge-on faces)."""
    rng = np.random.default_rng(seed)
    key = jax.random.PRNGKey(seed)
    R_ = jaxlie.SO3.sample_uniform(key, batch_axes=(n,))
    t = np.stack([rng.uniform(-2, 2, n), rng.uniform(-1, 1, n), rng.uniform(-1.5, 6, n)], 1)
    T = jaxlie.SE3.from_rotation_and_translation(R_, jnp.asarray(t, jnp.float32))
    k = n // 10  # edge-on: camera at the top plate's height (0.237 m)
    edge = T_cam_robot(0.237) @ jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_z_radians(jnp.asarray(rng.uniform(-np.pi, np.pi, k), jnp.float32)),
        jnp.asarray(np.stack([rng.uniform(0.3, 3, k), rng.uniform(-1, 1, k), np.zeros(k)], 1), jnp.float32))
    return jaxlie.SE3(jnp.concatenate([edge.wxyz_xyz, T.wxyz_xyz[k:]]))


def test_no_nan_or_inf_over_1000_hard_poses():
    mesh = R.as_mesh(_degenerate_model())
    Ts = _hard_poses(1000, seed=7)
    target = jnp.zeros((TINY.height, TINY.width)).at[10:30, 20:40].set(1.0)

    def loss(params):
        sil = R.silhouette(mesh, jaxlie.SE3(params), TINY.K, TINY.width, TINY.height, sharpness=2.0)
        return jnp.sum((sil - target) ** 2), sil

    (vals, sils), grads = jax.jit(lambda p: jax.lax.map(jax.value_and_grad(loss, has_aux=True), p))(Ts.wxyz_xyz)
    assert np.all(np.isfinite(np.asarray(vals))) and np.all(np.isfinite(np.asarray(grads)))
    sils = np.asarray(sils)
    assert np.all(np.isfinite(sils)) and sils.min() >= 0 and sils.max() <= 1
    assert (sils.max(axis=(1, 2)) > 0.5).sum() > 100  # many views do see the model
    out = R.render(mesh, Ts, TINY.K, TINY.width, TINY.height)
    for a in (out.rgb, out.depth):
        assert np.all(np.isfinite(np.asarray(a)))
    assert np.asarray(out.depth).min() >= 0


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "case, pattern",
    [
        ("nan_pose", "T_cam_model"),
        ("empty_model", "empty"),
        ("zero_crop", "box"),
        ("bad_sharpness", "sharpness"),
        ("bad_size", "width"),
        ("bad_K", "K"),
        ("not_se3", "T_cam_model"),
    ],
)
def test_bad_input_raises_a_clear_error(case, pattern):
    mesh, T, K, box, k, w = builtin(), view(2.0, 0.0, 0.0), CAM.K, None, 2.0, 32
    if case == "nan_pose":
        T = jaxlie.SE3(T.wxyz_xyz.at[4].set(jnp.nan))
    elif case == "empty_model":
        mesh = (np.zeros((0, 3)), np.zeros((0, 3), int))
    elif case == "zero_crop":
        box = jnp.asarray([10.0, 10.0, 10.0, 50.0])
    elif case == "bad_sharpness":
        k = -1.0
    elif case == "bad_size":
        w = 0
    elif case == "bad_K":
        K = np.zeros((3, 3))
    elif case == "not_se3":
        T = np.eye(4)
    for fn in (lambda: R.silhouette(mesh, T, K, w, 32, box=box, sharpness=k),
               lambda: R.render(mesh, T, K, w, 32, box=box) if case != "bad_sharpness" else R.silhouette(
                   mesh, T, K, w, 32, box=box, sharpness=k)):
        with pytest.raises(RhamlError, match=pattern) as info:
            fn()
        assert "\n" not in str(info.value)
