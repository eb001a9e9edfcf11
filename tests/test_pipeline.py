"""The jitted pipeline: equals its stages called one by one, compiles once per shape, is
differentiable through the pose graph, shards over devices, and refuses bad input clearly."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rhaml_jax import iml, pgo, pipeline, planar
from rhaml_jax.amlnet import build, get_config
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.errors import RhamlError

N, H, W = 6, 48, 64


def _biased(params, offset):
    """Head biases moved so that a random network calls the robot in view ~3 m ahead."""
    return jax.tree_util.tree_map_with_path(
        lambda p, v: v + offset if jax.tree_util.keystr(p) == "['head']['b'].value" else v, params)


def _stage():
    net, znet = build(get_config("micro"), jax.random.key(1)), build(get_config("tiny_zoom"), jax.random.key(2))
    params = iml.IMLParams((_biased(net.params, jnp.array([6.0, 3.0, 0.0, 0.0])), net.batch_stats),
                           (znet.params, znet.batch_stats))
    return iml.IMLModel(net, znet, zoom_mirror=True), params


@pytest.fixture(scope="module")
def stage():
    return _stage()


def _sequence(seed=0, n=N):
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (n, H, W, 3), dtype=np.uint8)
    K = np.repeat(np.asarray(DEFAULT_CAMERA.resized(W, H).K, np.float32)[None], n, 0)
    t = np.linspace(0, 1, n)
    odom_b = np.stack([3 + 0.5 * np.sin(t), 0.3 * t, 0.2 * t], 1).astype(np.float32)
    return pipeline.Sequence(images, K, np.zeros((n, 3), np.float32), odom_b, np.ones(n, bool), np.ones(n, bool))


def test_pipeline_equals_its_stages(stage):
    m, p = stage
    seq = _sequence()
    model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "pgo"), chunk=4))
    res = pipeline.run_jit(model, pipeline.PipelineParams(p), seq)
    est = iml.localize_jit(m, p, seq.images, seq.K)
    np.testing.assert_allclose(res.iml.xypsi, est.xypsi, atol=1e-4)
    assert bool(res.detected.all())
    obs = pgo.observation_from_xy_yaw_rp(est.xypsi, est.roll_pitch)
    rv = pgo.rendezvous_from_frames(seq.odom_a, seq.odom_b, obs, seq.a_observes)
    valid = jnp.ones(N, bool)
    first = pgo.fuse_jit(rv, pgo.FusionConfig(), valid=valid, flip_prob=est.flip_prob)
    c = pgo.range_model(rv, first.odom_a_T_odom_b, first.inlier.astype(jnp.float32))  # batch: calibrate, fuse again
    ref = pgo.fuse_jit(pgo.rescale_observations(rv, c), pgo.FusionConfig(), valid=valid, flip_prob=est.flip_prob)
    np.testing.assert_allclose(res.range_model, c, atol=1e-4)
    np.testing.assert_allclose(res.xypsi, ref.relative, atol=1e-3)
    # frames without a detection are no rendezvous: the graph then follows the odometry there
    invalid = seq._replace(valid=np.arange(N) < N - 2)
    res2 = pipeline.run_jit(model, pipeline.PipelineParams(p), invalid)
    assert not bool(res2.detected[-2:].any()) and bool(jnp.all(jnp.isfinite(res2.xypsi)))


def test_compiles_once_per_shape(stage):
    m, p = stage
    model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml",)))
    traces = []

    def counted(model, params, seq):  # runs once per compilation (jit traces, then caches)
        traces.append(seq.images.shape)
        return pipeline.run(model, params, seq)

    f = jax.jit(counted, static_argnums=0)
    f(model, pipeline.PipelineParams(p), _sequence(0))
    f(model, pipeline.PipelineParams(p), _sequence(1))
    assert len(traces) == 1
    f(model, pipeline.PipelineParams(p), _sequence(2, n=N + 1))
    assert len(traces) == 2


def test_gradient_reaches_amlnet_through_the_pose_graph(stage):
    m, p = stage
    seq = _sequence()
    model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "pgo"), chunk=N))
    truth = jnp.asarray(seq.odom_b)

    def loss(amlnet_params):
        params = pipeline.PipelineParams(iml.IMLParams((amlnet_params, p.amlnet[1]), p.zoom))
        r = pipeline.run(model, params, seq)
        d = planar.between(truth, r.xypsi)
        return jnp.sum(d[:, :2] ** 2) + 0.1 * jnp.sum(d[:, 2] ** 2)

    g = jax.jit(jax.grad(loss))(p.amlnet[0])
    leaves = jax.tree.leaves(g)
    assert all(bool(jnp.all(jnp.isfinite(v))) for v in leaves)
    assert sum(float(jnp.abs(v).sum()) for v in leaves) > 0


def test_modules_and_config_errors(stage):
    assert pipeline.parse_modules("pgo,iml") == ("iml", "pgo")
    for bad, msg in (("iml,iml", "twice"), ("iml,nope", "unknown module 'nope'"), ("pgo", "starts with iml")):
        with pytest.raises(RhamlError, match=msg):
            pipeline.parse_modules(bad)
    with pytest.raises(RhamlError, match="pgo_mode"):
        pipeline.PipelineConfig(pgo_mode="sometimes")
    with pytest.raises(RhamlError, match="has no refiner"):
        m, p = stage
        pipeline.run(pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "ir"))),
                     pipeline.PipelineParams(p), _sequence())


SHARD_SCRIPT = textwrap.dedent("""
    import jax, numpy as np
    import tests.test_pipeline as t
    from rhaml_jax import pipeline
    m, p = t._stage()
    seqs = jax.tree.map(lambda *a: np.stack(a), *[t._sequence(s, n=4) for s in range(8)])
    model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "pgo")))
    f = jax.jit(jax.vmap(lambda s: pipeline.run(model, pipeline.PipelineParams(p), s).xypsi))
    out = f(pipeline.shard_sequences(seqs))
    print(len(jax.devices()), len(out.sharding.device_set))
    np.save("{out}", np.asarray(out))
""")


def test_sharded_over_eight_devices_equals_one(tmp_path):
    results = {}
    for devices in (1, 8):
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}",
                   PYTHONPATH=os.pathsep.join([os.getcwd(), os.environ.get("PYTHONPATH", "")]))
        out = tmp_path / f"out{devices}.npy"
        run = subprocess.run([sys.executable, "-c", SHARD_SCRIPT.format(out=out)], env=env, capture_output=True,
                             text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        assert run.stdout.split()[-2:] == [str(devices), str(devices)]
        results[devices] = np.load(out)
    np.testing.assert_allclose(results[8], results[1], atol=1e-4)


def test_no_rendezvous_keeps_the_stage_estimates(stage):
    m, p = stage
    seq = _sequence()._replace(valid=np.zeros(N, bool))
    for mode in ("batch", "online"):
        model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "pgo"), pgo_mode=mode))
        res = pipeline.run_jit(model, pipeline.PipelineParams(p), seq)
        assert not bool(res.detected.any())
        np.testing.assert_allclose(res.xypsi, res.iml.xypsi)


def test_gradient_reaches_amlnet_through_refinement_and_the_pose_graph(stage):
    from rhaml_jax import refine, render
    from rhaml_jax.robots import load_robot

    m, p = stage
    cfg = refine.get_refiner_config("refiner_micro")
    refiner = refine.Refiner(refine.net.init_params(cfg, jax.random.key(3)), cfg)
    mesh = render.as_mesh(load_robot("pioneer3dx"))
    seq = _sequence(n=4)
    model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), chunk=4), refine.RefineConfig())
    truth = jnp.asarray(seq.odom_b)

    def loss(amlnet_params):
        params = pipeline.PipelineParams(iml.IMLParams((amlnet_params, p.amlnet[1]), p.zoom), refine.StageParams(refiner, mesh))
        r = pipeline.run(model, params, seq)
        d = planar.between(truth, r.xypsi)
        return jnp.sum(d[:, :2] ** 2) + 0.1 * jnp.sum(d[:, 2] ** 2), r

    (value, r), g = jax.jit(jax.value_and_grad(loss, has_aux=True))(p.amlnet[0])
    assert r.ir is not None and bool(jnp.all(jnp.isfinite(r.xypsi)))
    leaves = jax.tree.leaves(g)
    assert all(bool(jnp.all(jnp.isfinite(v))) for v in leaves)
    assert sum(float(jnp.abs(v).sum()) for v in leaves) > 0


def test_ir_with_a_segmenter_runs_the_alignment_to_its_masks(stage):
    """StageParams with a segmenter: IR aligns every detected frame to the segmenter's mask (the
    result moves from the learned iterations' and stays finite); declined frames keep IML's."""
    from rhaml_jax import refine, render
    from rhaml_jax.refine import segmenter as G
    from rhaml_jax.robots import load_robot

    m, p = stage
    rc = refine.get_refiner_config("refiner_micro")
    refiner = refine.Refiner(refine.net.init_params(rc, jax.random.key(3)), rc)
    sc = G.get_segmenter_config("segmenter_micro")
    params = G.init_params(sc, jax.random.key(4))
    params["out"]["b"] = jnp.array([3.0])  # a segmenter that calls every pixel robot: the alignment must move
    seg = G.Segmenter(params, sc)
    mesh = render.as_mesh(load_robot("pioneer3dx"))
    seq = _sequence(n=2)
    tiny = refine.AlignConfig(crop=32, stages=((2.0, 2),), coarse_stages=((1.0, 1, "xy"),))
    cfg = pipeline.PipelineConfig(modules=("iml", "ir"), chunk=2)
    learned = pipeline.PipelineModel(m, cfg, refine.RefineConfig(n_iter=1))  # no alignment without a segmenter
    aligned = pipeline.PipelineModel(m, cfg, refine.RefineConfig(align=tiny, n_iter=1))
    without = pipeline.run_jit(learned, pipeline.PipelineParams(p, refine.StageParams(refiner, mesh)), seq)
    with_seg = pipeline.run_jit(aligned, pipeline.PipelineParams(p, refine.StageParams(refiner, mesh, seg)), seq)
    assert with_seg.ir is not None and bool(jnp.all(jnp.isfinite(with_seg.ir.xypsi)))
    assert not np.allclose(with_seg.ir.xypsi, without.ir.xypsi)


def test_ir_frame_by_frame_equals_vmapped_frames(stage):
    """`PipelineConfig.ir_chunk` 1 (each frame alone: lax.cond skips a frame that is no candidate,
    and the alignment where its start fits the mask, `AlignConfig.skip_iou`) gives what 2 frames
    vmapped together give (both branches run); a frame that is not valid keeps IML's estimate."""
    from rhaml_jax import refine, render
    from rhaml_jax.refine import segmenter as G
    from rhaml_jax.robots import load_robot

    m, p = stage
    rc = refine.get_refiner_config("refiner_micro")
    refiner = refine.Refiner(refine.net.init_params(rc, jax.random.key(3)), rc)
    sc = G.get_segmenter_config("segmenter_micro")
    params = G.init_params(sc, jax.random.key(4))
    params["out"]["b"] = jnp.array([3.0])  # every pixel robot: the alignment runs (its start's IoU is low)
    stage_params = refine.StageParams(refiner, render.as_mesh(load_robot("pioneer3dx")), G.Segmenter(params, sc))
    seq = _sequence(n=2)._replace(valid=np.array([True, False]))
    tiny = refine.AlignConfig(crop=32, stages=((2.0, 2),), coarse_stages=(), skip_iou=0.9)
    runs = [pipeline.run_jit(pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "ir"), chunk=2, ir_chunk=k),
                                                    refine.RefineConfig(align=tiny, n_iter=1)),
                             pipeline.PipelineParams(p, stage_params), seq) for k in (1, 2)]
    np.testing.assert_allclose(np.asarray(runs[0].ir.xypsi), np.asarray(runs[1].ir.xypsi), atol=1e-4)
    np.testing.assert_array_equal(np.asarray(runs[0].ir.xypsi[1]), np.asarray(runs[0].iml.xypsi[1]))
    assert not np.allclose(runs[0].ir.xypsi[0], runs[0].iml.xypsi[0])
    with pytest.raises(RhamlError, match="ir_chunk"):
        pipeline.PipelineConfig(ir_chunk=0)


def test_frames_where_ir_does_not_converge_keep_imls_estimate(stage):
    """`RefineConfig.max_final_step`: where the refiner's last coarse iteration still moves the
    range by more than it, the pipeline keeps IML's estimate (as where the refiner declines)."""
    from rhaml_jax import refine, render
    from rhaml_jax.robots import load_robot

    m, p = stage
    rc = refine.get_refiner_config("refiner_micro")
    refiner = refine.Refiner(jax.tree.map(lambda a: a + 0.05, refine.net.init_params(rc, jax.random.key(3))), rc)
    params = pipeline.PipelineParams(p, refine.StageParams(refiner, render.as_mesh(load_robot("pioneer3dx"))))
    seq = _sequence(n=2)
    cfg = pipeline.PipelineConfig(modules=("iml", "ir"), chunk=2)
    runs = {tol: pipeline.run_jit(pipeline.PipelineModel(m, cfg, refine.RefineConfig(n_iter=2, max_final_step=tol)), params, seq)
            for tol in (None, 1e-9)}
    free, strict = runs[None], runs[1e-9]
    assert not np.allclose(free.ir.xypsi, free.iml.xypsi)  # refined where nothing is checked
    np.testing.assert_array_equal(np.asarray(strict.ir.xypsi), np.asarray(strict.iml.xypsi))


def _redetect_case(seed: int, n: int = 40):
    """A robot circling 3 m ahead of a still observer: estimates (n,) a few cm off, frames 30-39 a
    metre off in x (about 25 % of the range), and both odometries (odom_a fixed at 0: truth = odom_b)."""
    t = np.linspace(0, 2 * np.pi, n)
    odom_b = np.stack([3 + np.cos(t), np.sin(t), t], 1).astype(np.float32)
    odom_a = np.zeros((n, 3), np.float32)
    xypsi = odom_b + np.random.default_rng(seed).normal(0, [0.02, 0.02, 0.01], (n, 3)).astype(np.float32)
    xypsi[30:, 0] += 1.0
    return iml.Estimate(jnp.asarray(xypsi), jnp.ones(n), jnp.full(n, 0.1), jnp.zeros((n, 2))), odom_a, odom_b


def test_redetect_adds_the_low_frames_that_agree_with_the_graph():
    n = 40
    est, odom_a, odom_b = _redetect_case(0, n)
    cfg = pipeline.PipelineConfig(modules=("iml", "pgo"), redetect_threshold=0.2)
    confident = jnp.asarray(np.arange(n) < 20)
    fusion, c, detected = jax.jit(pipeline.redetect, static_argnums=0)(
        cfg, est, confident, jnp.ones(n, bool), odom_a, odom_b, jnp.ones(n, bool))
    np.testing.assert_array_equal(np.asarray(detected), np.arange(n) < 30)
    assert float(jnp.max(jnp.abs(fusion.relative[:, :2] - odom_b[:, :2]))) < 0.05
    # no confident frame: no graph to agree with, nothing is re-detected
    _, _, none = pipeline.redetect(cfg, est, jnp.zeros(n, bool), jnp.ones(n, bool), odom_a, odom_b, jnp.ones(n, bool))
    assert not bool(none.any())


def test_online_redetect_judges_each_frame_by_the_frames_before_it():
    """Online, a candidate is judged by the graph of the frames before it that joined: the good
    frames before the first confident one stay undetected (batch, which sees the future, takes them).
    The single pass is the plain online fusion of the frames it accepted, row for row."""
    n = 40
    est, odom_a, odom_b = _redetect_case(1, n)
    confident = jnp.asarray((np.arange(n) >= 10) & (np.arange(n) < 20))
    k = np.arange(n)
    for mode, expect in (("online", (k >= 10) & (k < 30)), ("batch", k < 30)):
        cfg = pipeline.PipelineConfig(modules=("iml", "pgo"), pgo_mode=mode)
        fusion, _, detected = jax.jit(pipeline.redetect, static_argnums=0)(
            cfg, est, confident, jnp.ones(n, bool), odom_a, odom_b, jnp.ones(n, bool))
        np.testing.assert_array_equal(np.asarray(detected), expect, err_msg=mode)
        assert bool(jnp.all(jnp.isfinite(fusion.relative))), mode
        if mode == "online":
            plain, _ = jax.jit(pipeline.fuse_estimates, static_argnums=0)(
                cfg, est, detected, odom_a, odom_b, jnp.ones(n, bool))
            np.testing.assert_allclose(np.asarray(fusion.relative), np.asarray(plain.relative), atol=1e-5)
            np.testing.assert_array_equal(np.asarray(fusion.inlier), np.asarray(plain.inlier))


def test_redetect_config_errors():
    for kw, msg in [(dict(redetect_threshold=0.5), "under the detection threshold"),
                    (dict(redetect_threshold=0.0), "under the detection threshold"),
                    (dict(redetect_gate=0.0), "redetect_gate")]:
        with pytest.raises(RhamlError, match=msg):
            pipeline.PipelineConfig(**({"modules": ("iml", "pgo")} | kw))
    pipeline.PipelineConfig(modules=("iml",))  # the default: unused without pgo


def test_range_window_follows_the_modules():
    """'auto': a range-model transform per RANGE_WINDOW_REFINED rows for refined estimates, one for
    the whole sequence for IML's; a number or None as given; too few rows refused."""
    auto = {mods: pipeline.PipelineConfig(modules=mods).calibration_window
            for mods in (("iml", "pgo"), ("iml", "ir", "pgo"))}
    assert auto == {("iml", "pgo"): None, ("iml", "ir", "pgo"): pipeline.RANGE_WINDOW_REFINED}
    assert pipeline.PipelineConfig(modules=("iml", "pgo"), range_window=50).calibration_window == 50
    assert pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), range_window=None).calibration_window is None
    for bad in (3, "sometimes", 100.0):
        with pytest.raises(RhamlError, match="range_window"):
            pipeline.PipelineConfig(range_window=bad)
    for bad in (0.0, -0.02, 0.5):
        with pytest.raises(RhamlError, match="range_window_max_scale"):
            pipeline.PipelineConfig(range_window_max_scale=bad)
    from rhaml_jax import evaluate  # its CLI default is the pipeline's (it does not import the pipeline early)

    assert evaluate.Args(data=Path(".")).range_window_max_scale == pipeline.RANGE_WINDOW_MAX_SCALE


@pytest.mark.parametrize("mode", ["batch", "online"])
def test_redetect_in_the_pipeline_runs_and_never_loses_a_detection(stage, mode):
    m, p = stage
    seq = _sequence()
    off = pipeline.PipelineConfig(modules=("iml", "pgo"), pgo_mode=mode, redetect_threshold=None)
    base = pipeline.run_jit(pipeline.PipelineModel(m, off), pipeline.PipelineParams(p), seq)
    cfg = pipeline.PipelineConfig(modules=("iml", "pgo"), pgo_mode=mode, redetect_threshold=0.05)
    res = pipeline.run_jit(pipeline.PipelineModel(m, cfg), pipeline.PipelineParams(p), seq)
    assert bool(jnp.all(res.detected >= base.detected)) and bool(jnp.all(jnp.isfinite(res.xypsi)))


def _refined(xypsi, declined, converged, mask_iou):
    """A refine.RefineResult (N,) with these fields, the rest neutral (no scorer, no alignment margin)."""
    from rhaml_jax import refine

    n = len(xypsi)
    z = lambda *shape: jnp.zeros((n, *shape), jnp.float32)  # noqa: E731
    return refine.RefineResult(z(7), jnp.asarray(xypsi, jnp.float32), z(2) + 0.01, jnp.asarray(declined), z(), z(), z(2, 3),
                               jnp.full((n,), -1.0), jnp.asarray(converged), jnp.zeros(n, bool), jnp.asarray(mask_iou, jnp.float32))


def test_track_joins_only_the_frames_the_mask_confirms():
    """`pipeline.track`: of the frames refined from the graph's answer, one joins where it
    converged, the segmenter's mask fits it (mask_iou >= track_iou) and it agrees with the graph;
    not where the mask does not fit, the refined pose left the graph, the refiner declined or did
    not converge, nor a frame that was not to be tried."""
    cfg = pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), track_iou=0.7)
    n = 7
    predicted = jnp.tile(jnp.array([[3.0, 0.5, 0.3]], jnp.float32), (n, 1))
    near = np.array([3.05, 0.48, 0.35], np.float32)
    xypsi = np.stack([near, near, near, [3.8, 0.5, 0.3], near, near, near])  # frame 3: 0.8 m from the graph's answer
    second = _refined(xypsi, declined=[False, False, False, False, True, False, False],
                      converged=[True, True, True, True, True, False, True], mask_iou=[0.9, 0.7, 0.3, 0.9, 0.9, 0.9, 0.9])
    want = jnp.array([True] * 6 + [False])
    np.testing.assert_array_equal(np.asarray(pipeline.track(cfg, want, predicted, second)),
                                  [True, True, False, False, False, False, False])


def test_track_config_errors(stage):
    """track_iou outside (0, 1], or without ir and batch pgo, is refused naming the field; with an
    IR stage that has no segmenter the pipeline says what is missing."""
    from rhaml_jax import refine, render
    from rhaml_jax.robots import load_robot

    for bad in (0.0, 1.5):
        with pytest.raises(RhamlError, match="track_iou"):
            pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), track_iou=bad)
    for kw in ({"modules": ("iml", "pgo")}, {"modules": ("iml", "ir")}, {"modules": ("iml", "ir", "pgo"), "pgo_mode": "online"}):
        with pytest.raises(RhamlError, match="track_iou"):
            pipeline.PipelineConfig(track_iou=0.7, **kw)
    m, p = stage
    rc = refine.get_refiner_config("refiner_micro")
    stage_params = refine.StageParams(refine.Refiner(refine.net.init_params(rc, jax.random.key(3)), rc),
                                      render.as_mesh(load_robot("pioneer3dx")))
    model = pipeline.PipelineModel(m, pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), chunk=2, track_iou=0.7),
                                   refine.RefineConfig(n_iter=1))
    with pytest.raises(RhamlError, match="segmenter"):
        pipeline.run(model, pipeline.PipelineParams(p, stage_params), _sequence(n=2))


def test_the_second_look_in_the_pipeline():
    """`PipelineConfig.track_iou` in the pipeline (micro networks; an IML whose objectness varies
    from frame to frame, and a segmenter that calls every pixel robot): the frames tried are the
    valid ones the detection left out; the frames it joins are among them and the detections are
    the first pass's plus those; at track_iou 1 (an IoU this mask never reaches) nothing joins and
    the answer is the run's without the second look."""
    from rhaml_jax import refine, render
    from rhaml_jax.refine import segmenter as G
    from rhaml_jax.robots import load_robot

    net, znet = build(get_config("micro"), jax.random.key(1)), build(get_config("tiny_zoom"), jax.random.key(2))
    # the objectness column of the head scaled up: o then differs between the random images
    w = jax.tree_util.tree_map_with_path(
        lambda p, v: v.at[..., 0].multiply(3e4) if jax.tree_util.keystr(p) == "['head']['w'].value" else v, net.params)
    p = iml.IMLParams((_biased(w, jnp.array([0.15, 3.0, 0.0, 0.0])), net.batch_stats), (znet.params, znet.batch_stats))
    m = iml.IMLModel(net, znet, zoom_mirror=True)
    rc = refine.get_refiner_config("refiner_micro")
    sc = G.get_segmenter_config("segmenter_micro")
    sp = G.init_params(sc, jax.random.key(4))
    sp["out"]["b"] = jnp.array([3.0])
    stage_params = refine.StageParams(refine.Refiner(refine.net.init_params(rc, jax.random.key(3)), rc),
                                      render.as_mesh(load_robot("pioneer3dx")), G.Segmenter(sp, sc))
    rcfg = refine.RefineConfig(align=refine.AlignConfig(crop=32, stages=((2.0, 1),), coarse_stages=()), n_iter=1)
    seq = _sequence()._replace(valid=np.array([True] * (N - 1) + [False]))

    def run(track_iou):
        cfg = pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), chunk=2, redetect_threshold=None, track_iou=track_iou)
        return pipeline.run_jit(pipeline.PipelineModel(m, cfg, rcfg), pipeline.PipelineParams(p, stage_params), seq)

    base, loose, strict = run(None), run(0.05), run(1.0)
    first = np.asarray(base.detected)
    assert 0 < first.sum() < N - 1, np.asarray(base.iml.o)  # some frames to look at again
    assert base.second_look is None
    look = loose.second_look
    np.testing.assert_array_equal(np.asarray(look.tried), np.asarray(seq.valid) & ~first)
    joined = np.asarray(look.joined)
    assert not np.any(joined & ~np.asarray(look.tried))
    np.testing.assert_array_equal(np.asarray(loose.detected), first | joined)
    assert np.all(np.asarray(look.mask_iou)[np.asarray(look.tried)] >= 0) and np.all(np.asarray(look.mask_iou)[~np.asarray(look.tried)] == -1)
    assert bool(jnp.all(jnp.isfinite(loose.xypsi)))
    assert not np.any(np.asarray(strict.second_look.joined))
    np.testing.assert_array_equal(np.asarray(strict.detected), first)
    np.testing.assert_allclose(np.asarray(strict.xypsi), np.asarray(base.xypsi), atol=1e-5)
