"""The graph `fuse` solves, handed to GTSAM's GncOptimizer (the reference for its GNC-TLS):
for cross-checks and benchmarks. gtsam is not a dependency; this imports it when called."""

from __future__ import annotations

import numpy as np

from rhaml_jax.pgo._fusion import FusionConfig, FusionGraph
from rhaml_jax.pgo._types import PoseGraph


def gtsam_gnc(pg: PoseGraph, g: FusionGraph, cfg: FusionConfig):
    """(GncGaussNewtonOptimizer, mutual factor indices) set up as `fuse`'s GNC-TLS over the graph
    of `fusion_graph`: odometry and the start prior known inliers, the mutual edges robust with
    `fuse`'s initial weights (its consensus) and inlier threshold `cfg.barc_sq`. After
    `opt.optimize()`, `opt.getWeights()[mutual]` are the mutual edges' final weights."""
    import gtsam

    fg = gtsam.NonlinearFactorGraph()
    known = []
    for e, ((i, j), z, L, rob) in enumerate(zip(pg.edges, pg.measurements, pg.information, pg.robust_edges)):
        fg.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), gtsam.noiseModel.Gaussian.Information(L)))
        if not rob:
            known.append(e)
    fg.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*pg.poses[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    known.append(fg.size() - 1)
    init = gtsam.Values()
    for k, p in enumerate(pg.poses):
        init.insert(k, gtsam.Pose2(*p))
    params = gtsam.GncGaussNewtonParams(gtsam.GaussNewtonParams())
    params.setKnownInliers(known)
    opt = gtsam.GncGaussNewtonOptimizer(fg, init, params)
    opt.setInlierCostThresholds(cfg.barc_sq)
    mutual = np.flatnonzero(pg.robust_edges)
    w0 = np.ones(fg.size())
    w0[mutual] = np.asarray(g.init_weights)[np.asarray(g.usable)]
    opt.setWeights(w0)
    return opt, mutual


def gtsam_poses(values, num_nodes: int) -> np.ndarray:
    """(num_nodes, 3) x, y, theta of a GTSAM Values of Pose2 keyed 0..num_nodes-1."""
    return np.array([[values.atPose2(k).x(), values.atPose2(k).y(), values.atPose2(k).theta()] for k in range(num_nodes)])
