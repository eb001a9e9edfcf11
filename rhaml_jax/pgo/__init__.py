"""Pose-graph optimisation on SE(2): the paper's Algorithm 1 (RHAML two-robot graphs) and a
jit-compiled Gauss-Newton / Levenberg-Marquardt solver for any 2D g2o pose graph.

Public API:
- `PoseGraph`, `SolverConfig`, `SolveResult`: data types.
- `read_g2o`, `write_g2o`, `parse_g2o`, `format_g2o`: g2o files (VERTEX_SE2 / EDGE_SE2 / FIX).
- `optimize(graph, config)`: solves with the first (or FIXed) pose held fixed.
- `graph_cost(graph, poses)`: GTSAM's cost 0.5 sum r^T Lambda r, r = Log(z^-1 x_i^-1 x_j).
- `chordal_initialization(graph)`: rotations then translations by linear least squares.
- RHAML (Algorithm 1): `Rendezvous`, `RhamlPGOConfig`, `delete_erroneous_nodes`,
  `construct_pose_graph`, `calculate_information_matrix`, `global_optimization`, `rhaml_pgo`
  (`rhaml_pgo_jit`: the same, jit-compiled and shared),
  `rhaml_pose_graph` (the graph as a `PoseGraph`, e.g. for `write_g2o`).
- Robust fusion (consensus + GNC-TLS, information from noise models): `OdometryNoise`,
  `FusionConfig`, `FusionResult`, `fuse` / `fuse_jit` (batch), `fuse_online` /
  `fuse_online_jit` (row k from rendezvous <= k), `fuse_online_redetect` /
  `fuse_online_redetect_jit` (the same, with candidate rows that join where they `agrees` with
  the graph before them), `fusion_graph` (the graph GNC sees, host side; `gtsam_gnc` hands it to
  GTSAM's GncOptimizer, the reference),
  `odometry_information`, `rendezvous_from_frames` (per-frame arrays -> Rendezvous);
  range calibration from odometry: `range_model`, `rescale_observations`, and `fuse_calibrated`
  (fuse, calibrate, fuse again, kept only if the calibrated fusion keeps `MIN_SUPPORT` of the rows);
  simulators `simulate_static_observer`, `simulate_two_robots` (`FusionSequence`).
"""

from ._chordal import chordal_initialization
from ._gtsam import gtsam_gnc, gtsam_poses
from ._fusion import (
    FusionConfig,
    FusionGraph,
    FusionResult,
    OdometryNoise,
    agrees,
    fuse,
    fuse_jit,
    fuse_online,
    fuse_online_jit,
    fuse_online_redetect,
    fuse_online_redetect_jit,
    fusion_graph,
    odometry_information,
    rendezvous_from_frames,
)
from ._fusion_sim import FusionSequence, simulate_static_observer, simulate_two_robots
from ._g2o import format_g2o, parse_g2o, read_g2o, write_g2o
from ._rhaml_graph import (
    Rendezvous,
    RhamlPGOConfig,
    RhamlPGOResult,
    calculate_information_matrix,
    construct_pose_graph,
    delete_erroneous_nodes,
    global_optimization,
    observation_from_xy_yaw_rp,
    rhaml_pgo,
    rhaml_pgo_jit,
    rhaml_pose_graph,
)
from ._scale import MAX_LOG_SCALE, MIN_SUPPORT, RANGE_R0_M, fuse_calibrated, range_model, rescale_observations
from ._simulate import simulate_rendezvous
from ._solver import graph_cost, optimize
from ._types import PoseGraph, SolverConfig, SolveResult
from ._validate import validate_graph

__all__ = [
    "MAX_LOG_SCALE", "MIN_SUPPORT", "RANGE_R0_M", "fuse_calibrated", "range_model", "rescale_observations", "simulate_rendezvous",
    "PoseGraph", "SolverConfig", "SolveResult",
    "read_g2o", "write_g2o", "parse_g2o", "format_g2o", "validate_graph",
    "optimize", "graph_cost", "chordal_initialization",
    "Rendezvous", "RhamlPGOConfig", "RhamlPGOResult", "delete_erroneous_nodes", "construct_pose_graph",
    "calculate_information_matrix", "global_optimization", "rhaml_pgo", "rhaml_pgo_jit", "rhaml_pose_graph",
    "observation_from_xy_yaw_rp",
    "OdometryNoise", "FusionConfig", "FusionResult", "FusionGraph", "agrees", "fuse", "fuse_jit", "fuse_online",
    "fuse_online_jit", "fuse_online_redetect", "fuse_online_redetect_jit", "fusion_graph", "gtsam_gnc", "gtsam_poses", "odometry_information", "rendezvous_from_frames",
    "FusionSequence", "simulate_static_observer", "simulate_two_robots",
]
