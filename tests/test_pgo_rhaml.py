"""Algorithm 1 step by step: DeleteErroneousNodes, ConstructPoseGraph (node and edge counts,
either robot observing), CalculateInformationMatrix (eqs. 9-10), GlobalOptimization (A_0 fixed,
A_0 T B_0 accuracy), g2o export, robust kernel against wrong observations."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rhaml_jax.errors import RhamlError
from rhaml_jax.pgo import (
    RhamlPGOConfig, Rendezvous, SolverConfig,
    delete_erroneous_nodes, format_g2o, observation_from_xy_yaw_rp, parse_g2o, rhaml_pgo_jit, rhaml_pose_graph,
)
from rhaml_jax.pgo._rhaml_graph import _prepare
from rhaml_jax.pgo import simulate_rendezvous

K = 40  # the same size in test_pgo_gtsam.py: one compiled rhaml_pgo_jit for both
_pgo = rhaml_pgo_jit
_delete = jax.jit(delete_erroneous_nodes, static_argnums=1)


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


def _dev(rv):
    return jax.tree.map(jnp.asarray, rv)


def test_delete_erroneous_nodes_drops_tilted_and_keeps_time_order():
    sim = simulate_rendezvous(K, seed=4, tilted_fraction=0.25)
    rv = _dev(sim.rendezvous)
    # roll, pitch from an independent implementation (R = Rz(yaw) Ry(pitch) Rx(roll))
    q = np.asarray(sim.rendezvous.observation)[:, :4]  # wxyz
    rpy = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("xyz")
    expect = np.all(np.abs(rpy[:, :2]) <= np.deg2rad(10), axis=1)
    compact, valid, keep = _delete(rv, 10.0)
    np.testing.assert_array_equal(keep, expect)
    n = int(valid.sum())
    assert n == expect.sum() == K - 10
    kept = np.flatnonzero(expect)
    np.testing.assert_allclose(compact.observation[:n], rv.observation[kept])
    np.testing.assert_allclose(compact.odom_a[1 : n + 1], rv.odom_a[kept + 1])
    np.testing.assert_allclose(compact.odom_a[0], rv.odom_a[0])
    # padding repeats the last kept rendezvous (identity odometry, no mutual information)
    np.testing.assert_allclose(compact.odom_b[n + 1 :], np.repeat(rv.odom_b[kept[-1] + 1][None], K - n, 0))


def test_graph_sizes_edges_and_information():
    sim = simulate_rendezvous(K, seed=5, tilted_fraction=0.1)
    cfg = RhamlPGOConfig(kappa=80.0, tau=0.25)
    g = rhaml_pose_graph(sim.rendezvous, cfg)
    n = K - 4
    assert g.num_nodes == 2 * (1 + n) and g.num_edges == 3 * n
    # delete_erroneous_nodes, construct_pose_graph, calculate_information_matrix, jitted together
    _, arrays, info = _prepare(_dev(sim.rendezvous), 10.0, 80.0, 0.25)
    info = np.asarray(info)
    rp = np.asarray(arrays.roll_pitch)
    for k in range(n):
        a, b, m = 3 * k, 3 * k + 1, 3 * k + 2
        np.testing.assert_allclose(info[a], np.eye(3) * 80.0)
        np.testing.assert_allclose(info[b], np.eye(3) * 80.0)
        km = 40.0 * np.exp(-abs(rp[k, 0]) - abs(rp[k, 1]))
        np.testing.assert_allclose(info[m], np.diag([km, km, 0.25 * km]))
        A_k, B_k = 2 * (k + 1), 2 * (k + 1) + 1
        assert tuple(g.edges[a]) == (A_k - 2, A_k) and tuple(g.edges[b]) == (B_k - 2, B_k)
        observer_a = bool(np.asarray(arrays.a_observes)[k])
        assert tuple(g.edges[m]) == ((A_k, B_k) if observer_a else (B_k, A_k))
    assert np.all(info[3 * n :] [2::3] == 0)  # padded mutual edges carry nothing
    assert set(np.asarray(arrays.a_observes)[:n]) == {True, False}  # both robots observe
    # exportable: g2o text round trip
    h = parse_g2o(format_g2o(g), "rhaml")
    np.testing.assert_allclose(h.information, g.information)


def test_global_optimization_recovers_a0_T_b0_and_fixes_a0():
    sim = simulate_rendezvous(K, seed=6)
    out = _pgo(_dev(sim.rendezvous))
    assert bool(out.converged) and float(out.final_cost) < float(out.initial_cost)
    np.testing.assert_allclose(out.poses_a[0], sim.rendezvous.odom_a[0], atol=1e-12)
    err = np.asarray(out.a0_T_b0) - sim.a0_T_b0
    # observation noise 5 cm / 2 deg, odometry drift of ~40 m of driving: a few cm expected
    assert np.hypot(err[0], err[1]) < 0.15 and abs(err[2]) < np.deg2rad(2.0)
    # both simulated odometries start at the true first pose in one world frame: F ~ identity
    F = np.asarray(out.odom_a_T_odom_b)
    assert np.hypot(F[0], F[1]) < 0.15 and abs(F[2]) < np.deg2rad(2.0)


def test_float32_converges_like_float64():
    """In float32 (JAX's default) the cost is only known to ~1e-6 relative: the solver must
    stop at that noise floor, not count rounding as failed steps and damp to max_lambda."""
    sim = simulate_rendezvous(K, seed=6)
    ref = _pgo(_dev(sim.rendezvous))
    tight = RhamlPGOConfig(solver=SolverConfig(linear_solver="banded", relative_tolerance=1e-12, absolute_tolerance=0.0))
    with jax.enable_x64(False):
        out = _pgo(_dev(jax.tree.map(lambda a: np.asarray(a, np.float32) if a.dtype == np.float64 else a, sim.rendezvous)),
                   config=tight)
    assert out.a0_T_b0.dtype == jnp.float32
    assert bool(out.converged) and int(out.iterations) <= int(ref.iterations) + 1
    np.testing.assert_allclose(out.a0_T_b0, ref.a0_T_b0, atol=1e-4)


def test_robust_kernel_handles_wrong_observations():
    sim = simulate_rendezvous(K, seed=7, outlier_fraction=0.3)
    rv = _dev(sim.rendezvous)
    plain = _pgo(rv)
    robust = _pgo(rv, config=RhamlPGOConfig(solver=SolverConfig(linear_solver="banded", robust="cauchy",
                                                                  robust_delta=1.0, max_iterations=50)))

    def err(o):
        e = np.asarray(o.a0_T_b0) - sim.a0_T_b0
        return np.hypot(e[0], e[1])

    assert err(robust) < 0.1
    assert err(robust) < err(plain)


def test_bad_rendezvous_input():
    sim = simulate_rendezvous(5, seed=0)
    with pytest.raises(RhamlError, match="odom_a"):
        rhaml_pose_graph(sim.rendezvous._replace(odom_a=sim.rendezvous.odom_a[:3]))
    with pytest.raises(RhamlError, match="odom_b: .*non-finite"):
        rhaml_pose_graph(sim.rendezvous._replace(odom_b=np.full((6, 3), np.nan)))
    tilted = observation_from_xy_yaw_rp(np.ones((5, 3)), np.full((5, 2), 0.5))
    with pytest.raises(RhamlError, match="no mutual edge"):
        rhaml_pose_graph(sim.rendezvous._replace(observation=np.asarray(tilted)))
    assert isinstance(sim.rendezvous, Rendezvous)
