"""Synthetic data: trajectories, odometry noise, BOP/TUM writing and reading, consistency
against an independent renderer (trimesh ray casting), determinism, bad input, input pipeline."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from rhaml_jax import data, planar
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import write_scenario, write_training_set
from rhaml_jax.errors import RhamlError

SMALL = DEFAULT_CAMERA.resized(160, 120)


def _check_heading_is_travel(p):
    """Heading = direction of travel: against central differences of the positions."""
    d = p[2:, :2] - p[:-2, :2]
    np.testing.assert_allclose(np.cos(p[1:-1, 2] - np.arctan2(d[:, 1], d[:, 0])), 1.0, atol=1e-3)


def test_circle_and_sine_match_design_formulas():
    c = data.circle(500)
    th = np.pi + 2 * np.pi * np.arange(500) / 500
    np.testing.assert_allclose(c[:, :2], np.c_[4.5 + 2 * np.cos(th), 2 * np.sin(th)], atol=1e-6)
    np.testing.assert_allclose(c[0, :2], [2.5, 0.0], atol=1e-12)
    # Counter-clockwise, heading = direction of travel (finite differences of the positions).
    _check_heading_is_travel(c)
    r0, r1 = c[0, :2] - [4.5, 0], c[1, :2] - [4.5, 0]
    assert r0[0] * r1[1] - r0[1] * r1[0] > 0  # counter-clockwise
    s = data.sine(500)
    u = np.linspace(0, 1, 500)
    np.testing.assert_allclose(s[:, :2], np.c_[4.5 + 2.5 * np.sin(4 * np.pi * u), -1.2 + 2.4 * u], atol=1e-6)
    _check_heading_is_travel(s)
    assert 1.9 < s[:, 0].min() and s[:, 0].max() < 7.1  # the paper's 5 m of depth variation


@pytest.mark.parametrize("name", ["circle", "sine", "rendezvous"])
def test_scaled_scenarios_scale_every_distance_and_no_heading(name):
    from rhaml_jax.data._writer import scenario_poses

    (ref, ref_bounds), (small, bounds) = scenario_poses(name, 60, 3), scenario_poses(name, 60, 3, 0.39)
    assert scenario_poses(name, 60, 3, 1.0)[1] == ref_bounds  # scale 1: DESIGN.md's scenarios
    np.testing.assert_allclose(bounds, 0.39 * np.asarray(ref_bounds))
    for a, b in zip(ref, small):
        for truth_a, truth_b in zip(a[1:3], b[1:3]):
            np.testing.assert_allclose(truth_b[:, :2], 0.39 * truth_a[:, :2], atol=1e-12)
            np.testing.assert_array_equal(truth_b[:, 2], truth_a[:, 2])
    with pytest.raises(RhamlError, match="--scale 0"):
        scenario_poses(name, 60, 3, 0.0)


def test_scaled_synth_config_scales_the_working_range():
    cfg = data.SynthConfig()
    assert cfg.scaled(1.0) is cfg and cfg.scaled(0.5).depth_m == (0.5, 4.0)
    with pytest.raises(RhamlError, match="--scale -1"):
        cfg.scaled(-1.0)


def test_odometry_noise_model():
    truth = data.circle(500)
    a, b = data.noisy_odometry(truth, seed=3), data.noisy_odometry(truth, seed=3)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a[0], truth[0])
    # Per-step increment errors have the design's sigmas (2 % of the step, 0.5 deg per metre).
    steps = planar.between(truth[:-1], truth[1:])
    L = np.hypot(steps[:, 0], steps[:, 1])
    errs = []
    for seed in range(40):
        o = data.noisy_odometry(truth, seed=seed)
        errs.append((planar.between(o[:-1], o[1:]) - steps) / np.c_[0.02 * L, 0.02 * L, np.radians(0.5) * L])
    z = np.concatenate(errs)
    np.testing.assert_allclose(z.std(axis=0), 1.0, atol=0.03)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.03)


def test_tum_round_trip(tmp_path):
    p = data.sine(50)
    data.write_tum(tmp_path / "t.txt", p)
    t, q = data.read_tum(tmp_path / "t.txt")
    np.testing.assert_allclose(q, p, atol=1e-8)
    assert len(t) == 50 and t[1] > t[0]
    (tmp_path / "bad.txt").write_text("0 1 2 3\n")
    with pytest.raises(RhamlError, match=r"bad.txt:1: expected 8"):
        data.read_tum(tmp_path / "bad.txt")


@pytest.fixture(scope="module")
def training_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("train") / "set"
    write_training_set(out, "pioneer3dx", SMALL, seed=7, num=180, negatives=20, workers=1)
    return out


def _raycast_mask(model, T_m2c: np.ndarray, K: np.ndarray, w: int, h: int) -> np.ndarray:
    """Independent reference: trimesh ray casting from each pixel centre (inside a box around
    the projected model, for speed)."""
    import trimesh

    v = model.vertices @ T_m2c[:3, :3].T + T_m2c[:3, 3]
    mesh = trimesh.Trimesh(v, model.faces, process=False)
    uv = v[:, :2] / v[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    x0, y0 = np.clip(np.floor(uv.min(0)) - 2, 0, [w - 1, h - 1]).astype(int)
    x1, y1 = np.clip(np.ceil(uv.max(0)) + 2, 0, [w - 1, h - 1]).astype(int)
    mask = np.zeros((h, w), bool)
    if x1 < x0 or y1 < y0:
        return mask
    us, vs = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
    d = np.stack([(us - K[0, 2]) / K[0, 0], (vs - K[1, 2]) / K[1, 1], np.ones(us.shape)], -1).reshape(-1, 3)
    hit = trimesh.ray.ray_triangle.RayMeshIntersector(mesh).intersects_any(np.zeros_like(d), d)
    mask[y0 : y1 + 1, x0 : x1 + 1] = hit.reshape(us.shape)
    return mask


def test_generated_masks_match_ray_casting(training_set):
    model = data.load_bop_model(training_set)
    np.testing.assert_allclose(model.extents, [0.455, 0.381, 0.237], atol=1e-3)  # PLY in mm, read back in m
    frames = data.read_bop(training_set, split=None)
    assert len(frames) == 200 and sum(f.observed for f in frames) == 180
    ious = []
    for f in frames:
        if not f.observed:
            continue
        ref = _raycast_mask(model, f.T_m2c, f.K, SMALL.width, SMALL.height)
        got = data.load_mask(f.mask)
        ious.append((ref & got).sum() / max((ref | got).sum(), 1))
    ious = np.asarray(ious)
    assert ious.min() >= 0.98, (ious.min(), np.argsort(ious)[:5])


def test_generated_set_layout_and_labels(training_set):
    info = json.loads((training_set / "models" / "models_info.json").read_text())["1"]
    assert 450 < info["size_x"] < 460 and info["diameter"] > info["size_x"]
    cam = json.loads((training_set / "camera.json").read_text())
    assert (cam["width"], cam["height"]) == (160, 120)
    frames = data.read_bop(training_set, split=None)
    splits = {f.split for f in frames}
    assert splits == {"train", "val", "test"}
    heights = np.array([f.camera_height_m for f in frames])
    assert 0.2 < heights.mean() < 0.4 and 0.02 < heights.std() < 0.09  # N(0.30, 0.05^2)
    poses = np.array([f.xypsi for f in frames if f.observed])
    assert poses[:, 0].min() >= 1.0 - 1e-6 and poses[:, 0].max() <= 8.0 + 1e-6
    for f in frames[:20]:
        gt_info = json.loads((f.rgb.parents[1] / "scene_gt_info.json").read_text())[str(f.im_id)]
        assert (len(gt_info) == 1) == f.observed


def test_generation_is_deterministic(training_set, tmp_path):
    out = tmp_path / "again"
    write_training_set(out, "pioneer3dx", SMALL, seed=7, num=180, negatives=20, workers=1, chunk=200)
    for rel in ("train/000000/rgb/000005.png", "val/000000/rgb/000000.png", "train/000000/scene_gt.json", "models/obj_000001.ply"):
        assert (out / rel).read_bytes() == (training_set / rel).read_bytes(), rel


def test_interrupted_generation_resumes(training_set, tmp_path):
    """A run stopped before a scene's JSON was written redoes only that scene, to the same bytes."""
    out = tmp_path / "resumed"
    shutil.copytree(training_set, out)
    (out / "val/000000/scene_gt.json").unlink()
    (out / "val/000000/rgb/000003.png").unlink()
    kept = (out / "train/000000/rgb/000000.png").stat().st_mtime_ns
    write_training_set(out, "pioneer3dx", SMALL, seed=7, num=180, negatives=20, workers=1)
    assert (out / "train/000000/rgb/000000.png").stat().st_mtime_ns == kept  # complete scene skipped
    for rel in ("val/000000/scene_gt.json", "val/000000/rgb/000003.png", "val/000000/scene_gt_info.json"):
        assert (out / rel).read_bytes() == (training_set / rel).read_bytes(), rel


def test_scenario_files(tmp_path):
    out = tmp_path / "circle"
    write_scenario(out, "circle", "pioneer3dx", SMALL, seed=0, frames=24, workers=1)
    scene = out / "test" / "000000"
    t, observed = data.read_tum(scene / "observed_groundtruth.txt")
    _, observer = data.read_tum(scene / "observer_groundtruth.txt")
    _, odo = data.read_tum(scene / "observed_odometry.txt")
    np.testing.assert_allclose(observed, data.circle(24), atol=1e-6)
    np.testing.assert_allclose(observer, 0.0, atol=1e-12)
    np.testing.assert_allclose(odo[0], observed[0], atol=1e-9)
    frames = data.read_bop(out)
    assert [f.im_id for f in frames] == list(range(24)) == list(range(len(t)))  # TUM rows = images
    for f in frames:
        if f.observed:
            np.testing.assert_allclose(f.xypsi[:2], observed[f.im_id, :2], atol=1e-4)
    assert sum(f.observed for f in frames) >= 20


def test_rendezvous_scenario(tmp_path):
    out = tmp_path / "rv"
    write_scenario(out, "rendezvous", "pioneer3dx", SMALL, seed=1, frames=30, workers=1)
    _, a0 = data.read_tum(out / "test/000000/observer_groundtruth.txt")
    _, b1 = data.read_tum(out / "test/000001/observed_groundtruth.txt")
    np.testing.assert_allclose(a0, b1, atol=1e-9)  # scene 1 is robot B's camera looking at A
    _, oa0 = data.read_tum(out / "test/000000/observer_odometry.txt")
    _, oa1 = data.read_tum(out / "test/000001/observed_odometry.txt")
    np.testing.assert_allclose(oa0, oa1, atol=1e-9)
    _, b0 = data.read_tum(out / "test/000000/observed_groundtruth.txt")
    for f in data.read_bop(out, scene=0):
        if f.observed:
            np.testing.assert_allclose(f.xypsi[:2], planar.between(a0[f.im_id], b0[f.im_id])[:2], atol=1e-4)


# ----------------------------------------------------------------------------- bad input


@pytest.fixture()
def small_copy(training_set, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(training_set, dst)
    return dst


def _edit_json(path: Path, fn):
    d = json.loads(path.read_text())
    fn(d)
    path.write_text(json.dumps(d))


def test_mixed_sets_read_as_one(training_set, tmp_path):
    """fit's curriculum trains on v3 and v1 images as one set: every frame of each, once, with its
    own labels; a set of another camera is refused by name and nothing is linked."""
    other = tmp_path / "v1"
    write_training_set(other, "pioneer3dx", SMALL, seed=8, num=6, negatives=0, workers=1, cfg=data.SynthConfig(appearance=None))
    counts = data.mix_sets(tmp_path / "mix", [training_set, other])
    assert data.mix_sets(tmp_path / "mix", [training_set, other]) == counts  # run again: nothing changes
    for split in ("train", "val"):
        mixed = data.read_bop(tmp_path / "mix", split)
        parts = [data.read_bop(s, split) for s in (training_set, other)]
        assert len(mixed) == sum(len(p) for p in parts)
        np.testing.assert_array_equal(np.stack([f.K for f in mixed]), np.stack([f.K for p in parts for f in p]))
        assert sorted(map(str, (f.rgb.resolve() for f in mixed))) == sorted(str(f.rgb.resolve()) for p in parts for f in p)
    wide = tmp_path / "wide"
    write_training_set(wide, "pioneer3dx", DEFAULT_CAMERA.resized(200, 150), seed=8, num=2, negatives=0, workers=1)
    with pytest.raises(RhamlError, match="wide/camera.json differs .*not the same robot and camera"):
        data.mix_sets(tmp_path / "mix2", [training_set, wide])
    assert not (tmp_path / "mix2").exists()


def test_corrupt_png(small_copy):
    p = small_copy / "train/000000/rgb/000003.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(RhamlError, match="000003.png: cannot decode"):
        data.load_rgb(p)


def test_missing_gt_entry(small_copy):
    _edit_json(small_copy / "train/000000/scene_gt.json", lambda d: d.pop("4"))
    with pytest.raises(RhamlError, match=r"scene_gt.json: no entry for image 4"):
        data.read_bop(small_copy)


def test_ids_do_not_match(small_copy):
    (small_copy / "train/000000/rgb/000002.png").rename(small_copy / "train/000000/rgb/000999.png")
    with pytest.raises(RhamlError, match="image ids do not match"):
        data.read_bop(small_copy)


def test_K_wrong_shape(small_copy):
    _edit_json(small_copy / "train/000000/scene_camera.json", lambda d: d["1"].update(cam_K=[1, 2, 3]))
    with pytest.raises(RhamlError, match=r"scene_camera.json: image 1 cam_K: expected 9"):
        data.read_bop(small_copy)


def test_model_in_wrong_units(small_copy, tmp_path):
    from rhaml_jax.robots import load_robot

    load_robot("pioneer3dx").to_trimesh().export(small_copy / "models" / "obj_000001.ply")  # metres
    with pytest.raises(RhamlError, match="millimetres"):
        data.load_bop_model(small_copy)


def test_reads_blenderproc_layout(tmp_path):
    """Another tool's BOP scene: train_pbr, JPEG images, several objects, no cam_*_w2c."""
    import cv2

    scene = tmp_path / "bp" / "train_pbr" / "000000"
    (scene / "rgb").mkdir(parents=True)
    (scene / "mask_visib").mkdir()
    cv2.imwrite(str(scene / "rgb" / "000000.jpg"), np.zeros((48, 64, 3), np.uint8))
    cv2.imwrite(str(scene / "mask_visib" / "000000_000001.png"), np.zeros((48, 64), np.uint8))
    K = [50.0, 0, 32, 0, 50, 24, 0, 0, 1]
    (scene / "scene_camera.json").write_text(json.dumps({"0": {"cam_K": K, "depth_scale": 0.1}}))
    R = np.eye(3).reshape(-1).tolist()
    (scene / "scene_gt.json").write_text(json.dumps({"0": [{"obj_id": 5, "cam_R_m2c": R, "cam_t_m2c": [0, 0, 900]},
                                                           {"obj_id": 1, "cam_R_m2c": R, "cam_t_m2c": [100, 0, 2000]}]}))
    frames = data.read_bop(tmp_path / "bp")
    assert len(frames) == 1 and frames[0].observed and frames[0].mask.name == "000000_000001.png"
    np.testing.assert_allclose(frames[0].T_m2c[:3, 3], [0.1, 0, 2.0])
    assert data.load_rgb(frames[0].rgb).shape == (48, 64, 3)


# ----------------------------------------------------------------------------- input pipeline


def test_pipeline_is_a_pure_function_of_step(training_set):
    src = data.FromDisk(training_set, 64, 48, split="train")
    a = data.make_batch_fn(src, 6, seed=2)
    b = data.make_batch_fn(src, 6, seed=2)
    for step in (0, 1, 5):
        x, y = a(step), b(step)
        np.testing.assert_array_equal(x.images, y.images)
        np.testing.assert_array_equal(x.pose, y.pose)
    first = a(0)
    assert first.images.shape == (6, 48, 64, 3) and first.images.dtype == np.float32
    assert 0.0 <= first.images.min() and first.images.max() <= 1.0
    # A resumed run (a new batch_fn started at step 5, nothing cached) sees what an
    # uninterrupted one does.
    fresh = data.FromDisk(training_set, 64, 48, split="train", cache_bytes=0)
    np.testing.assert_array_equal(data.make_batch_fn(fresh, 6, seed=2)(5).images, a(5).images)
    # Every training example is seen once per epoch.
    idx = np.concatenate([data._pipeline.indices_for_step(s, 6, src.size, 2) for s in range(src.size // 6)])
    assert len(np.unique(idx)) == len(idx)


def test_on_the_fly_source_matches_generated_pixels():
    src = data.OnTheFly("pioneer3dx", 160, 120, seed=7)
    img, obs, pose = src.example(3)
    from rhaml_jax.render import as_mesh
    from rhaml_jax.robots import load_robot

    s = data.training_sample(as_mesh(load_robot("pioneer3dx")), SMALL, 7, 3)
    np.testing.assert_array_equal(img, s.rgb)
    assert obs == float(s.observed)


def test_augment_range_and_determinism():
    import jax

    imgs = np.random.default_rng(0).random((4, 24, 32, 3)).astype(np.float32)
    a = np.asarray(data.augment(jax.random.PRNGKey(1), imgs))
    b = np.asarray(data.augment(jax.random.PRNGKey(1), imgs))
    c = np.asarray(data.augment(jax.random.PRNGKey(2), imgs))
    np.testing.assert_array_equal(a, b)
    assert a.shape == imgs.shape and 0 <= a.min() and a.max() <= 1
    assert np.abs(a - imgs).mean() > 1e-3 and np.abs(a - c).mean() > 1e-3


def test_augment_effects_on_a_fraction_and_noise_level():
    """Blur and JPEG (`_on_some`) touch p B whole images of a batch (rounded at random); the
    noise is zero-mean with a standard deviation within the configured maximum."""
    import jax

    imgs = np.random.default_rng(1).uniform(0.2, 0.8, (10, 24, 32, 3)).astype(np.float32)
    off = dict(brightness=0.0, contrast=0.0, saturation=0.0, gain=0.0, blur_prob=0.0, jpeg_prob=0.0, noise=0.0)
    key = jax.random.PRNGKey(3)
    np.testing.assert_allclose(np.asarray(data.augment(key, imgs, data.AugmentConfig(**off))), imgs, atol=1e-6)
    from rhaml_jax.data._augment import _on_some

    def changed(prob, key, x):  # an effect that always shows: + strength + 1
        out = np.asarray(_on_some(key, x, prob, lambda im, s: im + s + 1.0, 0.5))
        d = np.abs(out - x).reshape(len(x), -1)
        assert ((d.min(axis=1) >= 1.0) | (d.max(axis=1) == 0.0)).all()  # whole images, or none of it
        return int((d.min(axis=1) >= 1.0).sum())

    assert changed(0.3, key, imgs) == 3 and changed(0.0, key, imgs) == 0 and changed(1.0, key, imgs) == 10
    # 5.5 of 10: 5 or 6; one image with chance 0.3: each image's chance stays 0.3
    assert {changed(0.55, jax.random.PRNGKey(i), imgs) for i in range(40)} == {5, 6}
    assert 0.2 < np.mean([changed(0.3, jax.random.PRNGKey(i), imgs[:1]) for i in range(100)]) < 0.4
    out = np.asarray(data.augment(key, imgs, data.AugmentConfig(**(off | {"noise": 0.05}))))
    d = (out - imgs).reshape(10, -1)
    assert np.abs(d.mean(axis=1)).max() < 0.005
    assert d.std(axis=1).max() <= 0.05 * 1.05 and d.std(axis=1).max() > 0.01


def test_network_image_keeps_bearings():
    """A point seen through another camera lands, after network_image, where the network's
    camera would see it (the residual homography); the network's own camera is a plain resize."""
    import cv2

    from rhaml_jax.camera import Camera, project

    hw = (128, 160)
    K_net = DEFAULT_CAMERA.resized(hw[1], hw[0]).K
    other = Camera(fx=520.0, fy=515.0, cx=410.0, cy=290.0, width=800, height=600)
    for p in ([0.3, -0.2, 3.0], [-0.6, 0.25, 2.0]):  # optical frame, metres
        uv = np.asarray(project(other.K, np.array(p))[0])
        img = np.zeros((600, 800, 3), np.uint8)
        cv2.circle(img, (int(round(uv[0] * 8)), int(round(uv[1] * 8))), 40, (255, 255, 255), -1, shift=3)
        out = data.network_image(img, other.K, hw)[..., 0].astype(np.float64)
        ys, xs = np.mgrid[: hw[0], : hw[1]]
        centre = np.array([(xs * out).sum(), (ys * out).sum()]) / out.sum()
        np.testing.assert_allclose(centre, np.asarray(project(K_net, np.array(p))[0]), atol=0.35)
    img = np.random.default_rng(0).integers(0, 255, (480, 640, 3), np.uint8)
    np.testing.assert_array_equal(data.network_image(img, DEFAULT_CAMERA.K, hw),
                                  cv2.resize(img, (160, 128), interpolation=cv2.INTER_AREA))
    with pytest.raises(RhamlError, match="RGB"):
        data.network_image(img[..., 0], DEFAULT_CAMERA.K, hw)


def test_image_cache_keeps_images_within_its_budget():
    from rhaml_jax.data._cache import ImageCache

    loads = []

    def load(i):
        loads.append(i)
        return np.full((10, 10, 3), i, np.uint8)  # 300 bytes

    cache = ImageCache(max_bytes=700)
    for i in (0, 1, 2, 0, 1, 2):
        np.testing.assert_array_equal(cache.get(i, lambda: load(i)), i)
    assert loads == [0, 1, 2, 2] and len(cache) == 2 and cache.nbytes == 600  # the third never fits
    none = ImageCache(max_bytes=0)
    none.get(0, lambda: load(0))
    none.get(0, lambda: load(0))
    assert len(none) == 0 and loads[-2:] == [0, 0]


def test_one_process_renders_each_robot_with_its_own_mesh(tmp_path):
    """In-process rendering (workers=1) of two robots one after the other: the second set's
    masks are the second robot's (its mesh was once cached under the first's)."""
    import trimesh

    from rhaml_jax.data import load_mask, read_bop
    from rhaml_jax.robots import load_robot

    m = load_robot("pioneer3dx")
    small = tmp_path / "small_pioneer.obj"
    trimesh.Trimesh(np.asarray(m.vertices) * 0.4, np.asarray(m.faces), process=False).export(small)
    area = {}
    for robot in ("pioneer3dx", str(small)):
        out = tmp_path / Path(robot).stem
        write_scenario(out, "circle", robot, DEFAULT_CAMERA.resized(160, 120), 0, frames=6, workers=1)
        area[robot] = sum(int(load_mask(f.mask).sum()) for f in read_bop(out) if f.observed)
    assert area[str(small)] < 0.3 * area["pioneer3dx"]  # 0.4 x the size: 0.16 x the pixels
