"""AMLNet's dense head (`amlnet.heatmap`) and its luminance input: targets, decoding, loss,
gradients, and the network at test size (`tiny_heat`)."""

import dataclasses
import tempfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from rhaml_jax.amlnet import build, decode, get_config
from rhaml_jax.amlnet.heatmap import STRIDE, heatmap_loss, net_intrinsics, reference_pixels
from rhaml_jax.camera import DEFAULT_CAMERA

GRID = (32, 40)  # the cpu_heat grid: 256 x 320 input
POSES = np.array([[2.5, 0.0, 0.0], [4.5, 1.2, 2.0], [6.8, -2.1, -3.0], [3.0, -0.4, 1.5]], np.float32)
Z = 0.12


def _exact_map(poses, logit=8.0):
    """The dense output (B, Gh, Gw, 6) that predicts `poses` exactly: the target cell lit, its
    8 neighbours (which the regression also trains) holding their own targets, all others -logit."""
    gh, gw = GRID
    K = net_intrinsics(GRID)
    uv = np.asarray(reference_pixels(jnp.asarray(poses), jnp.asarray(K), Z))
    out = np.zeros((len(poses), gh, gw, 6), np.float32)
    out[..., 0] = -logit
    for i, (p, (u, v)) in enumerate(zip(poses, uv)):
        q = (np.array([u, v]) + 0.5) / STRIDE
        j = np.floor(q).astype(int)
        b = np.arctan2(p[1], p[0])
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                c = j + [dx, dy]
                if 0 <= c[0] < gw and 0 <= c[1] < gh:
                    out[i, c[1], c[0], 1:] = [*(q - c), np.log(np.hypot(p[0], p[1])), np.cos(p[2] - b), np.sin(p[2] - b)]
        out[i, j[1], j[0], 0] = logit
    return jnp.asarray(out)


def test_network_camera_is_the_default_camera_resized():
    K = net_intrinsics(GRID)
    np.testing.assert_allclose(K, np.asarray(DEFAULT_CAMERA.resized(320, 256).K), rtol=1e-6)


def test_decode_inverts_an_exact_map():
    d = decode(_exact_map(POSES))
    np.testing.assert_allclose(d["x"], POSES[:, 0], atol=1e-4)
    np.testing.assert_allclose(d["y"], POSES[:, 1], atol=1e-4)
    dpsi = np.asarray(d["psi"]) - POSES[:, 2]
    np.testing.assert_allclose(np.arctan2(np.sin(dpsi), np.cos(dpsi)), 0.0, atol=1e-5)
    assert np.all(np.asarray(d["o"]) > 0.99)


def test_loss_is_small_for_an_exact_map_and_large_for_a_shifted_one():
    observed = np.array([1, 1, 1, 0], np.float32)
    out = _exact_map(POSES, logit=12.0)
    out = out.at[3, ..., 0].set(-12.0)  # the negative: no cell lit
    loss, parts = heatmap_loss(out, observed, POSES, Z)
    assert float(parts["loss_o"]) < 1e-4
    assert float(parts["loss_heat"]) < 0.05  # the Gaussian's neighbours are not quite 0
    assert float(parts["loss_p"]) == pytest.approx(0.0, abs=1e-5)
    _, w = heatmap_loss(out.at[..., 3].add(0.1), observed, POSES, Z)  # 10 % range error
    assert float(w["loss_p"]) == pytest.approx(1.0, rel=1e-3)  # W_RANGE: as much as a cell of offset
    # a negative's pose is not a target: garbage there changes nothing but its heat
    garbage = out.at[3, ..., 1:].set(99.0)
    _, g = heatmap_loss(garbage, observed, POSES, Z)
    assert float(g["loss_p"]) == pytest.approx(float(parts["loss_p"]), rel=1e-6)


def test_loss_and_decode_are_differentiable_and_finite():
    out = _exact_map(POSES) + 0.1
    observed = jnp.ones(len(POSES))
    g = jax.grad(lambda o: heatmap_loss(o, observed, POSES, Z)[0])(out)
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.abs(g).sum()) > 0
    gx = jax.grad(lambda o: decode(o)["x"].sum())(out)
    assert np.all(np.isfinite(np.asarray(gx))) and float(jnp.abs(gx[..., 3]).sum()) > 0
    # a robot behind the camera (unobserved) keeps every value finite
    behind = POSES.copy()
    behind[0, 0] = -1.0
    loss, _ = heatmap_loss(out, jnp.asarray([0.0, 1, 1, 1]), behind, Z)
    assert np.isfinite(float(loss))


def test_luma_network_ignores_hue():
    """Two images of equal luminance and other colours give the same output (luma=True)."""
    cfg = get_config("tiny_heat")
    net = build(cfg, jax.random.key(1))
    rng = np.random.default_rng(0)
    a = rng.random((2, *cfg.input_hw, 3)).astype(np.float32) * 0.5 + 0.25
    w = np.array([0.299, 0.587, 0.114], np.float32)
    # move colour along a direction of zero luminance: (1, 0, -0.299 / 0.114) scaled
    d = np.array([0.05, 0.0, -0.05 * w[0] / w[2]], np.float32)
    b = a + d
    assert np.allclose(a @ w, b @ w, atol=1e-6)
    out = net.apply(net.params, net.batch_stats, jnp.asarray(a))
    assert out.shape == (2, cfg.input_hw[0] // STRIDE, cfg.input_hw[1] // STRIDE, 6)

    def features(c, x):  # the last stage's features (an untrained head's output is nearly constant)
        n = build(c, jax.random.key(1))
        return np.asarray(nnx.merge(n.graphdef, n.params, n.batch_stats).stage_outputs(jnp.asarray(x))[-1])

    fa, fb = features(cfg, a), features(cfg, b)
    np.testing.assert_allclose(fa, fb, atol=1e-5 * np.abs(fa).max())
    colour = dataclasses.replace(cfg, luma=False)
    assert np.abs(features(colour, a) - features(colour, b)).max() > 1e-2 * np.abs(fa).max()


def test_heatmap_configs_are_checked():
    from rhaml_jax.errors import RhamlError

    with pytest.raises(RhamlError, match="heatmap head needs"):
        dataclasses.replace(get_config("tiny_heat"), depths=(1, 1), dims=(16, 16), mlp_ratios=(2, 2))
    with pytest.raises(RhamlError, match="head must be"):
        dataclasses.replace(get_config("tiny_heat"), head="dense")


def test_heatmap_amlnet_in_iml_with_a_zoom_stage():
    """IML with a heatmap AMLNet and a luminance zoom stage runs jitted on full-size images."""
    from rhaml_jax.iml import IMLModel, IMLParams, localize_jit

    net = build(get_config("tiny_heat"), jax.random.key(2))
    znet = build(dataclasses.replace(get_config("tiny_zoom"), luma=True), jax.random.key(3))
    model = IMLModel(net, znet)
    params = IMLParams((net.params, net.batch_stats), (znet.params, znet.batch_stats))
    images = jnp.asarray(np.random.default_rng(1).integers(0, 255, (2, 480, 640, 3)), jnp.uint8)
    est = localize_jit(model, params, images, DEFAULT_CAMERA.K)
    assert est.xypsi.shape == (2, 3) and np.all(np.isfinite(np.asarray(est.xypsi)))
    assert np.all((np.asarray(est.o) >= 0) & (np.asarray(est.o) <= 1))


def test_init_starts_a_luma_network_from_a_colour_checkpoint_of_the_same_architecture():
    from rhaml_jax.amlnet import shipped_checkpoint
    from rhaml_jax.amlnet.trainer import initial_weights
    from rhaml_jax.errors import RhamlError

    params, _ = initial_weights(get_config("zoom_cpu_luma"), shipped_checkpoint("zoom_cpu"))
    assert jax.tree.structure(params) == jax.tree.structure(build(get_config("zoom_cpu_luma"), abstract=True).params)
    with pytest.raises(RhamlError, match="not the 'cpu_heat' being trained .*differ in .*dims"):
        initial_weights(get_config("cpu_heat"), shipped_checkpoint("zoom_cpu"))
    # the crop's geometry changes no weight: the Pioneer's zoom stage starts a TurtleBot's (fit)
    import dataclasses

    small = dataclasses.replace(get_config("zoom_cpu_luma"), zoom_length_m=0.178, zoom_centre_z_m=0.09)
    params, _ = initial_weights(small, shipped_checkpoint("zoom_luma_cpu"))
    assert jax.tree.structure(params) == jax.tree.structure(build(small, abstract=True).params)


def _ycbcr_turn(x, angle):
    """x (..., 3) RGB with its BT.601 (Cb, Cr) turned by `angle` about the grey axis (luminance
    kept): a hue rotation of the whole image."""
    M = np.array([[0.299, -0.168736, 0.5], [0.587, -0.331264, -0.418688], [0.114, 0.5, -0.081312]])
    ycc = x @ M
    c, s = np.cos(angle), np.sin(angle)
    ycc[..., 1:] = ycc[..., 1:] @ np.array([[c, s], [-s, c]])
    return (ycc @ np.linalg.inv(M)).astype(np.float32)


def test_chroma_contrast_reads_chroma_but_no_hue_or_tint():
    """The chroma channel (cpu_heat_chroma): equal to a brute-force box mean; unchanged by a
    global tint (a constant added to every pixel) or a hue rotation of the whole image, so the
    network's output is too; changed by a local colour that differs from its surroundings."""
    from rhaml_jax.amlnet.model import chroma_contrast

    rng = np.random.default_rng(0)
    a = (rng.random((1, 24, 30, 3)) * 0.4 + 0.3).astype(np.float32)
    c = np.asarray(chroma_contrast(jnp.asarray(a), 5))[0]
    M = np.array([[-0.168736, 0.5], [-0.331264, -0.418688], [0.5, -0.081312]])
    cbcr = a[0] @ M
    i, j = 0, 13  # an edge pixel: the mean over the window's pixels inside the image
    ref = cbcr[max(0, i - 2):i + 3, max(0, j - 2):j + 3].reshape(-1, 2).mean(0)
    assert abs(c[i, j] - np.linalg.norm(cbcr[i, j] - ref)) < 1e-4
    tint = a + np.array([0.05, -0.03, 0.08], np.float32)
    np.testing.assert_allclose(np.asarray(chroma_contrast(jnp.asarray(tint), 5))[0], c, atol=1e-5)
    turned = _ycbcr_turn(a, 2.0)
    assert turned.min() >= 0 and turned.max() <= 1
    np.testing.assert_allclose(np.asarray(chroma_contrast(jnp.asarray(turned), 5))[0], c, atol=1e-5)
    patch = a.copy()
    patch[0, 10:14, 10:14] = a[0, 10:14, 10:14] @ np.eye(3)[[2, 0, 1]]  # the channels swapped there
    assert np.abs(np.asarray(chroma_contrast(jnp.asarray(patch), 5))[0] - c)[10:14, 10:14].max() > 0.02

    cfg = dataclasses.replace(get_config("tiny_heat"), chroma=True, chroma_window=5)
    net = build(cfg, jax.random.key(1))
    x = (rng.random((1, *cfg.input_hw, 3)) * 0.4 + 0.3).astype(np.float32)
    out, out_turned = (np.asarray(net.apply(net.params, net.batch_stats, jnp.asarray(v))) for v in (x, _ycbcr_turn(x, 2.0)))
    np.testing.assert_allclose(out, out_turned, atol=1e-4 * np.abs(out).max())


@pytest.mark.parametrize("name, channel", [("cpu_heat_chroma", 2), ("cpu_heat_log", 1)])
def test_a_luma_checkpoint_starts_a_chroma_or_log_network_exactly(name, channel):
    """`initial_weights` moves the freed luminance copy's stem weights onto the first: the chroma
    or log-luminance network starts with the luma network's outputs, and cannot start a network
    without its channel; both channels need luma, the chroma window is odd."""
    from rhaml_jax.amlnet import shipped_checkpoint
    from rhaml_jax.amlnet.checkpoint import load_model
    from rhaml_jax.amlnet.trainer import initial_weights, luma_channel_freed
    from rhaml_jax.errors import RhamlError

    net0, p0, s0 = load_model(shipped_checkpoint("heat_nocart_cpu"))
    cfg = get_config(name)
    p1, s1 = initial_weights(cfg, shipped_checkpoint("heat_nocart_cpu"))
    net1 = build(cfg, abstract=True)
    x = jnp.asarray(np.random.default_rng(2).random((1, *cfg.input_hw, 3)), jnp.float32)
    a, b = np.asarray(net0.apply(p0, s0, x)), np.asarray(net1.apply(p1, s1, x))
    np.testing.assert_allclose(a, b, atol=1e-5 * np.abs(a).max())
    assert np.abs(np.asarray(p1["stem"][...])[:, :, channel]).max() == 0
    before = np.asarray(p0["stem"][...]).copy()
    luma_channel_freed(p0, channel)
    np.testing.assert_array_equal(np.asarray(p0["stem"][...]), before)  # the caller's state is left as it was
    with pytest.raises(RhamlError, match="needs luma"):
        dataclasses.replace(cfg, luma=False)
    with pytest.raises(RhamlError, match="chroma_window must be odd"):
        dataclasses.replace(get_config("cpu_heat_chroma"), chroma_window=4)
    with tempfile.TemporaryDirectory() as d:  # a checkpoint with the channel cannot start one without it
        from rhaml_jax.amlnet.checkpoint import Checkpoints
        from rhaml_jax.amlnet.config import config_to_dict

        ck = Checkpoints(d, keep=1)
        ck.save(0, {"params": p1, "batch_stats": s1}, {"model_config": config_to_dict(cfg), "weights_only": True})
        ck.close()
        with pytest.raises(RhamlError, match="cannot start 'cpu_heat'"):
            initial_weights(get_config("cpu_heat"), d)


def test_log_luminance_reads_ratios():
    """The log-luminance channel: equal brightness ratios give equal differences (tyres at 2 %
    on a floor at 6 % as a body at 20 % on a floor at 60 %, up to the floor of the log), and a
    dark image's outline stays as strong as a light one's."""
    from rhaml_jax.amlnet.model import LOG_FLOOR, log_luminance

    f = lambda v: float(log_luminance(jnp.asarray(v, jnp.float32)))  # noqa: E731
    assert f(0.6) - f(0.2) == pytest.approx(np.log(0.62 / 0.22), rel=1e-5)
    assert f(0.06 - LOG_FLOOR) - f(0.02 - LOG_FLOOR) == pytest.approx(f(0.6 - LOG_FLOOR) - f(0.2 - LOG_FLOOR), rel=1e-5)
    assert np.isfinite(f(0.0))
