"""Cross-check against GTSAM (test-only dependency): same cost function, same initial guess,
final cost equal to a relative 1e-6 or lower, on the standard 2D benchmarks of
../shared/data/pgo and on RHAML two-robot graphs built by our code. Float64 throughout."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rhaml_jax.pgo import SolverConfig, graph_cost, optimize, read_g2o, rhaml_pgo_jit, rhaml_pose_graph
from rhaml_jax.pgo import simulate_rendezvous
from tests.conftest import shared_path

gtsam = pytest.importorskip("gtsam", reason="gtsam (pip package) is the reference for these tests")


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


def gtsam_problem(graph):
    """The same graph for GTSAM: BetweenFactorPose2 with the full information matrix, a tight
    prior on the fixed pose (as in REFERENCE_VALUES.md), our initial guess."""
    fg = gtsam.NonlinearFactorGraph()
    for (i, j), z, L in zip(graph.edges, graph.measurements, graph.information):
        fg.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), gtsam.noiseModel.Gaussian.Information(L)))
    f = graph.fixed
    fg.add(gtsam.PriorFactorPose2(f, gtsam.Pose2(*graph.poses[f]),
                                  gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))))
    init = gtsam.Values()
    for k, p in enumerate(graph.poses):
        init.insert(k, gtsam.Pose2(*p))
    return fg, init


def gtsam_values(poses):
    v = gtsam.Values()
    for k, p in enumerate(poses):
        v.insert(k, gtsam.Pose2(*p))
    return v


def gtsam_lm(fg, init):
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    params.setMaxIterations(200)
    return fg.error(gtsam.LevenbergMarquardtOptimizer(fg, init, params).optimize())


DATASETS = ["M3500", "intel", "CSAIL", "FR079", "FRH", "manhattan", "ring", "ringCity", "city10000"]


@pytest.mark.parametrize("name", DATASETS)
def test_benchmark_graph_matches_gtsam(name):
    graph = read_g2o(shared_path("pgo", f"{name}.g2o"))
    fg, init = gtsam_problem(graph)
    ours = optimize(graph, SolverConfig())
    assert np.isfinite(ours.poses).all() and ours.converged
    # the same cost function: GTSAM's error at our initial guess and at our result
    assert ours.initial_cost == pytest.approx(fg.error(init), rel=1e-9)
    assert ours.final_cost == pytest.approx(fg.error(gtsam_values(ours.poses)), rel=1e-9, abs=1e-9)
    ref = gtsam_lm(fg, init)
    assert ours.final_cost <= ref * (1 + 1e-6) + 1e-12, (ours.final_cost, ref)
    assert ours.final_cost >= ref * (1 - 1e-6) - 1e-12, (ours.final_cost, ref)  # same minimum


def test_mitb_chordal_reaches_global_optimum_where_odometry_start_does_not():
    graph = read_g2o(shared_path("pgo", "MITb.g2o"))
    odo = optimize(graph, SolverConfig())  # GTSAM's GN fails here (indeterminate system)
    assert np.isfinite(odo.poses).all() and np.isfinite(odo.final_cost)
    assert odo.final_cost == pytest.approx(385.12, rel=1e-3)  # GTSAM LM's local minimum too
    ch = optimize(graph, SolverConfig(initialization="chordal"))
    assert ch.final_cost == pytest.approx(20.6035, rel=1e-5)
    fg, _ = gtsam_problem(graph)
    assert ch.final_cost == pytest.approx(fg.error(gtsam_values(ch.poses)), rel=1e-9)


_rhaml_pgo = rhaml_pgo_jit  # shared with test_pgo_rhaml.py (same K: one compilation)


@pytest.mark.parametrize("seed,tilted", [(0, 0.0), (1, 0.2), (2, 0.1)])
def test_rhaml_graph_matches_gtsam(seed, tilted):
    sim = simulate_rendezvous(K=40, seed=seed, tilted_fraction=tilted)
    graph = rhaml_pose_graph(sim.rendezvous)
    fg, init = gtsam_problem(graph)
    # the exported graph (sparse path: padded sizes, one compilation for every seed)
    ours = optimize(graph, SolverConfig(linear_solver="sparse"))
    assert ours.initial_cost == pytest.approx(fg.error(init), rel=1e-9)
    ref = gtsam_lm(fg, init)
    assert ours.final_cost == pytest.approx(ref, rel=1e-6)
    # the jitted end-to-end Algorithm 1 (padded static shapes, banded solver) reaches it too
    out = _rhaml_pgo(jax.tree.map(jnp.asarray, sim.rendezvous))
    assert float(out.final_cost) == pytest.approx(ref, rel=1e-6)
    n = int(out.num_kept)
    assert 2 * (n + 1) == graph.num_nodes and 3 * n == graph.num_edges
    poses = np.stack([np.asarray(out.poses_a[: n + 1]), np.asarray(out.poses_b[: n + 1])], 1).reshape(-1, 3)
    assert graph_cost(graph, poses) == pytest.approx(ref, rel=1e-6)
