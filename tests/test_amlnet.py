"""AMLNet: fast kernels vs plain lax convolutions, parameter/MAC counts, configs, bad input."""

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from rhaml_jax.amlnet import ops
from rhaml_jax.amlnet.acn import acn, acn_reference, init_acn_params
from rhaml_jax.amlnet.block import AIncepBlock
from rhaml_jax.amlnet.init import HostInit
from rhaml_jax.amlnet.config import (AMLNetConfig, config_from_dict, config_to_dict, get_config, num_outputs)
from rhaml_jax.amlnet.count import count_macs, count_params
from rhaml_jax.amlnet.functional import build, check_images
from rhaml_jax.amlnet.model import scale_head
from rhaml_jax.errors import RhamlError

TOL = 1e-5


def _scaled(tree, key, std=0.3):
    """Replaces every leaf by N(0, std^2) so that every term of the network matters."""
    leaves, treedef = jax.tree.flatten(tree)
    keys = jax.random.split(key, len(leaves))
    return jax.tree.unflatten(treedef, [std * jax.random.normal(k, l.shape, l.dtype) for k, l in zip(keys, leaves)])


@pytest.mark.parametrize("kernels,dense", [((3, 5, 7), True), ((3,), True), ((3, 5), False), ((), True)])
def test_acn_matches_lax_reference(kernels, dense):
    c = 5
    p = _scaled(init_acn_params(jax.random.key(0), c, kernels, dense), jax.random.key(1))
    x = jax.random.normal(jax.random.key(2), (2, 9, 11, c))
    f = jax.jit(lambda p, x: acn(p, x, kernels, dense))
    r = jax.jit(lambda p, x: acn_reference(p, x, kernels, dense))
    a, b = f(p, x), r(p, x)
    assert a.shape == x.shape
    np.testing.assert_allclose(a, b, atol=TOL, rtol=TOL)


def test_acn_reference_is_eq2_by_hand():
    """The reference itself against eq. (2) spelled out with numpy loops (K = {3}, dense)."""
    c, k = 2, 3
    p = _scaled(init_acn_params(jax.random.key(3), c, (k,), True), jax.random.key(4))
    x = np.asarray(jax.random.normal(jax.random.key(5), (1, 4, 5, c)), np.float64)
    out = np.asarray(acn_reference(p, jnp.asarray(x, jnp.float32), (k,), True))
    P = {n: np.asarray(v, np.float64) for n, v in p.items()}
    want = x.copy()
    for i in range(4):
        for j in range(5):
            logits = x[0, i, j] @ P["mix"]  # (2,) = (x-direction, y-direction) with n = 1
            w = np.exp(logits - logits) / 1.0  # softmax over one size is 1
            gx = P["bx3"].copy()
            gy = P["by3"].copy()
            for t in range(k):
                jj, ii = j + t - 1, i + t - 1
                if 0 <= jj < 5:
                    gx += x[0, i, jj] @ P["x3"][t]
                if 0 <= ii < 4:
                    gy += x[0, ii, j] @ P["y3"][t]
            want[0, i, j] += w[0] * gx + w[1] * gy
    np.testing.assert_allclose(out, want, atol=TOL, rtol=TOL)


def test_kernels_match_lax_reference():
    x = jax.random.normal(jax.random.key(6), (2, 8, 12, 4))
    w = jax.random.normal(jax.random.key(7), (11, 4))
    b = jax.random.normal(jax.random.key(8), (4,))
    wd = jax.random.normal(jax.random.key(9), (5, 4, 3))
    w2 = jax.random.normal(jax.random.key(10), (3, 3, 4))
    wp = jax.random.normal(jax.random.key(11), (4, 4, 4, 5))
    w1 = jax.random.normal(jax.random.key(12), (4, 6))

    @jax.jit
    def pairs(x):
        out = []
        for axis in (1, 2):
            out.append((ops.depthwise_1d(x, w, b, axis), ops.depthwise_1d_ref(x, w, b, axis)))
            out.append((ops.dense_1d(x, wd, None, axis), ops.dense_1d_ref(x, wd, None, axis)))
            out.append((ops.pointwise(ops.im2col_1d(x, 5, axis), wd.reshape(20, 3)), ops.dense_1d_ref(x, wd, None, axis)))
        out.append((ops.depthwise_2d(x, w2, b), ops.depthwise_2d_ref(x, w2, b)))
        out.append((ops.patchify(x, wp), ops.patchify_ref(x, wp)))
        out.append((ops.pointwise(x, w1), ops.pointwise_ref(x, w1)))
        return out

    for a, r in pairs(x):
        np.testing.assert_allclose(a, r, atol=TOL, rtol=TOL)


def test_depthwise_gradient_matches_the_reference_convolution():
    """The hand-written VJP of the shifted-slice depthwise convolution against XLA's autodiff
    of lax's grouped convolution, along both axes, with an uneven cotangent."""
    x = jax.random.normal(jax.random.key(1), (2, 9, 7, 5))
    w = jax.random.normal(jax.random.key(2), (11, 5))
    b = jax.random.normal(jax.random.key(3), (5,))
    ct = jax.random.normal(jax.random.key(4), (2, 9, 7, 5))
    for axis in (1, 2):
        grads = [jax.jit(jax.grad(lambda x, w, b, f=f: jnp.sum(f(x, w, b, axis) * ct), argnums=(0, 1, 2)))(x, w, b)
                 for f in (ops.depthwise_1d, ops.depthwise_1d_ref)]
        for a, r in zip(*grads):
            np.testing.assert_allclose(a, r, atol=1e-4, rtol=1e-4)


def test_gelu_matches_jax_exact_gelu_and_its_derivative():
    """The erf-based GELU with its own JVP against jax.nn.gelu(approximate=False) (erfc form),
    values and first derivatives, from deep in the negative tail to large positive inputs and
    at 0; and against central finite differences in float64."""
    h = jnp.concatenate([jnp.linspace(-12.0, 12.0, 2001), jnp.array([0.0, -0.0, 1e-8, -1e-8])])
    ref = ops.gelu_ref
    np.testing.assert_allclose(ops.gelu(h), ref(h), atol=1e-6, rtol=1e-6)
    d, d_ref = (jax.vmap(jax.grad(f))(h) for f in (ops.gelu, ref))
    np.testing.assert_allclose(d, d_ref, atol=1e-6, rtol=1e-5)
    with jax.enable_x64(True):
        z = jnp.linspace(-6.0, 6.0, 61, dtype=jnp.float64)
        eps = 1e-6
        fd = (ops.gelu(z + eps) - ops.gelu(z - eps)) / (2 * eps)
        np.testing.assert_allclose(jax.vmap(jax.grad(ops.gelu))(z), fd, atol=1e-8)


def test_mlp_gradient_matches_reference():
    x = jax.random.normal(jax.random.key(1), (2, 5, 6, 8))
    w1, w2 = (0.3 * jax.random.normal(jax.random.key(i), s) for i, s in ((2, (8, 16)), (3, (16, 8))))
    b1, b2 = jax.random.normal(jax.random.key(4), (16,)), jax.random.normal(jax.random.key(5), (8,))
    ct = jax.random.normal(jax.random.key(6), x.shape)
    grads = [jax.grad(lambda *a, f=f: jnp.sum(f(*a) * ct), argnums=(0, 1, 2, 3, 4))(x, w1, b1, w2, b2) for f in (ops.mlp, ops.mlp_ref)]
    for a, r in zip(*grads):
        np.testing.assert_allclose(a, r, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("name", ["tiny", "tiny_k0"])
def test_block_matches_reference(name):
    cfg = get_config(name)
    blk = AIncepBlock(16, 2, cfg, init=HostInit(jax.random.key(0)))
    gd, params, stats = nnx.split(blk, nnx.Param, nnx.BatchStat)
    params = _scaled(params, jax.random.key(1))
    x = jax.random.normal(jax.random.key(2), (2, 8, 8, 16))

    @jax.jit
    def run(params, stats, x):
        outs = []
        for impl in ("fast", "reference"):
            for train in (False, True):
                m = nnx.merge(gd, params, stats, copy=True)
                outs.append(m(x, train, None, impl))
        return outs

    fe, ft, re_, rt = run(params, stats, x)
    np.testing.assert_allclose(fe, re_, atol=TOL, rtol=TOL)
    np.testing.assert_allclose(ft, rt, atol=TOL, rtol=TOL)
    assert float(jnp.abs(fe - x).max()) > 1e-2  # the branch is not negligible


@pytest.mark.parametrize("variant", [{}, {"pool": "flatten", "angle_head": "cossin"}, {"pool": "gap", "angle_head": "axis"}])
def test_network_matches_reference(variant):
    cfg = replace(get_config("micro"), **variant)
    net = build(cfg, jax.random.key(0))
    params = _scaled(net.params, jax.random.key(1), 0.1)
    x = jax.random.uniform(jax.random.key(2), (2, *cfg.input_hw, 3))

    @jax.jit
    def run(p):
        return [net.train_apply(p, net.batch_stats, x, None, impl) for impl in ("fast", "reference")]

    (a, sa), (b, sb) = run(params)
    assert a.shape == (2, num_outputs(cfg))
    np.testing.assert_allclose(a, b, atol=TOL, rtol=TOL)
    for u, v in zip(jax.tree.leaves(sa), jax.tree.leaves(sb)):
        np.testing.assert_allclose(u, v, atol=TOL, rtol=TOL)


def test_head_is_standardised():
    """The raw head is scaled to metres around the scenarios' middle depth: a zero head
    predicts (o logit 0, x 4.5 m, y 0, psi 0 | cos 0, sin 0)."""
    np.testing.assert_allclose(scale_head(jnp.zeros((1, 5))), [[0.0, 4.5, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(scale_head(jnp.ones((1, 4))), [[1.0, 6.5, 2.0, 1.0]])
    # the zoom stage's corrections have no offset and their own spreads
    np.testing.assert_allclose(scale_head(jnp.zeros((1, 7)), "zoom"), jnp.zeros((1, 7)))
    np.testing.assert_allclose(scale_head(jnp.ones((1, 7)), "zoom"), [[1.0, 0.15, 0.05, 1.0, 1.0, 1.0, 1.0]])


def test_paper_and_frontnet_counts():
    paper = get_config("paper")
    net = build(paper, abstract=True)
    p, m = count_params(paper, net=net), count_macs(paper, net=net)
    assert abs(p - 49.8e6) <= 0.01 * 49.8e6, p
    assert abs(m - 8.8e9) <= 0.1e9, m
    fn = get_config("frontnet")
    p, m = count_params(fn), count_macs(fn)
    assert round(p / 1e6, 2) == 0.32, p  # "0.32 M" (323,364)
    assert round(m / 1e9, 3) == 0.066, m
    # describe: by name, or a network's own config (a checkpoint's, which a name may not match)
    from rhaml_jax.amlnet import describe

    assert describe("frontnet") == describe(fn) == {"config": "frontnet", "params": p, "macs": m, "input_shape": [224, 224, 3]}
    assert describe(replace(fn, name="mine"))["config"] == "mine"


def test_config_roundtrip_and_validation():
    for name in ("paper", "cpu", "frontnet", "cpu_k0"):
        cfg = get_config(name)
        assert config_from_dict(config_to_dict(cfg)) == cfg
    with pytest.raises(RhamlError, match="unknown model config"):
        get_config("nope")
    with pytest.raises(RhamlError, match="divisible"):
        AMLNetConfig("bad", input_hw=(100, 100))
    with pytest.raises(RhamlError, match="odd"):
        AMLNetConfig("bad", acn_kernels=(3, 4))


def test_bad_images():
    cfg = get_config("tiny")
    good = np.zeros((2, 32, 32, 3), np.float32)
    check_images(cfg, good)
    with pytest.raises(RhamlError, match="32 x 32"):
        check_images(cfg, np.zeros((2, 64, 32, 3), np.float32))
    with pytest.raises(RhamlError, match="channels"):
        check_images(cfg, np.zeros((2, 32, 32, 4), np.float32))
    with pytest.raises(RhamlError, match="dtype"):
        check_images(cfg, np.zeros((2, 32, 32, 3), np.uint8))
    with pytest.raises(RhamlError, match="shape"):
        check_images(cfg, np.zeros((32, 32, 3), np.float32))
