"""The observed-mask segmenter of the silhouette alignment: the CLI trains and resumes, the
checkpoint rebuilds it and refuses another robot or another kind of network, its examples are a
pure function of (seed, index), it can learn a mask, and refine() with it declines a bad start
without NaN. Tiny config (segmenter_micro) and data."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from rhaml_jax import render
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import load_bop_model, load_rgb, read_bop, write_training_set
from rhaml_jax.errors import RhamlError
from rhaml_jax.refine import RefineConfig, load_refiner, load_segmenter, observed_mask, refine
from rhaml_jax.refine import segmenter as G
from tests.conftest import train_tiny


@pytest.fixture(scope="module")
def bop_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("segment") / "set"
    write_training_set(root, "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=7, num=21, negatives=0, workers=1)
    return root


@pytest.fixture(scope="module")
def run(bop_set, tmp_path_factory):
    return train_tiny("segmenter", "segmenter_micro", bop_set, tmp_path_factory.mktemp("segrun"))


def test_cli_trains_resumes_and_logs(run, tmp_path):
    out, res, args = run
    rows = [json.loads(l) for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [2, 4] and all(np.isfinite(r["loss"]) for r in rows)
    assert 0 <= rows[-1]["val_iou"] <= 1 and res["step"] == 4
    from rhaml_jax.train import main

    with pytest.raises(RhamlError, match="already holds a checkpoint"):
        main(args)
    # --init: a new run fine-tunes from this one's weights (and says so in its checkpoints)
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta

    ft = [tmp_path / "ft" if a == str(out) else a for a in args]
    assert main([str(a) for a in ft] + ["--init", str(out)])["step"] == 4
    assert checkpoint_meta(tmp_path / "ft")["initialised_from"] == str(out)


def test_checkpoint_rebuilds_and_refuses_another_robot_or_kind(run, bop_set, tmp_path):
    out, _, _ = run
    model = load_bop_model(bop_set)
    seg = load_segmenter(out, model)
    assert seg.cfg == G.get_segmenter_config("segmenter_micro")
    other = dataclasses.replace(model, vertices=model.vertices * 1.5)
    with pytest.raises(RhamlError, match="checkpoint is for robot"):
        load_segmenter(out, other)
    with pytest.raises(RhamlError, match="not a refiner checkpoint"):
        load_refiner(out)
    exported = G.export_segmenter(out, tmp_path / "exported")
    again = load_segmenter(exported, model)
    for a, b in zip(jax.tree.leaves(seg.params), jax.tree.leaves(again.params)):
        np.testing.assert_array_equal(a, b)


def test_examples_are_a_pure_function_of_seed_and_index(bop_set):
    cfg = G.get_segmenter_config("segmenter_micro")
    a, b = G.SegmenterSource(bop_set, "train", cfg, 3, seed=2), G.SegmenterSource(bop_set, "train", cfg, 3, seed=2)
    for x, y in zip(a(1), b(1)):
        np.testing.assert_array_equal(x, y)
    batch = a(0)
    assert batch.crop.shape == (3, 32, 32, 3) and batch.mask.shape == (3, 32, 32)
    assert 0 <= batch.mask.min() and batch.mask.max() <= 1 and (batch.mask.mean((1, 2)) > 0.02).all()
    assert not np.allclose(a(0).crop, a(1).crop)


def test_learns_a_mask(bop_set):
    """Fitting one batch: the mask IoU rises from the zero-initialised output's (nothing) to most of the robot."""
    cfg = G.get_segmenter_config("segmenter_micro")
    b = G.SegmenterSource(bop_set, "train", cfg, 8, seed=0)(0)
    params = G.init_params(cfg, jax.random.key(0))
    tx = optax.adam(3e-3)
    opt = tx.init(params)

    @jax.jit
    def step(params, opt):
        (_, parts), g = jax.value_and_grad(lambda p: G.segmenter_loss(cfg, p, b.crop, b.mask), has_aux=True)(params)
        u, opt = tx.update(g, opt)
        return optax.apply_updates(params, u), opt, parts

    first = None
    for _ in range(200):
        params, opt, parts = step(params, opt)
        first = parts if first is None else first
    assert float(first["iou"]) < 0.3 and float(parts["iou"]) > 0.6, (first, parts)


def test_refine_with_a_segmenter_declines_a_start_behind_the_camera(run, bop_set):
    out, _, _ = run
    model = load_bop_model(bop_set)
    seg = load_segmenter(out, model)
    f = [f for f in read_bop(bop_set, "train") if f.observed][0]
    image = jnp.asarray(load_rgb(f.rgb), jnp.float32) / 255
    mesh = render.as_mesh(model)
    from rhaml_jax.refine import AlignConfig

    cfg = RefineConfig(align=AlignConfig(crop=32, stages=((2.0, 2),), coarse_stages=((1.0, 1, "xy"),)))
    behind = jnp.array([-2.0, 0.1, 0.3])
    r = refine(None, mesh, image, jnp.asarray(f.K), behind, cfg, segmenter=seg)
    assert bool(r.declined) and np.allclose(r.xypsi, behind) and np.all(np.isfinite(r.pose)) and not bool(r.align_skipped)
    r = refine(None, mesh, image, jnp.asarray(f.K), jnp.asarray(f.xypsi, jnp.float32), cfg, segmenter=seg)
    assert not bool(r.declined) and np.all(np.isfinite(r.xypsi))
    m = observed_mask(seg, image, jnp.array([10.0, 10.0, 90.0, 90.0]))
    assert m.shape == (32, 32) and float(m.min()) >= 0 and float(m.max()) <= 1



def test_fine_starts_centre_the_crops_on_the_robot(bop_set):
    """`SegmenterConfig.starts` "fine" (the crops the alignment after the cascade sees): the robot's
    mask is centred in every crop, far tighter than around the paper's noise; an unknown setting is
    refused."""
    with pytest.raises(RhamlError, match="SegmenterConfig.starts"):
        G.SegmenterConfig(starts="far")
    micro = G.get_segmenter_config("segmenter_micro")

    def offsets(cfg):
        b = G.SegmenterSource(bop_set, "train", cfg, 16, seed=3)(0)
        S = cfg.crop
        u = (np.arange(S) + 0.5) / S - 0.5
        m = b.mask / b.mask.sum((1, 2), keepdims=True)
        return np.hypot((m.sum(1) * u).sum(-1), (m.sum(2) * u).sum(-1))  # (B,) centroid's offset, crop widths

    fine, coarse = offsets(dataclasses.replace(micro, starts="fine")), offsets(micro)
    assert np.median(fine) < 0.05 and np.median(fine) < 0.5 * np.median(coarse), (fine, coarse)
