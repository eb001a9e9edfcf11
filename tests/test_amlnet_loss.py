"""The AMLNet loss (paper eqs. 3-5) and the decoding of each heading head."""

import jax.numpy as jnp
import numpy as np
import pytest

from rhaml_jax.amlnet.loss import amlnet_loss, decode

PSI = np.array([0.0, 0.3, -2.0, 3.1, -3.1, 1.5707963])


def _head(psi, kind, x=4.0, y=-1.0, lean=1.0):
    """The raw head that predicts (x, y, psi) exactly (o logit 5)."""
    n = len(psi)
    base = [np.full(n, 5.0), np.full(n, x), np.full(n, y)]
    if kind == "psi":
        return jnp.asarray(np.stack(base + [psi], 1))
    cs = [lean * np.cos(psi), lean * np.sin(psi)]
    if kind == "cossin":
        return jnp.asarray(np.stack(base + cs, 1))
    return jnp.asarray(np.stack(base + cs + [np.cos(2 * psi), np.sin(2 * psi)], 1))


@pytest.mark.parametrize("kind", ["psi", "cossin", "axis"])
def test_decode_inverts_an_exact_head(kind):
    d = decode(_head(PSI, kind), kind)
    np.testing.assert_allclose(np.cos(d["psi"]), np.cos(PSI), atol=1e-6)
    np.testing.assert_allclose(np.sin(d["psi"]), np.sin(PSI), atol=1e-6)
    np.testing.assert_allclose(d["x"], 4.0)
    assert np.all(np.asarray(d["o"]) > 0.99)


def test_axis_head_takes_the_end_its_direction_outputs_lean_to():
    """However short the (cos, sin) outputs, their sign picks psi or psi + pi on the axis."""
    for lean, flip in ((0.01, 0.0), (-0.01, np.pi), (-1.0, np.pi)):
        psi = np.asarray(decode(_head(PSI, "axis", lean=lean), "axis")["psi"])
        d = psi - (PSI + flip)
        np.testing.assert_allclose(np.arctan2(np.sin(d), np.cos(d)), 0.0, atol=1e-5)


@pytest.mark.parametrize("kind", ["psi", "cossin", "axis"])
def test_loss_is_zero_for_an_exact_head_and_masks_negatives(kind):
    pose = np.stack([np.full(len(PSI), 4.0), np.full(len(PSI), -1.0), PSI], 1)
    observed = np.array([1, 1, 1, 1, 0, 1], np.float32)
    out = _head(PSI, kind)
    out = out.at[:, 0].set(jnp.where(observed > 0, 30.0, -30.0))
    _, parts = amlnet_loss(out, observed, pose, kind)
    assert float(parts["loss_p"]) == pytest.approx(0.0, abs=1e-10)
    assert float(parts["loss_o"]) == pytest.approx(0.0, abs=1e-10)
    # a negative's pose is not a target: garbage there changes nothing
    garbage = out.at[4, 1:].set(99.0)
    _, g = amlnet_loss(garbage, observed, pose, kind)
    assert float(g["loss_p"]) == pytest.approx(0.0, abs=1e-10)


def test_loss_weights_and_wrapping():
    """L_A = L_o + w_p L_p, L_p = mean over positives of dx^2 + dy^2 + w_psi d^2, with the
    heading error wrapped (psi = pi - 0.1 against pi + 0.1 is 0.2 apart, not 2 pi - 0.2)."""
    out = jnp.asarray([[0.0, 4.5, 1.0, np.pi - 0.1]])
    pose = np.array([[4.0, 1.0, -np.pi + 0.1]])
    loss, parts = amlnet_loss(out, np.ones(1), pose, "psi", w_psi=3.0, w_p=2.0)
    want_p = 0.25 + 3 * 0.2**2
    assert float(parts["loss_p"]) == pytest.approx(want_p, rel=1e-5)
    assert float(parts["loss_psi"]) == pytest.approx(0.2**2, rel=1e-5)
    assert float(loss) == pytest.approx(np.log(2) + 2 * want_p, rel=1e-5)
    # w_xy weighs the x and y terms (out is 0.5 off in x, 0 in y; then 1 off in y)
    _, parts = amlnet_loss(out, np.ones(1), pose, "psi", w_psi=3.0, w_p=2.0, w_xy=(10.0, 100.0))
    assert float(parts["loss_p"]) == pytest.approx(10 * 0.25 + 3 * 0.2**2, rel=1e-5)
    _, parts = amlnet_loss(out.at[0, 2].set(2.0), np.ones(1), pose, "psi", w_psi=3.0, w_xy=(10.0, 100.0))
    assert float(parts["loss_p"]) == pytest.approx(10 * 0.25 + 100 + 3 * 0.2**2, rel=1e-5)


def test_front_back_ambiguity_keeps_the_axis():
    """Targets psi and psi + pi for the same prediction: the cossin loss is smallest at
    (0, 0), which carries no heading at all; the axis outputs' optimum is still the axis."""
    pose = np.array([[4.0, 0.0, 0.7], [4.0, 0.0, 0.7 + np.pi]])
    obs = np.ones(2)

    def loss_at(kind, c, s, c2=0.0, s2=0.0):
        row = [0.0, 4.0, 0.0, c, s] + ([c2, s2] if kind == "axis" else [])
        return float(amlnet_loss(jnp.asarray([row, row]), obs, pose, kind)[1]["loss_psi"])

    assert loss_at("cossin", 0.0, 0.0) < loss_at("cossin", np.cos(0.7), np.sin(0.7))
    best = loss_at("axis", 0.0, 0.0, np.cos(1.4), np.sin(1.4))
    assert best < loss_at("axis", 0.0, 0.0, 0.0, 0.0) and best < loss_at("axis", 0.0, 0.0, np.cos(1.0), np.sin(1.0))
