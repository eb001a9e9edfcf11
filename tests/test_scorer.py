"""The refinement's heading scorer: the search finds the peak of a known score between grid
points and reports its flip confidence; the CLI trains and resumes; the checkpoint refuses
another robot or kind; examples are a pure function of (seed, index) with the hypotheses'
heading errors as constructed; the network can learn to pick the true heading; refine() with it
stays finite, declines a bad start and passes gradients straight through. Tiny config
(scorer_micro) and data."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rhaml_jax import render
from rhaml_jax.data import load_bop_model, load_rgb, read_bop
from rhaml_jax.errors import RhamlError
from rhaml_jax.refine import RefineConfig, load_refiner, load_scorer, refine
from rhaml_jax.refine import scorer as S
from tests.conftest import train_tiny


def _wrap(a):
    return np.arctan2(np.sin(a), np.cos(a))


def _gaussian_score(psi_true, sigma=np.deg2rad(12.0)):
    """A score peaked at psi_true, smooth in the heading (what the training targets ask for)."""
    return lambda h: -0.5 * (jnp.arctan2(jnp.sin(h - psi_true), jnp.cos(h - psi_true)) / sigma) ** 2


@settings(max_examples=30, deadline=None)
@given(st.floats(-np.pi, np.pi), st.floats(-np.pi, np.pi))
def test_search_finds_the_peak_between_grid_points(psi_true, psi0):
    r = S.search_heading(_gaussian_score(psi_true), jnp.float32(psi0), 24, 5, np.deg2rad(5.0))
    assert abs(_wrap(float(r.psi) - psi_true)) < np.deg2rad(0.3)
    assert float(r.flip_confidence) > 0.99


def test_search_keeps_the_start_on_a_flat_or_doubtful_score():
    r = S.search_heading(lambda h: jnp.zeros_like(h), jnp.float32(0.3), 24, 5, np.deg2rad(5.0))
    assert float(r.psi) == pytest.approx(0.3, abs=1e-6) and float(r.flip_confidence) == pytest.approx(0.5, abs=1e-6)
    assert not bool(r.flipped)
    # two equal peaks, front and back (at 1 and 1 + pi): the one on psi0's side, mass split evenly
    two = lambda h: 5 * jnp.cos(2 * (h - 1.0))  # noqa: E731
    r = S.search_heading(two, jnp.float32(0.8), 24, 5, np.deg2rad(5.0))
    assert abs(float(r.psi) - 1.0) < np.deg2rad(0.5) and abs(float(r.flip_confidence) - 0.5) < 0.05
    # a peak behind psi0 with 70 % of the mass: turned at threshold 0.5, kept at 0.8
    behind = lambda h: jnp.log(0.7 * jnp.exp(-0.5 * (jnp.cos(h - np.pi) - 1) ** 2 * 40) + 0.3 / 24)  # noqa: E731
    lo = S.search_heading(behind, jnp.float32(0.0), 24, 5, np.deg2rad(5.0), flip_threshold=0.5)
    hi = S.search_heading(behind, jnp.float32(0.0), 24, 5, np.deg2rad(5.0), flip_threshold=0.99)
    assert bool(lo.flipped) and abs(abs(float(lo.psi)) - np.pi) < np.deg2rad(0.5)
    assert not bool(hi.flipped) and abs(float(hi.psi)) < np.pi / 2


@pytest.fixture(scope="module")
def bop_set(tiny_bop_set):
    return tiny_bop_set


@pytest.fixture(scope="module")
def run(bop_set, tmp_path_factory):
    return train_tiny("scorer", "scorer_micro", bop_set, tmp_path_factory.mktemp("scorerun"))


def test_cli_trains_resumes_and_logs(run):
    out, res, args = run
    rows = [json.loads(l) for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [2, 4] and all(np.isfinite(r["loss"]) for r in rows)
    assert 0 <= rows[-1]["val_top1"] <= 1 and 0 <= rows[-1]["val_err_deg"] <= 180 and res["step"] == 4
    from rhaml_jax.train import main

    with pytest.raises(RhamlError, match="already holds a checkpoint"):
        main(args)


def test_checkpoint_refuses_another_robot_or_kind(run, bop_set, tmp_path):
    out, _, _ = run
    model = load_bop_model(bop_set)
    sc = load_scorer(out, model)
    assert sc.cfg == S.get_scorer_config("scorer_micro")
    with pytest.raises(RhamlError, match="checkpoint is for robot"):
        load_scorer(out, dataclasses.replace(model, vertices=model.vertices * 1.5))
    with pytest.raises(RhamlError, match="not a refiner checkpoint"):
        load_refiner(out)
    again = load_scorer(S.export_scorer(out, tmp_path / "exported"), model)
    for a, b in zip(jax.tree.leaves(sc.params), jax.tree.leaves(again.params)):
        np.testing.assert_array_equal(a, b)


def test_examples_are_pure_and_their_errors_as_constructed(bop_set):
    cfg = S.get_scorer_config("scorer_micro")
    a, b = S.ScorerSource(bop_set, "train", cfg, 4, seed=3), S.ScorerSource(bop_set, "train", cfg, 4, seed=3)
    for x, y in zip(a(1), b(1)):
        np.testing.assert_array_equal(x, y)
    batch = a(0)
    H = len(S.train_offsets_deg(cfg))
    assert batch.T_hyp.shape == (4, H, 7) and batch.err.shape == (4, H) and batch.obs.shape == (4, 32, 32, 3)
    offs = np.deg2rad(S.train_offsets_deg(cfg))
    # every hypothesis is the first turned by its offset; all share one position
    np.testing.assert_allclose(_wrap(batch.err - batch.err[:, :1] - offs), 0, atol=1e-4)
    np.testing.assert_allclose(batch.T_hyp[..., 4:], batch.T_hyp[:, :1, 4:].repeat(H, 1), atol=1e-5)


def test_repainted_renders_keep_the_parts_and_the_rest_of_the_example(bop_set):
    """`ScorerConfig.paint_prob`: at 1 every example renders a repainted robot (each colour group of
    the model one new colour, in [0, 1]), and the loss reads it; at 0 the model's own colours; the
    rest of an example is the same either way (the paint has its own random stream)."""
    from rhaml_jax.data._appearance import color_groups

    cfg = S.get_scorer_config("scorer_flip_micro")
    plain = S.ScorerSource(bop_set, "train", cfg, 4, seed=2)(0)
    painted = S.ScorerSource(bop_set, "train", dataclasses.replace(cfg, paint_prob=1.0), 4, seed=2)(0)
    model = load_bop_model(bop_set)
    own = np.asarray(model.face_colors, np.float32)
    np.testing.assert_array_equal(plain.paint, np.broadcast_to(own, plain.paint.shape))
    for field in ("obs", "box", "K", "T_hyp", "err"):
        np.testing.assert_array_equal(getattr(plain, field), getattr(painted, field))
    _, group = color_groups(own)
    for p in painted.paint:
        assert np.abs(p - own).max() > 0.05 and p.min() >= 0 and p.max() <= 1
        for g in np.unique(group):
            assert np.ptp(p[group == g], axis=0).max() == 0  # a part is repainted whole
    mesh = render.as_mesh(model)
    params = S.init_params(cfg, jax.random.key(1))
    params = jax.tree.map(lambda a: a + 0.1 * jax.random.normal(jax.random.key(2), a.shape), params)  # not the zero head
    la, _ = S.scorer_loss(cfg, mesh, params, tuple(jnp.asarray(x) for x in plain))
    lb, _ = S.scorer_loss(cfg, mesh, params, tuple(jnp.asarray(x) for x in painted))
    assert abs(float(la) - float(lb)) > 1e-6
    with pytest.raises(RhamlError, match="paint_prob"):
        dataclasses.replace(cfg, paint_prob=1.5)


def test_the_network_learns_to_pick_the_true_heading(bop_set):
    """Overfit two crops: the scorer must come to rate the hypothesis nearest the truth best
    (a scorer that cannot tell renders apart stays at top-1 = chance and loss log H)."""
    cfg = S.get_scorer_config("scorer_micro")
    src = S.ScorerSource(bop_set, "train", cfg, 2, seed=0)
    b = tuple(jnp.asarray(x) for x in src(0))
    mesh = render.as_mesh(load_bop_model(bop_set))
    params = S.init_params(cfg, jax.random.key(0))
    tx = optax.adam(3e-3)
    opt = tx.init(params)
    grad = jax.jit(jax.value_and_grad(lambda p: S.scorer_loss(cfg, mesh, p, b), has_aux=True))
    (l0, _), _ = grad(params)
    for _ in range(150):
        (loss, parts), g = grad(params)
        upd, opt = tx.update(g, opt)
        params = optax.apply_updates(params, upd)
    assert float(loss) < 0.5 * float(l0) and float(parts["top1"]) == 1.0 and float(parts["flip"]) == 0.0


def test_refine_with_a_scorer_is_finite_declines_and_passes_gradients(run, bop_set):
    from rhaml_jax.refine import Refiner, RefinerConfig
    from rhaml_jax.refine import net as N

    out, _, _ = run
    model = load_bop_model(bop_set)
    sc = load_scorer(out, model)
    rc = RefinerConfig(name="t", crop=32, widths=(8, 16), hidden=16, n_points=32, n_iter=1)
    ref = Refiner(N.init_params(rc, jax.random.key(1)), rc)
    mesh = render.as_mesh(model)
    f = read_bop(bop_set, "train")[0]
    img = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    cfg = RefineConfig(camera_height_m=float(f.camera_height_m))
    go = jax.jit(lambda init: refine(ref, mesh, img, f.K, init, cfg, scorer=sc))
    r = go(jnp.asarray(f.xypsi, jnp.float32))
    assert not bool(r.declined) and np.isfinite(np.asarray(r.xypsi)).all()
    assert r.iterates.shape == (1 + 1 + 1 + cfg.post_iter, 3) and 0 <= float(r.flip_prob) <= 1
    bad = go(jnp.asarray([-2.0, 0.0, 0.0], jnp.float32))  # behind the camera
    assert bool(bad.declined) and float(bad.flip_prob) == -1.0
    np.testing.assert_allclose(bad.xypsi, [-2.0, 0.0, 0.0])
    g = jax.grad(lambda init: jnp.sum(go(init).xypsi))(jnp.asarray(f.xypsi, jnp.float32))
    assert np.isfinite(np.asarray(g)).all() and float(jnp.abs(g[2])) > 0


@settings(max_examples=40, deadline=None)
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-np.pi, np.pi), st.floats(-np.pi, np.pi),
       st.floats(-0.3, 0.3), st.floats(-0.3, 0.3))
def test_a_turn_about_a_pivot_keeps_it_in_place_and_undoes(x, y, psi, angle, px, py):
    pose, pivot = jnp.asarray([x, y, psi]), jnp.asarray([px, py])
    t = S.turned(pose, angle, pivot)

    def world(p):  # the pivot's place in the world at planar pose p
        c, s = jnp.cos(p[2]), jnp.sin(p[2])
        return p[:2] + jnp.stack([c * px - s * py, s * px + c * py])

    np.testing.assert_allclose(world(t), world(pose), atol=1e-5)
    np.testing.assert_allclose(float(t[2]), psi + angle, atol=1e-6)
    np.testing.assert_allclose(S.turned(t, -angle, pivot), pose, atol=1e-5)


def test_flip_examples_turn_about_the_box_centre(bop_set):
    """The front/back scorer's two hypotheses: the drawn estimate (within near_deg of the truth)
    and it turned by 180 deg about the model's box centre, which stays where it was."""
    cfg = S.get_scorer_config("scorer_flip_micro")
    src = S.ScorerSource(bop_set, "train", cfg, 6, seed=5)
    b = src(0)
    assert b.T_hyp.shape == (6, 2, 7)
    assert np.all(np.abs(np.rad2deg(b.err[:, 0])) <= cfg.near_deg + 1e-3)
    np.testing.assert_allclose(np.abs(_wrap(b.err[:, 1] - b.err[:, 0])), np.pi, atol=1e-4)
    v = src.model.vertices
    centre = np.append(S.pivot_xy(cfg, v), 0.0)
    assert abs(centre[0]) > 0.01  # the Pioneer's box centre is not its frame's origin: the test can fail
    import jaxlie

    at = [np.asarray(jaxlie.SE3(jnp.asarray(b.T_hyp[:, h])) @ jnp.asarray(centre)) for h in range(2)]
    np.testing.assert_allclose(at[0], at[1], atol=1e-5)
    with pytest.raises(RhamlError, match="pivot"):
        dataclasses.replace(cfg, pivot="tail")


def test_the_flip_search_turns_about_the_box_centre(bop_set, monkeypatch):
    """With a score that prefers the turned hypothesis, refine.heading_search answers the pose
    turned by 180 deg about the box centre, with the probability that the answer is wrong;
    gradients pass straight through; a threshold above the other side's probability keeps the pose."""
    from rhaml_jax.refine import heading_search

    cfg = S.get_scorer_config("scorer_flip_micro")
    model = load_bop_model(bop_set)
    mesh = render.as_mesh(model)
    sc = S.Scorer(S.init_params(cfg, jax.random.key(0)), cfg)
    monkeypatch.setattr(S, "apply", lambda c, p, x: jnp.asarray([0.0, 2.0]))  # (psi0, psi0 + pi)
    f = read_bop(bop_set, "train")[0]
    img = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    x0 = jnp.asarray(f.xypsi, jnp.float32)
    pose, p_wrong, _ = heading_search(sc, mesh, img, f.K, x0, float(f.camera_height_m), 0.5)
    pivot = S.pivot_xy(cfg, np.asarray(mesh.vertices))
    want = S.turned(x0, np.pi, jnp.asarray(pivot))
    np.testing.assert_allclose(pose[:2], want[:2], atol=1e-4)
    assert abs(_wrap(float(pose[2] - want[2]))) < 1e-4
    assert float(p_wrong) == pytest.approx(1 - float(jax.nn.sigmoid(2.0)), abs=1e-5)  # the answer's doubt
    kept, p_kept, _ = heading_search(sc, mesh, img, f.K, x0, float(f.camera_height_m), 0.9)
    np.testing.assert_allclose(kept, x0, atol=1e-6)
    assert float(p_kept) == pytest.approx(float(jax.nn.sigmoid(2.0)), abs=1e-5)
    g = jax.jacobian(lambda x: heading_search(sc, mesh, img, f.K, x, float(f.camera_height_m), 0.5)[0])(x0)
    np.testing.assert_allclose(g, np.eye(3), atol=1e-6)


def test_the_mirrored_read_drops_a_left_right_cue(bop_set, monkeypatch):
    """`RefineConfig.scorer_mirror`: a score that reads a left-right difference of the crop is
    cancelled by the mirrored read (the other side's probability becomes 1/2); a score that reads
    the crop as a whole is the same with or without it."""
    from rhaml_jax.refine import heading_search

    cfg = S.get_scorer_config("scorer_flip_micro")
    mesh = render.as_mesh(load_bop_model(bop_set))
    sc = S.Scorer(S.init_params(cfg, jax.random.key(0)), cfg)
    f = read_bop(bop_set, "train")[0]
    img = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    img = img * jnp.linspace(0.2, 1.0, img.shape[1])[None, :, None]  # a left-right gradient: the cue can be read
    x0 = jnp.asarray(f.xypsi, jnp.float32)
    half = cfg.crop // 2

    def p_other(reads, mirror):
        monkeypatch.setattr(S, "apply", lambda c, p, x: jnp.stack([jnp.zeros(()), reads(x)]))
        return float(heading_search(sc, mesh, img, f.K, x0, float(f.camera_height_m), 1.0, mirror)[1])

    left_right = lambda x: 20.0 * (x[0, :, :half, 0].mean() - x[0, :, half:, 0].mean())  # noqa: E731
    whole = lambda x: 5.0 * x[0, :, :, 0].mean()  # noqa: E731
    assert abs(p_other(left_right, False) - 0.5) > 0.05  # the plain read sees the cue
    assert p_other(left_right, True) == pytest.approx(0.5, abs=1e-5)
    assert p_other(whole, True) == pytest.approx(p_other(whole, False), abs=1e-5)
    assert abs(p_other(whole, False) - 0.5) > 0.05


def test_a_threshold_outside_zero_to_one_is_refused():
    for bad in (-0.1, 1.5):
        with pytest.raises(RhamlError, match="flip_threshold"):
            RefineConfig(flip_threshold=bad)
    with pytest.raises(RhamlError, match="post_iter"):
        RefineConfig(post_iter=-1)
