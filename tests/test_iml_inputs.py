"""IML's input-side options: the grey-world white balance (a global tint undone up to
brightness, a neutral image kept, gains bounded, gradients finite on a black image, the switch
wired through) and the mirrored AMLNet map (decodes to the mirrored pose, averages both views)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rhaml_jax import iml
from rhaml_jax.colour import MAX_GAIN, grey_world, grey_world_gains
from rhaml_jax.errors import RhamlError
from tests.conftest import random_checkpoint

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)


def _scene(seed, h=12, w=16):
    return np.random.default_rng(seed).uniform(20, 200, (1, h, w, 3)).astype(np.float32)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.tuples(*[st.floats(0.5, 1.0)] * 3))
def test_a_tinted_light_is_undone_up_to_brightness(seed, tint):
    # a light of colour t multiplies every pixel's channel c by t_c; grey world divides it back out,
    # leaving the balanced scene scaled by the ratio of the two mean luminances (gains stay inside
    # MAX_GAIN here)
    img = _scene(seed)
    t = np.asarray(tint, np.float32)
    got = np.asarray(grey_world(jnp.asarray(img * t)))
    m = img.mean(axis=(0, 1, 2))
    want = np.asarray(grey_world(jnp.asarray(img))) * float(_LUMA @ (m * t) / (_LUMA @ m))
    np.testing.assert_allclose(got, np.clip(want, 0, 255), rtol=1e-4, atol=1e-2)


def test_a_neutral_image_is_kept_and_gains_are_bounded():
    grey = np.broadcast_to(_scene(0)[..., :1], (1, 12, 16, 3)).copy()
    np.testing.assert_allclose(np.asarray(grey_world(jnp.asarray(grey))), grey, rtol=1e-5)
    green = _scene(1) * np.array([0.01, 1.0, 0.01], np.float32)  # a nearly monochrome light
    g = np.asarray(grey_world_gains(jnp.asarray(green)))
    assert g.min() >= 1 / MAX_GAIN - 1e-6 and g.max() <= MAX_GAIN + 1e-6 and np.isclose(g[0, 0], MAX_GAIN)
    out = np.asarray(grey_world(jnp.asarray(green)))
    assert out.min() >= 0 and out.max() <= 255


def test_gradient_is_finite_on_a_black_image():
    black = jnp.zeros((2, 4, 5, 3))
    g = jax.grad(lambda x: jnp.sum(grey_world(x)))(black)
    assert bool(jnp.all(jnp.isfinite(g)))


def test_iml_switch_balances_the_images_the_networks_see():
    from rhaml_jax.amlnet import build, get_config

    net = build(get_config("micro"), jax.random.key(1))
    plain = iml.IMLModel(net)
    balanced = dataclasses.replace(plain, white_balance=True)
    params = iml.IMLParams((net.params, net.batch_stats), None)
    img = _scene(2, 48, 64)
    K = iml.DEFAULT_CAMERA.resized(64, 48).K
    tint = np.array([0.6, 1.0, 0.7], np.float32)
    a = iml.localize_jit(balanced, params, img * tint, K).xypsi
    b = iml.localize_jit(plain, params, np.asarray(grey_world(jnp.asarray(img * tint))), K).xypsi
    c = iml.localize_jit(plain, params, img * tint, K).xypsi
    np.testing.assert_allclose(a, b, atol=1e-5)
    assert not np.allclose(a, c, atol=1e-5)  # the switch changes what the network sees


def _peak_map(j, i, du, dv, log_r, rel, gh=4, gw=6):
    out = np.zeros((1, gh, gw, 6), np.float32)
    out[..., 0] = -5.0
    out[0, i, j] = [3.0, du, dv, log_r, np.cos(rel), np.sin(rel)]
    return jnp.asarray(out)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 5), st.integers(0, 3), st.floats(0.05, 0.95), st.floats(-0.5, 0.5), st.floats(-3.0, 3.0))
def test_mirrored_heatmap_decodes_to_the_mirrored_pose(j, i, du, log_r, rel):
    from rhaml_jax.amlnet import decode

    m = _peak_map(j, i, du, 0.5, log_r, rel)
    np.testing.assert_allclose(iml.mirror_heatmap(iml.mirror_heatmap(m)), m, atol=1e-6)  # an involution
    a, b = decode(m), decode(iml.mirror_heatmap(m))
    r = float(np.exp(log_r))
    np.testing.assert_allclose(b["x"], a["x"], atol=3e-3 * r)  # the principal point sits beside the centre column:
    np.testing.assert_allclose(b["y"], -a["y"], atol=3e-3 * r)  # the two views 0.0025 rad apart
    d = np.angle(np.exp(1j * (np.asarray(b["psi"]) + np.asarray(a["psi"]))))  # psi -> -psi
    assert abs(float(d[0])) < 4e-3 and float(b["o"][0]) == float(a["o"][0])


def test_amlnet_mirror_averages_both_views_and_needs_a_heatmap_head(tmp_path):
    from rhaml_jax.amlnet import build, get_config

    net = build(get_config("tiny_heat"), jax.random.key(3))
    loud = jax.tree_util.tree_map_with_path(  # head weights x 300: a random map with distinct peaks
        lambda p, v: v * 300.0 if jax.tree_util.keystr(p).startswith("['head']") else v, net.params)
    params = iml.IMLParams((loud, net.batch_stats), None)
    img = _scene(4, 64, 96)
    K = iml.DEFAULT_CAMERA.resized(96, 64).K
    both = iml.localize_jit(iml.IMLModel(net, amlnet_mirror=True), params, img, K)
    one = iml.localize_jit(iml.IMLModel(net), params, img, K)
    mirrored = iml.localize_jit(iml.IMLModel(net, amlnet_mirror=True), params, img[:, :, ::-1].copy(), K)
    assert not np.allclose(both.o, one.o)
    # the averaged map of the mirrored image is the mirror of the averaged map: the same o
    np.testing.assert_allclose(mirrored.o, both.o, rtol=1e-4)
    with pytest.raises(RhamlError, match="heatmap head"):
        iml.load_iml(random_checkpoint(tmp_path / "micro", get_config("micro")), amlnet_mirror=True)
