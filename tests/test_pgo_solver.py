"""Solver internals: SE(2) maths against jaxlie and autodiff, robust kernels, the three linear
solvers against each other, damping of singular / non-finite steps, float32."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from rhaml_jax.pgo import PoseGraph, SolverConfig, graph_cost, optimize
from rhaml_jax.pgo import _residuals as R
from rhaml_jax.pgo._robust import robust_rho_and_weight


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


angles = st.floats(-np.pi + 1e-9, np.pi, allow_nan=False)
small = st.sampled_from([0.0, 1e-12, 1e-7, 1e-4, 9e-3, 1.1e-2, -3e-3])


@settings(max_examples=40, deadline=None)
@given(theta=st.one_of(angles, small), x=st.floats(-5, 5), y=st.floats(-5, 5))
@example(theta=2.936519585668833e-08, x=0.0, y=3.0)  # where jaxlie's exp is 1.3e-9 off (CI, session 37)
def test_log_exp_match_jaxlie(theta, x, y):
    with jax.enable_x64(True):
        p = R.poses_to_se2(jnp.array([[x, y, theta]])).unit_complex_xy
        np.testing.assert_allclose(R.log(p), jaxlie.SE2(p).log(), atol=1e-9)
        v = jnp.array([[x, y, theta]])
        if abs(theta) > 1e-3:  # below, jaxlie's (1 - cos) / theta loses digits to cancellation (1e-9 at 3e-8 rad)
            np.testing.assert_allclose(R.exp(v), jaxlie.SE2.exp(v).unit_complex_xy, atol=1e-9)
        np.testing.assert_allclose(R.exp(v), _se2_exp_reference(x, y, theta), atol=1e-9)
        np.testing.assert_allclose(R.log(R.exp(v)), v, atol=1e-9)


def _se2_exp_reference(x: float, y: float, theta: float) -> np.ndarray:
    """(1, 4) cos, sin, tx, ty of exp((x, y, theta)) in closed form without cancellation:
    (1 - cos t) / t = 2 sin^2(t / 2) / t, both terms written as t -> 0 limits at t = 0."""
    a = np.sinc(theta / np.pi)  # sin(t) / t, 1 at 0
    b = 0.5 * theta * np.sinc(theta / (2 * np.pi)) ** 2  # 2 sin^2(t / 2) / t, 0 at 0
    return np.array([[np.cos(theta), np.sin(theta), a * x - b * y, b * x + a * y]])


def test_jacobians_match_autodiff_and_are_finite_at_zero(x64):
    rng = np.random.default_rng(0)
    N = 12
    x = rng.normal(size=(N, 3)) * 2
    x[3, 2] = x[2, 2]  # an edge with residual angle ~0
    z = rng.normal(size=(N - 1, 3))
    i, j = jnp.arange(N - 1), jnp.arange(1, N)
    T = R.poses_to_se2(jnp.asarray(x)).unit_complex_xy
    Z = R.poses_to_se2(jnp.asarray(z)).inverse().unit_complex_xy
    Z = Z.at[2].set(R.inverse(R.compose(R.inverse(T[2]), T[3])))  # residual exactly 0 on edge 2
    lin = jax.jit(R.linearize)(T, Z, i, j)
    J = jax.jit(jax.jacfwd(lambda d: R.residuals(R.retract(T, d), Z, i, j)))(jnp.zeros((N, 3)))
    e = np.arange(N - 1)
    np.testing.assert_allclose(lin.J_i, J[e, :, e, :], atol=1e-9)
    np.testing.assert_allclose(lin.J_j, J[e, :, e + 1, :], atol=1e-9)
    g = jax.jit(jax.grad(lambda t: graph_cost_jax(t, Z, i, j)))(T)
    assert np.isfinite(g).all()


def graph_cost_jax(T, Z, i, j):
    r = R.residuals(T, Z, i, j)
    return 0.5 * jnp.sum(r * r)


def test_robust_kernels_match_gtsam_definitions(x64):
    s2 = jnp.array([0.0, 0.25, 1.0, 4.0, 100.0])
    s = jnp.sqrt(s2)
    k = 1.5
    rho, w = robust_rho_and_weight(s2, "huber", k)
    np.testing.assert_allclose(0.5 * rho, jnp.where(s <= k, s2 / 2, k * s - k * k / 2))
    np.testing.assert_allclose(w, jnp.where(s <= k, 1.0, k / jnp.maximum(s, 1e-300)))
    rho, w = robust_rho_and_weight(s2, "cauchy", k)
    np.testing.assert_allclose(0.5 * rho, k * k / 2 * jnp.log1p(s2 / k**2))
    np.testing.assert_allclose(w, 1 / (1 + s2 / k**2))
    assert np.isfinite(jax.grad(lambda a: robust_rho_and_weight(a, "huber", k)[0].sum())(s2)).all()


def ladder(K=20, seed=0, noise=0.01):
    """The RHAML graph shape: two odometry chains and one rung per rendezvous."""
    rng = np.random.default_rng(seed)
    N = 2 * (K + 1)
    gt = np.cumsum(rng.normal(size=(N, 3)) * 0.3, axis=0)

    def rel(a, b):
        c, s = np.cos(a[2]), np.sin(a[2])
        d = b[:2] - a[:2]
        return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], np.arctan2(np.sin(b[2] - a[2]), np.cos(b[2] - a[2]))])

    edges, z = [], []
    for k in range(1, K + 1):
        for i, j in [(2 * k - 2, 2 * k), (2 * k - 1, 2 * k + 1), (2 * k + 1, 2 * k)]:
            edges.append((i, j))
            z.append(rel(gt[i], gt[j]) + rng.normal(size=3) * noise)
    E = len(edges)
    info = np.tile(np.diag([100.0, 80.0, 300.0]), (E, 1, 1))
    info[:, 0, 1] = info[:, 1, 0] = 10.0
    return PoseGraph(gt + rng.normal(size=(N, 3)) * 0.2, np.array(edges, np.int32), np.array(z), info, np.arange(N))


def test_linear_solvers_agree(x64):
    g = ladder()
    res = {lin: optimize(g, SolverConfig(linear_solver=lin)) for lin in ("dense", "banded", "sparse")}
    for r in res.values():
        assert r.converged and r.final_cost < r.initial_cost
        assert r.final_cost == pytest.approx(res["dense"].final_cost, rel=1e-9)
        np.testing.assert_allclose(r.poses, res["dense"].poses, atol=1e-7)
    np.testing.assert_allclose(res["dense"].poses[0], g.poses[0], atol=1e-12)  # the gauge stays put


def _block_tridiagonal(M=7, b=6, seed=0):
    """A random SPD block-tridiagonal system: (D, Lo, r) and its dense matrix."""
    rng = np.random.default_rng(seed)
    n = M * b
    J = rng.normal(size=(2 * n, n)) * (np.abs(np.subtract.outer(np.arange(2 * n) // 2, np.arange(n))) < 2 * b - 1)
    A = J.T @ J + np.eye(n)
    A *= np.abs(np.subtract.outer(np.arange(n) // b, np.arange(n) // b)) <= 1  # keep the block band
    A += n * np.eye(n)  # still SPD after the cut
    D = np.stack([A[i * b:(i + 1) * b, i * b:(i + 1) * b] for i in range(M)])
    Lo = np.stack([np.zeros((b, b))] + [A[i * b:(i + 1) * b, (i - 1) * b:i * b] for i in range(1, M)])
    r = rng.normal(size=(M, b, 2))
    return D, Lo, r, A


@pytest.mark.parametrize("how,M", [("thomas", 7), ("twisted", 7), ("twisted", 8), ("twisted", 2)])
def test_band_solvers_match_a_dense_solve(x64, how, M):
    from rhaml_jax.pgo._banded import band_solve

    D, Lo, r, A = _block_tridiagonal(M)
    D, Lo, r = jnp.asarray(D), jnp.asarray(Lo), jnp.asarray(r)
    x = np.asarray(jax.jit(band_solve, static_argnums=3)(D, Lo, r, how))
    ref = np.linalg.solve(A, np.asarray(r).reshape(-1, 2)).reshape(r.shape)
    np.testing.assert_allclose(x, ref, rtol=1e-10, atol=1e-12)
    x32 = np.asarray(band_solve(*(jnp.asarray(a, jnp.float32) for a in (D, Lo, r)), how))
    assert x32.dtype == np.float32
    np.testing.assert_allclose(x32, ref, rtol=1e-3, atol=1e-4)
    bad = D.at[M // 2].multiply(-1.0)  # not positive definite: a non-finite step, which the solver damps
    assert not np.isfinite(np.asarray(band_solve(bad, Lo, r, how))).all()
    batched = jax.vmap(lambda d: band_solve(d, Lo, r, how))(jnp.stack([D, 2 * D]))
    np.testing.assert_allclose(batched[0], ref, rtol=1e-10, atol=1e-12)


def test_band_solvers_give_the_same_optimisation(x64):
    g = ladder(seed=4)
    a = optimize(g, SolverConfig(linear_solver="banded", band_solver="thomas"))
    b = optimize(g, SolverConfig(linear_solver="banded", band_solver="twisted"))
    assert b.iterations == a.iterations and b.final_cost == pytest.approx(a.final_cost, rel=1e-12)
    np.testing.assert_allclose(b.poses, a.poses, atol=1e-10)


def test_ring_is_solved_banded_in_reverse_cuthill_mckee_order(x64):
    """A ring's closing edge makes its natural order's band as wide as the ring; "auto" then
    reorders it to width 2, solves it banded, and returns the poses in the caller's order."""
    from rhaml_jax.pgo._solver import choose_linear_solver

    rng = np.random.default_rng(7)
    N = 31
    a = np.linspace(0, 2 * np.pi, N, endpoint=False)
    gt = np.stack([5 * np.cos(a), 5 * np.sin(a), a + np.pi / 2], 1)
    g0 = ladder()
    edges = np.array([(i, (i + 1) % N) for i in range(N)], np.int32)
    R = lambda t: np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])  # noqa: E731
    z = np.array([[*(R(gt[i, 2]) @ (gt[j, :2] - gt[i, :2])), np.arctan2(np.sin(gt[j, 2] - gt[i, 2]), np.cos(gt[j, 2] - gt[i, 2]))]
                  for i, j in edges]) + rng.normal(size=(len(edges), 3)) * 0.01
    g = PoseGraph(gt + rng.normal(size=(N, 3)) * 0.1, edges, z, np.tile(g0.information[:1], (len(edges), 1, 1)),
                  np.arange(N), fixed=3)
    linear, order = choose_linear_solver(g, SolverConfig())
    assert linear == "banded" and order is not None
    auto, dense = optimize(g, SolverConfig()), optimize(g, SolverConfig(linear_solver="dense"))
    assert (auto.linear_solver, auto.reordered, dense.linear_solver, dense.reordered) == ("banded", True, "dense", False)
    assert auto.final_cost == pytest.approx(dense.final_cost, rel=1e-9)
    np.testing.assert_allclose(auto.poses, dense.poses, atol=1e-7)
    np.testing.assert_allclose(auto.poses[3], g.poses[3], atol=1e-12)  # the gauge, in the caller's numbering


def test_lm_and_gn_reach_the_same_minimum(x64):
    g = ladder(seed=3)
    gn = optimize(g, SolverConfig(method="gn", linear_solver="banded"))
    lm = optimize(g, SolverConfig(method="lm", linear_solver="banded"))
    assert lm.final_cost == pytest.approx(gn.final_cost, rel=1e-9)


def test_singular_system_is_damped_not_nan(x64):
    # a node whose only edge has a rank-deficient contribution after the gauge: make the
    # Hessian singular by giving two nodes identical, tiny information and a huge offset
    g = ladder(K=20, seed=1)
    info = g.information.copy()
    info[5] = np.diag([1e-30, 1e-30, 1e-30]) + 0.0
    bad = g._replace(information=info, poses=g.poses + np.array([1e6, -1e6, 3.0]) * (np.arange(g.num_nodes) % 2)[:, None])
    bad = bad._replace(poses=np.where(np.arange(g.num_nodes)[:, None] == 0, g.poses, bad.poses))
    r = optimize(bad, SolverConfig(linear_solver="banded"))  # same executable as the other ladder tests
    assert np.isfinite(r.poses).all() and np.isfinite(r.final_cost)
    assert r.final_cost <= r.initial_cost


def test_float32_runs():
    g = ladder(seed=2)
    r = optimize(g, SolverConfig(linear_solver="banded", relative_tolerance=1e-6))
    assert r.poses.dtype == np.float32 and np.isfinite(r.poses).all()
    with jax.enable_x64(True):
        ref = optimize(g, SolverConfig(linear_solver="banded"))
    assert r.final_cost == pytest.approx(ref.final_cost, rel=1e-3)
    assert graph_cost(g) > 0
