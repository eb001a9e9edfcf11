"""The learned refiner: the CLI trains and resumes, the checkpoint rebuilds the refiner and
refuses another robot, gradients reach the initial pose and the params, DeepIM's disentangled
update is exact for a known relative pose. Tiny config (refiner_micro) and data."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rhaml_jax import camera, frames, render
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import load_bop_model, load_rgb, read_bop
from rhaml_jax.errors import RhamlError
from rhaml_jax.refine import RefineConfig, StageParams, load_refiner, refine, refine_stage
from rhaml_jax.refine import net as N
from rhaml_jax.refine.train import RefinerBatch, RefinerSource
from tests.conftest import train_tiny


@pytest.fixture(scope="module")
def bop_set(tiny_bop_set):
    return tiny_bop_set


@pytest.fixture(scope="module")
def run(bop_set, tmp_path_factory):
    return train_tiny("refiner", "refiner_micro", bop_set, tmp_path_factory.mktemp("run"))


def test_cli_trains_resumes_and_logs(run):
    out, res, args = run
    rows = [json.loads(l) for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [2, 4] and all(np.isfinite(r["loss"]) for r in rows)
    assert "val_loss_pm" in rows[-1] and res["step"] == 4
    assert (out / "metrics.png").stat().st_size > 1000  # the curves fit's report shows
    from rhaml_jax.train import main

    with pytest.raises(RhamlError, match="already holds a checkpoint"):
        main(args)
    with pytest.raises(RhamlError, match="settings differ"):
        main(args[:-1] + ["--lr", "0.5", "--resume", "--no-progress"])


def test_init_fine_tunes_from_a_run(run, tmp_path):
    """--init: a refiner run starts at another run's weights (at learning rate 0 it ends there),
    also one of another config of the same network (a cascade's fine stage from a coarse one),
    records where they came from, and refuses a checkpoint of another network or kind."""
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta
    from rhaml_jax.train import main

    out, res, args = run
    a = dict(zip(args[::2], args[1::2]))
    tuned = main(["--stage", "refiner", "--config", "refiner_micro", "--data", a["--data"], "--out", str(tmp_path / "ft"),
                  "--init", str(out), "--steps", "2", "--batch", "2", "--lr", "0", "--warmup", "0", "--val-every", "2",
                  "--val-batches", "1", "--no-progress"])
    for x, y in zip(jax.tree.leaves(tuned["params"]), jax.tree.leaves(res["params"])):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert checkpoint_meta(tmp_path / "ft")["initialised_from"] == str(out)
    fine = main(["--stage", "refiner", "--config", "refiner_micro_fine", "--data", a["--data"], "--out",
                 str(tmp_path / "fine"), "--init", str(out), "--steps", "2", "--batch", "2", "--lr", "0", "--warmup", "0",
                 "--val-every", "2", "--val-batches", "1", "--no-progress"])  # another config of the same network
    for x, y in zip(jax.tree.leaves(fine["params"]), jax.tree.leaves(res["params"])):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert load_refiner(tmp_path / "fine").cfg.starts == "fine"
    with pytest.raises(RhamlError, match=r"--init .*holds a 'refiner_micro' refiner, whose network differs from --config 'refiner_cpu'"):
        main(["--stage", "refiner", "--config", "refiner_cpu", "--data", a["--data"], "--out", str(tmp_path / "x"),
              "--init", str(out), "--no-progress"])
    with pytest.raises(RhamlError, match=r"not a segmenter checkpoint"):
        main(["--stage", "segmenter", "--config", "segmenter_micro", "--data", a["--data"], "--out", str(tmp_path / "y"),
              "--init", str(out), "--no-progress"])


def test_checkpoint_refuses_another_robot(run, bop_set):
    out, _, _ = run
    model = load_bop_model(bop_set)
    ref = load_refiner(out, model)
    assert ref.cfg == N.get_refiner_config("refiner_micro")
    other = dataclasses.replace(model, vertices=model.vertices * 1.5)
    with pytest.raises(RhamlError, match="refiner checkpoint is for robot"):
        load_refiner(out, other)


def test_source_is_a_pure_function_of_seed_and_step(bop_set):
    cfg = N.get_refiner_config("refiner_micro")
    a, b = RefinerSource(bop_set, "train", cfg, 3, seed=2), RefinerSource(bop_set, "train", cfg, 3, seed=2)
    for x, y in zip(a(1), b(1)):
        np.testing.assert_array_equal(x, y)
    assert not np.allclose(a(0).T_init, a(1).T_init)


@pytest.mark.parametrize("config", ["refiner_micro", "refiner_micro_native"])
def test_repainted_renders_are_the_refiners_input_and_nothing_else_changes(bop_set, config):
    """`RefinerConfig.paint_prob`: at 1 every example renders a repainted robot (a part repainted
    whole), the rest of each example is the same as without (the paint has its own stream), and the
    network's input is the render in that paint; in the model's own paint the per-example render
    is the batched one the refiner ran before."""
    from rhaml_jax.data._appearance import color_groups
    from rhaml_jax.refine.train import painted_input, refiner_loss, render_input

    cfg = N.get_refiner_config(config)
    plain = RefinerSource(bop_set, "train", cfg, 3, seed=2)(0)
    painted = RefinerSource(bop_set, "train", dataclasses.replace(cfg, paint_prob=1.0), 3, seed=2)(0)
    model = load_bop_model(bop_set)
    own = np.asarray(model.face_colors, np.float32)
    np.testing.assert_array_equal(plain.paint, np.broadcast_to(own, plain.paint.shape))
    for field in RefinerBatch._fields[:-1]:
        np.testing.assert_array_equal(getattr(plain, field), getattr(painted, field))
    _, group = color_groups(own)
    for p in painted.paint:
        assert np.abs(p - own).max() > 0.05
        for g in np.unique(group):
            assert np.ptp(p[group == g], axis=0).max() == 0
    mesh = render.as_mesh(model)
    points = jnp.asarray(model.sample_surface(cfg.n_points, seed=0))
    params = N.init_params(cfg, jax.random.key(1))
    params = jax.tree.map(lambda a: a + 0.1 * jax.random.normal(jax.random.key(2), a.shape), params)  # not the zero head
    la, _ = refiner_loss(cfg, mesh, points, params, tuple(jnp.asarray(x) for x in plain))
    lb, _ = refiner_loss(cfg, mesh, points, params, tuple(jnp.asarray(x) for x in painted))
    assert abs(float(la) - float(lb)) > 1e-6
    args = tuple(jnp.asarray(a) for a in (plain.obs, plain.T_init, plain.K, plain.box))
    batched = jax.jit(lambda m, o, T, k, bx: render_input(m, cfg, o, jaxlie.SE3(T), k, bx))  # as the loss ran it before
    per_example = jax.jit(lambda c, o, T, k, bx: painted_input(mesh, cfg, o, T, k, bx, c))  # what the loss runs
    np.testing.assert_allclose(per_example(jnp.asarray(plain.paint), *args), batched(mesh, *args), atol=1e-5)
    repainted = per_example(jnp.asarray(painted.paint), *args)
    np.testing.assert_array_equal(repainted[..., :3], args[0])  # the observed crop is the data's
    assert float(jnp.abs(repainted - batched(mesh, *args))[..., 3:6].max()) > 0.05  # the render is not
    with pytest.raises(RhamlError, match="paint_prob"):
        dataclasses.replace(cfg, paint_prob=-0.1)


def test_gradients_reach_the_initial_pose_and_the_params(run, bop_set):
    out, _, _ = run
    model = load_bop_model(bop_set)
    mesh = render.as_mesh(model)
    ref = load_refiner(out, model)
    f = [f for f in read_bop(bop_set, "train") if f.observed][0]
    img = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    h = float(np.linalg.inv(f.T_w2c)[2, 3])  # the camera height of this image
    cfg = RefineConfig(camera_height_m=h, align=None, n_iter=2)
    init = jnp.asarray(f.xypsi + np.array([0.1, -0.05, 0.2]), jnp.float32)

    def loss(r, i):
        return jnp.sum(refine(r, mesh, img, f.K, i, cfg).xypsi)

    g_ref, g_init = jax.jit(jax.grad(loss, argnums=(0, 1)))(ref, init)
    leaves = jax.tree.leaves(g_ref)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in leaves) and sum(float(jnp.abs(x).sum()) for x in leaves) > 0
    assert np.all(np.isfinite(np.asarray(g_init))) and np.abs(np.asarray(g_init)).sum() > 0
    out_bad = jax.jit(lambda r: refine(r, mesh, img, f.K, jnp.array([-2.0, 0.0, 0.0]), cfg))(ref)
    assert bool(out_bad.declined) and np.all(np.isfinite(np.asarray(out_bad.pose)))


def _pair(dpos: float = 0.3, view: float = 0.5):
    """(source, target) T_cam_model, both (1,), the source `dpos` m off in x and y and 20 deg off in
    heading; K (1, 3, 3); a crop box (1, 4)."""
    tgt = camera.T_cam_robot(0.3) @ frames.se3_from_xypsi(jnp.array([3.0, 0.0, view]))
    src = camera.T_cam_robot(0.3) @ frames.se3_from_xypsi(jnp.array([3.0 + dpos, dpos, view + 0.35]))
    K = jnp.asarray(DEFAULT_CAMERA.K, jnp.float32)[None]
    return jaxlie.SE3(src.wxyz_xyz[None]), jaxlie.SE3(tgt.wxyz_xyz[None]), K, jnp.array([[200.0, 150.0, 300.0, 260.0]])


def test_disentangled_update_reaches_a_known_target():
    """The update `target_update` gives for a known (source, target) pair, written out here from
    DeepIM's definitions, maps source to target exactly through `apply_update`."""
    src, tgt, K, box = _pair()
    ts, tt = src.translation()[0], tgt.translation()[0]
    bw, bh = box[0, 2] - box[0, 0], box[0, 3] - box[0, 1]
    upd = jnp.concatenate([
        jnp.stack([(tt[0] / tt[2] - ts[0] / ts[2]) * K[0, 0, 0] / bw, (tt[1] / tt[2] - ts[1] / ts[2]) * K[0, 1, 1] / bh,
                   jnp.log(ts[2] / tt[2])]),
        (tgt.rotation() @ src.rotation().inverse()).log()[0]])
    np.testing.assert_allclose(np.asarray(N.target_update(src, tgt, K, box))[0], np.asarray(upd), rtol=1e-5, atol=1e-6)
    out = N.apply_update(src, upd[None], K, box)
    np.testing.assert_allclose(np.asarray(out.as_matrix()), np.asarray(tgt.as_matrix()), atol=1e-5)


@pytest.mark.parametrize("loss", ["joint", "disentangled"])
def test_pose_losses_vanish_at_the_true_update(loss):
    src, tgt, K, box = _pair()
    pts = jnp.asarray(np.random.default_rng(0).uniform(-0.2, 0.2, (64, 3)), jnp.float32)
    cfg = N.RefinerConfig(loss=loss)
    true = N.target_update(src, tgt, K, box)
    assert float(N.update_loss(cfg, src, true, tgt, K, box, pts)[0]) < 1e-4
    assert float(N.update_loss(cfg, src, jnp.zeros_like(true), tgt, K, box, pts)[0]) > 0.1


def test_the_disentangled_loss_weighs_its_parts():
    """part_weights (0, 0, 1): only the rotation is scored, the translation's error is not; the
    default (1, 1, 10) scores a rotation error ten times."""
    src, tgt, K, box = _pair()
    pts = jnp.asarray(np.random.default_rng(0).uniform(-0.2, 0.2, (64, 3)), jnp.float32)
    true = N.target_update(src, tgt, K, box)
    rot_only = N.RefinerConfig(loss="disentangled", part_weights=(0.0, 0.0, 1.0))
    wrong_t = true.at[:, :3].set(0.0)
    assert float(N.update_loss(rot_only, src, wrong_t, tgt, K, box, pts)[0]) < 1e-4
    unit = N.RefinerConfig(loss="disentangled", part_weights=(1.0, 1.0, 1.0))
    wrong_r = true.at[:, 3:].set(0.0)
    ratio = N.update_loss(N.RefinerConfig(), src, wrong_r, tgt, K, box, pts) / N.update_loss(unit, src, wrong_r, tgt, K, box, pts)
    np.testing.assert_allclose(np.asarray(ratio), 10.0, rtol=1e-4)


@pytest.mark.parametrize("bad", [{"loss": "l2"}, {"part_weights": (1.0, -1.0, 1.0)}, {"part_weights": (0.0, 0.0, 0.0)},
                                 {"native": 16}])
def test_a_bad_loss_setting_is_refused(bad):
    with pytest.raises(RhamlError, match="RefinerConfig"):
        N.RefinerConfig(**bad)


def test_the_disentangled_loss_turns_the_heading_where_the_joint_one_cannot():
    """Why `RefinerConfig.loss` exists: with the source 30 cm off in x and y, eq. 8's L1 gives
    every point's error the sign of the translation error, so its gradient on the rotation about
    the camera's vertical (y) axis, the heading, nearly cancels over the model's points; the
    disentangled loss's gradient at the same source is the one without a translation error and
    points toward the true heading (the true update turns by +0.35 rad about the camera's y axis:
    the loss falls as that component grows, a negative gradient)."""
    src, tgt, K, box = _pair(dpos=0.3)
    pts = jnp.asarray(np.random.default_rng(0).uniform([-0.23, -0.2, 0.0], [0.23, 0.2, 0.25], (256, 3)), jnp.float32)
    true = N.target_update(src, tgt, K, box)
    zero = jnp.zeros_like(true)

    def heading_grad(loss):
        g = jax.grad(lambda u: N.update_loss(N.RefinerConfig(loss=loss), src, u, tgt, K, box, pts).sum())(zero)
        return float(g[0, 4])

    assert float(true[0, 4]) > 0.3
    g_joint, g_dis = heading_grad("joint"), heading_grad("disentangled")
    assert g_dis < -0.05 and abs(g_joint) < 0.25 * abs(g_dis), (g_joint, g_dis)


def test_a_luma_refiner_reads_luminance_only(bop_set):
    """refiner_cpu_luma's input is the crops' luminance and the mask: two observed crops of equal
    luminance but other hues give the same update; a colour refiner tells them apart."""
    from rhaml_jax.refine.train import render_input

    mesh = render.as_mesh(load_bop_model(bop_set))
    K = jnp.asarray(DEFAULT_CAMERA.K, jnp.float32)
    T = jaxlie.SE3((camera.T_cam_robot(0.3) @ frames.se3_from_xypsi(jnp.array([3.0, 0.2, 0.5]))).wxyz_xyz[None])
    box = jnp.array([[260.0, 200.0, 380.0, 320.0]])
    rng = np.random.default_rng(0)
    a = rng.uniform(0.2, 0.8, (1, 16, 16, 3)).astype(np.float32)
    # move colour along a direction of zero luminance: (0.587, -0.299, 0) * t keeps 0.299 r + 0.587 g
    b = a + np.array([0.587, -0.299, 0.0], np.float32) * 0.2
    outs = {}
    for luma in (True, False):
        cfg = dataclasses.replace(N.get_refiner_config("refiner_micro"), crop=16, luma=luma)
        params = N.init_params(cfg, jax.random.key(0))
        params["head"]["w"] = jax.random.normal(jax.random.key(1), params["head"]["w"].shape)  # a non-zero head
        xa, xb = (render_input(mesh, cfg, jnp.asarray(o), T, K, box) for o in (a, b))
        assert xa.shape[-1] == N.in_channels(cfg) == (3 if luma else 7)
        outs[luma] = [np.asarray(N.apply(cfg, params, x).update) for x in (xa, xb)]
    np.testing.assert_allclose(outs[True][0], outs[True][1], atol=1e-5)
    assert np.abs(outs[False][0] - outs[False][1]).max() > 1e-4


def test_a_native_render_is_the_full_image_render_cropped_as_the_observed_image_is(bop_set):
    """`RefinerConfig.native`: for a far robot (a box smaller than the crop: magnified) the render
    in the crop equals the whole image rendered at its pixel centres and then cropped by
    `crop.crop_image` (what the observed crop is); the crop-resolution render differs from it at
    the silhouette's edges. For a nearer one (a box larger than the crop: shrunk) it is closer to
    it than the crop-resolution render; where the box is wider than the window, it is the
    crop-resolution render."""
    from rhaml_jax import crop as C
    from rhaml_jax.refine.train import render_crop

    mesh = render.as_mesh(load_bop_model(bop_set))
    cam = DEFAULT_CAMERA.resized(160, 120)
    K = jnp.asarray(cam.K, jnp.float32)
    cfg = N.get_refiner_config("refiner_micro_native")  # crop 32, window 48
    direct_cfg = dataclasses.replace(cfg, native=0)
    corners = jnp.asarray(np.array(np.meshgrid(*zip(mesh.vertices.min(0), mesh.vertices.max(0)), indexing="ij")).reshape(3, -1).T)
    for xypsi, kind in (([6.0, 0.3, 0.4], "magnified"), ([2.0, -0.1, 1.2], "shrunk"), ([0.9, 0.0, 0.2], "too wide")):
        T = camera.T_cam_robot(0.3) @ frames.se3_from_xypsi(jnp.asarray(xypsi, jnp.float32))
        box = C.object_box(K, T @ corners, margin=1.2)
        side = float(jnp.maximum(box[2] - box[0], box[3] - box[1]))
        assert (side < cfg.crop, side <= cfg.native - 2) == {"magnified": (True, True), "shrunk": (False, True), "too wide": (False, False)}[kind]
        T1, b1 = jaxlie.SE3(T.wxyz_xyz[None]), box[None]
        rgb, mask = render_crop(mesh, cfg, T1, K, b1)
        full = render.render(mesh, T, K, cam.width, cam.height)
        ref = np.asarray(C.crop_image(jnp.concatenate([full.rgb, full.mask[..., None].astype(jnp.float32)], -1), box, cfg.crop, cfg.crop))
        d_rgb, d_mask = render_crop(mesh, direct_cfg, T1, K, b1)
        err, err_direct = np.abs(np.asarray(mask[0]) - ref[..., 3]).mean(), np.abs(np.asarray(d_mask[0]) - ref[..., 3]).mean()
        if kind == "magnified":
            np.testing.assert_allclose(np.asarray(mask[0]), ref[..., 3], atol=1e-4)
            np.testing.assert_array_equal(np.asarray(render_crop(mesh, cfg, T1, K, box)[1]), np.asarray(mask))  # one box (4,), as refine() passes it
            assert np.mean(np.abs(np.asarray(rgb[0]) - ref[..., :3]) < 1e-3) > 0.99  # ties between coplanar faces aside
            assert err_direct > 1e-2
        elif kind == "shrunk":  # the area filter's grid is the window's, not the whole image's
            assert err < 0.5 * err_direct, (err, err_direct)
        else:
            np.testing.assert_array_equal(np.asarray(mask), np.asarray(d_mask))
            np.testing.assert_array_equal(np.asarray(rgb), np.asarray(d_rgb))


def test_the_papers_position_noise_scales_with_the_robot(bop_set):
    """0.15 m for the Pioneer (its BOP ply read back has world scale 1), 0.15 m x 0.39 for a
    TurtleBot3-sized world; the heading noise and the IML-like draws do not depend on the scale."""
    from rhaml_jax.refine.train import initial_pose

    assert load_bop_model(bop_set).world_scale == 1.0
    assert RefinerSource(bop_set, "train", N.get_refiner_config("refiner_micro"), 2).scale == 1.0
    truth = np.array([3.0, 0.5, 0.3])

    def spread(scale):
        draws = [initial_pose(truth, np.random.default_rng(i), scale) for i in range(4000)]
        rng_first = [np.random.default_rng(i).random() < 0.5 for i in range(4000)]  # the paper's branch
        d = np.array([x - truth for x, paper in zip(draws, rng_first) if paper])
        return d[:, :2].std(), d[:, 2].std()

    (xy1, psi1), (xy39, psi39) = spread(1.0), spread(0.39)
    assert abs(xy1 - 0.15) < 0.01 and abs(xy39 - 0.15 * 0.39) < 0.004
    assert abs(psi1 - np.deg2rad(20)) < 0.03 and abs(psi39 - psi1) < 1e-12



def test_fine_starts_are_a_coarse_refiners_residuals():
    """`starts="fine"`: range off by N(0, 1 %) or N(0, 3 %), bearing N(0, 0.2 deg) or N(0, 0.6 deg),
    heading N(0, 2 deg) or N(0, 6 deg), half each; never a flip; independent of the robot's scale."""
    from rhaml_jax.refine.train import initial_pose

    truth = np.array([4.0, -1.0, 2.0])
    d = np.array([initial_pose(truth, np.random.default_rng(i), 1.0, "fine") for i in range(4000)])
    rel = np.hypot(d[:, 0], d[:, 1]) / np.hypot(*truth[:2]) - 1
    bearing = np.arctan2(d[:, 1], d[:, 0]) - np.arctan2(truth[1], truth[0])
    dpsi = np.angle(np.exp(1j * (d[:, 2] - truth[2])))
    assert abs(rel.std() - np.sqrt((0.01 ** 2 + 0.03 ** 2) / 2)) < 0.002 and abs(rel.mean()) < 0.002
    assert abs(np.rad2deg(bearing.std()) - np.sqrt((0.2 ** 2 + 0.6 ** 2) / 2)) < 0.03
    assert abs(np.rad2deg(dpsi.std()) - np.sqrt((2.0 ** 2 + 6.0 ** 2) / 2)) < 0.25 and np.rad2deg(np.abs(dpsi).max()) < 40
    np.testing.assert_array_equal(initial_pose(truth, np.random.default_rng(3), 0.39, "fine"), d[3])
    cfg = N.get_refiner_config("refiner_micro_fine")
    with pytest.raises(RhamlError, match="RefinerConfig.starts 'tiny'"):
        dataclasses.replace(cfg, starts="tiny")


def _micro_cascade(run, bop_set):
    """The tiny run as a coarse refiner, a fine one made from it (a non-zero head), and a training
    frame to refine: (run dir, coarse, fine, mesh, frame, image, camera height, initial pose)."""
    out, _, _ = run
    model = load_bop_model(bop_set)
    coarse = load_refiner(out, model)
    fine = dataclasses.replace(coarse, cfg=N.get_refiner_config("refiner_micro_fine"))
    fine = dataclasses.replace(fine, params=jax.tree.map(lambda a: a + 0.05, fine.params))
    f = [f for f in read_bop(bop_set, "train") if f.observed][0]
    img = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    h = float(np.linalg.inv(f.T_w2c)[2, 3])
    init = jnp.asarray(f.xypsi + np.array([0.1, -0.05, 0.2]), jnp.float32)
    return out, coarse, fine, render.as_mesh(model), f, img, h, init


def test_a_fine_refiner_runs_after_the_coarse_one(run, bop_set):
    """The cascade: `fine_iter` more iterations (rows of `iterates`) of the fine refiner after the
    coarse ones; the coarse rows are the coarse refiner's alone; gradients reach the fine refiner."""
    out, coarse, fine, mesh, f, img, h, init = _micro_cascade(run, bop_set)
    cfg = RefineConfig(camera_height_m=h, align=None, n_iter=2, fine_iter=3)
    alone = refine(coarse, mesh, img, f.K, init, cfg)
    both = refine(coarse, mesh, img, f.K, init, cfg, fine=fine)
    assert alone.iterates.shape == (3, 3) and both.iterates.shape == (6, 3)
    np.testing.assert_allclose(np.asarray(both.iterates[:3]), np.asarray(alone.iterates), atol=1e-6)
    np.testing.assert_allclose(np.asarray(both.xypsi), np.asarray(both.iterates[-1]), atol=1e-6)
    assert np.abs(np.asarray(both.xypsi - alone.xypsi)).max() > 1e-4
    u8 = jnp.asarray(load_rgb(f.rgb))  # refine_stage: the stage's networks, the pipeline's uint8 frame
    staged = refine_stage(cfg, StageParams(coarse, mesh, fine=fine), u8, f.K, init)
    np.testing.assert_allclose(np.asarray(staged.iterates), np.asarray(both.iterates), atol=1e-5)
    g = jax.grad(lambda r: jnp.sum(refine(coarse, mesh, img, f.K, init, cfg, fine=r).xypsi))(fine)
    leaves = jax.tree.leaves(g)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in leaves) and sum(float(jnp.abs(x).sum()) for x in leaves) > 0


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=12, max_size=12))
def test_a_mirrored_update_is_the_update_of_the_mirrored_scene(v):
    """`refine.mirror_update`: the update between two poses seen in a left-right mirrored image
    (the camera frame's x axis reflected: T -> M T M, M = diag(-1, 1, 1)), mapped back, is the update
    between the poses themselves; mapping twice is the identity."""
    from rhaml_jax.refine import mirror_update

    v = np.asarray(v, np.float32)
    K = jnp.asarray(DEFAULT_CAMERA.K, jnp.float32)
    box = jnp.array([250.0, 200.0, 330.0, 280.0])
    M = jnp.diag(jnp.array([-1.0, 1.0, 1.0, 1.0]))

    def pose(a):
        R = jaxlie.SO3.exp(jnp.asarray(a[:3]))
        return jaxlie.SE3.from_rotation_and_translation(R, jnp.asarray([a[3], 0.5 * a[4], 4.0 + a[5]]))

    src, tgt = pose(v[:6]), pose(v[6:])
    mirrored = [jaxlie.SE3.from_matrix(M @ T.as_matrix() @ M) for T in (src, tgt)]
    u = N.target_update(src, tgt, K, box)
    np.testing.assert_allclose(np.asarray(mirror_update(N.target_update(*mirrored, K, box))), np.asarray(u), atol=2e-4)
    np.testing.assert_array_equal(np.asarray(mirror_update(mirror_update(u))), np.asarray(u))


def test_mirroring_runs_only_the_iterations_it_names(run, bop_set, tmp_path):
    """`RefineConfig.mirror`: "fine" changes only the fine refiner's rows, "all" the coarse ones
    too; results finite. `load_stage` keeps it off for a robot that is not left-right symmetric and
    refuses it named for one; an unknown setting is refused."""
    import shutil

    import rhaml_jax.refine as refine_pkg
    from rhaml_jax.data._bop import write_dataset_header
    from rhaml_jax.refine import load_stage
    from rhaml_jax.robots import load_robot

    out, coarse, fine, mesh, f, img, h, init = _micro_cascade(run, bop_set)
    its = {m: np.asarray(refine(coarse, mesh, img, f.K, init, RefineConfig(camera_height_m=h, align=None, n_iter=2, fine_iter=2,
                                                                           mirror=m), fine=fine).iterates)
           for m in ("none", "fine", "all")}
    assert all(np.all(np.isfinite(x)) for x in its.values())
    np.testing.assert_allclose(its["fine"][:3], its["none"][:3], atol=1e-6)
    assert np.abs(its["fine"][3:] - its["none"][3:]).max() > 1e-5 and np.abs(its["all"][1:3] - its["none"][1:3]).max() > 1e-5
    with pytest.raises(RhamlError, match="RefineConfig.mirror"):
        RefineConfig(mirror="both")
    assert load_stage(out, bop_set)[0].mirror == refine_pkg.DEFAULT_MIRROR != "none" == RefineConfig.mirror
    lopsided = tmp_path / "lopsided"
    shutil.copytree(bop_set, lopsided)
    m = load_robot("pioneer3dx")
    write_dataset_header(lopsided, dataclasses.replace(m, vertices=m.vertices + np.float32([0, 0.05, 0])), DEFAULT_CAMERA)
    assert load_stage(out, lopsided, check_robot=False)[0].mirror == "none"
    with pytest.raises(RhamlError, match="--refine-mirror: the robot model .* is not left-right symmetric"):
        load_stage(out, lopsided, check_robot=False, mirror="fine")


def test_an_ensemble_of_fine_refiners_averages_their_updates(run, bop_set):
    """`refine(fine=(a, b))`: a fine iteration applies the mean of the members' updates, each read
    from the same crop with its own network input; a one-member ensemble is that refiner alone.
    `check_ensemble` refuses an empty ensemble and members of another crop or margin; `load_stage`
    loads several fine folders as one ensemble and "none" as none."""
    from rhaml_jax import crop as C
    from rhaml_jax.refine import check_ensemble, load_stage
    from rhaml_jax.refine.alignment import _corners
    from rhaml_jax.refine.train import render_input

    out, coarse, a, mesh, f, img, h, init = _micro_cascade(run, bop_set)
    b = dataclasses.replace(a, params=jax.tree.map(lambda x: -0.5 * x, a.params))
    cfg = RefineConfig(camera_height_m=h, align=None, n_iter=1, fine_iter=1)
    both = refine(coarse, mesh, img, f.K, init, cfg, fine=(a, b))
    start = both.iterates[1]  # the coarse iteration's pose, where the fine one starts
    T = camera.T_cam_robot(h) @ frames.se3_from_xypsi(start)
    T1 = jaxlie.SE3(T.wxyz_xyz[None])
    box = C.object_box(f.K, T @ _corners(mesh), margin=a.cfg.margin)
    obs = C.crop_image(img, box, a.cfg.crop, a.cfg.crop)[None]
    updates = [N.apply(m.cfg, m.params, render_input(mesh, m.cfg, obs, T1, f.K, box)).update for m in (a, b)]
    assert float(jnp.abs(updates[0] - updates[1]).max()) > 1e-3  # the members disagree
    want = camera.T_cam_robot(h).inverse() @ jaxlie.SE3(N.apply_update(T1, 0.5 * (updates[0] + updates[1]), f.K, box).wxyz_xyz[0])
    np.testing.assert_allclose(np.asarray(both.xypsi), np.asarray(frames.xypsi_from_se3(want)), atol=1e-5)
    np.testing.assert_allclose(np.asarray(refine(coarse, mesh, img, f.K, init, cfg, fine=(a,)).xypsi),
                               np.asarray(refine(coarse, mesh, img, f.K, init, cfg, fine=a).xypsi), atol=1e-6)
    with pytest.raises(RhamlError, match="at least one refiner"):
        check_ensemble(())
    wide = dataclasses.replace(a, cfg=dataclasses.replace(a.cfg, margin=a.cfg.margin + 0.2))
    with pytest.raises(RhamlError, match="must share crop and margin"):
        refine(coarse, mesh, img, f.K, init, cfg, fine=(a, wide))
    assert isinstance(load_stage(out, bop_set, fine=(out, out))[1].fine, tuple)
    assert load_stage(out, bop_set, fine=(out,))[1].fine is not None and load_stage(out, bop_set, fine="none")[1].fine is None


def test_fine_views_average_the_fine_refiner_from_starts_around_the_pose(run, bop_set):
    """`RefineConfig.fine_views`: the fine refiner runs once from each `view_starts` pose and its
    answers are averaged (the heading as a unit vector); one view is the plain cascade."""
    from rhaml_jax.refine import view_starts

    _, coarse, fine, mesh, f, img, h, init = _micro_cascade(run, bop_set)
    cfg = RefineConfig(camera_height_m=h, align=None, n_iter=1, fine_iter=1, fine_views=4)
    many = refine(coarse, mesh, img, f.K, init, cfg, fine=fine)
    after_coarse = many.iterates[1]
    singles = np.stack([np.asarray(refine(fine, mesh, img, f.K, s, cfg).xypsi)  # one iteration of the fine refiner
                        for s in view_starts(after_coarse, 4, cfg.fine_spread)])
    np.testing.assert_allclose(np.asarray(many.xypsi[:2]), singles[:, :2].mean(0), atol=1e-4)
    psi = np.arctan2(np.sin(singles[:, 2]).mean(), np.cos(singles[:, 2]).mean())
    np.testing.assert_allclose(float(many.xypsi[2]), psi, atol=1e-4)
    assert many.iterates.shape == (3, 3) and np.all(np.isfinite(np.asarray(many.pose)))
    for bad in ({"fine_views": 9}, {"fine_views": 0}, {"fine_spread": (0.01, -0.1, 0.0)}, {"fine_iter": -1}):
        with pytest.raises(RhamlError, match="RefineConfig.fine_"):
            RefineConfig(**bad)
    with pytest.raises(RhamlError, match="RefineConfig.n_iter"):
        RefineConfig(n_iter=0)


@settings(max_examples=25, deadline=None)
@given(x=st.floats(1.0, 8.0), y=st.floats(-3.0, 3.0), psi=st.floats(-3.1, 3.1), views=st.integers(1, 8))
def test_view_starts_are_centred_on_the_pose(x, y, psi, views):
    """Any number of views is centred on the pose in log range, bearing and heading; an even
    number has each start off by exactly the spread in each, an odd one starts with the pose itself
    (one view: the pose alone, as `RefineConfig.fine_views` = 1 runs)."""
    from rhaml_jax.refine import view_starts

    spread = (0.02, 0.004, 0.05)
    s = np.asarray(view_starts(jnp.array([x, y, psi], jnp.float32), views, spread), np.float64)
    assert s.shape == (views, 3)
    lr = np.log(np.hypot(s[:, 0], s[:, 1]) / np.hypot(x, y))
    db = np.arctan2(s[:, 1], s[:, 0]) - np.arctan2(y, x)
    dpsi = s[:, 2] - psi
    off = slice(views % 2, None)  # the starts off the pose
    for d, sp in ((lr, spread[0]), (db, spread[1]), (dpsi, spread[2])):
        np.testing.assert_allclose(np.abs(d[off]), sp, rtol=2e-3, atol=2e-5)
        if views % 2:
            assert abs(d[0]) < 2e-5
        assert abs(d.mean()) < 2e-5 + 1e-3 * sp


def test_an_unconverged_cascade_keeps_the_initial_pose(run, bop_set):
    """`RefineConfig.max_final_step`: converged iff the last coarse iteration moved the range by at
    most that fraction; if not, the initial pose comes back (as for a declined start), with the
    iterates kept to inspect; None checks nothing."""
    out, _, _ = run
    model = load_bop_model(bop_set)
    mesh = render.as_mesh(model)
    ref = load_refiner(out, model)
    ref = dataclasses.replace(ref, params=jax.tree.map(lambda a: a + 0.05, ref.params))  # it moves the pose
    f = [f for f in read_bop(bop_set, "train") if f.observed][0]
    img = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    h = float(np.linalg.inv(f.T_w2c)[2, 3])
    init = jnp.asarray(f.xypsi + np.array([0.1, -0.05, 0.2]), jnp.float32)
    free = refine(ref, mesh, img, f.K, init, RefineConfig(camera_height_m=h, align=None, n_iter=2, max_final_step=None))
    its = np.asarray(free.iterates)
    step = abs(np.log(np.hypot(*its[2, :2]) / np.hypot(*its[1, :2])))
    assert bool(free.converged) and step > 1e-5
    np.testing.assert_allclose(np.asarray(free.xypsi), its[-1], atol=1e-6)
    for tol, settled in ((step * 1.01, True), (step * 0.99, False)):
        r = refine(ref, mesh, img, f.K, init, RefineConfig(camera_height_m=h, align=None, n_iter=2, max_final_step=tol))
        assert bool(r.converged) == settled and not bool(r.declined)
        np.testing.assert_allclose(np.asarray(r.xypsi), its[-1] if settled else np.asarray(init), atol=1e-6)
        np.testing.assert_allclose(np.asarray(r.iterates), its, atol=1e-6)
        assert settled or (float(r.flip_prob) == -1.0 and np.all(np.asarray(r.roll_pitch) == 0))
    with pytest.raises(RhamlError, match="RefineConfig.max_final_step"):
        RefineConfig(max_final_step=0.0)


def test_the_scorers_flip_probability_follows_an_alignment_that_turns_the_heading():
    """After the alignment turns the heading by more than 90 deg, the scorer's P(other way) is read
    for the new heading (1 - p); a smaller turn, or no scorer (-1), leaves it."""
    from rhaml_jax.refine import _flip_prob_after

    p = jnp.array([0.1, 0.1, 0.1, -1.0])
    before = jnp.array([3.0, 3.0, -3.0, 0.0])
    after = jnp.array([3.0 - np.pi, 3.0 + 1.0, -3.0 + 3.0, np.pi])  # turned by 180, 57, 172, 180 deg
    np.testing.assert_allclose(_flip_prob_after(p, before, after), [0.9, 0.1, 0.9, -1.0], atol=1e-6)


def test_fine_iterations_after_the_alignment(run, bop_set):
    """`RefineConfig.fine_after_align`: that many more rows of `iterates`, the fine refiner's
    iterations from the aligned pose; the rows before are the run without them, whose result is the
    aligned pose; a negative count is refused."""
    from rhaml_jax.refine import AlignConfig

    out, coarse, fine, mesh, f, img, h, init = _micro_cascade(run, bop_set)
    acfg = AlignConfig(crop=32, stages=((2.0, 2),), coarse_stages=())
    cfg = RefineConfig(camera_height_m=h, align=acfg, n_iter=2, fine_iter=1, max_final_step=None, fine_after_align=0)
    aligned = refine(coarse, mesh, img, f.K, init, cfg, fine=fine)
    after = refine(coarse, mesh, img, f.K, init, dataclasses.replace(cfg, fine_after_align=2), fine=fine)
    assert aligned.iterates.shape == (4, 3) and after.iterates.shape == (6, 3)
    np.testing.assert_allclose(np.asarray(after.iterates[:4]), np.asarray(aligned.iterates), atol=1e-6)
    np.testing.assert_allclose(np.asarray(after.xypsi), np.asarray(after.iterates[-1]), atol=1e-6)
    assert np.abs(np.asarray(after.iterates[4] - aligned.xypsi)).max() > 1e-4  # moved from the aligned pose
    with pytest.raises(RhamlError, match="fine_after_align"):
        RefineConfig(fine_after_align=-1)
