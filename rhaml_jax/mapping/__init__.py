"""Occupancy maps and map fusion (the paper's application: two robots merge their maps by A_0 T B_0).

- `OccupancyMap`, `read_map`, `write_map`: ROS map_server maps (PGM + YAML: resolution, origin,
  occupied_thresh, free_thresh, negate, mode trinary / scale / raw), as map_saver, slam_toolbox
  and Cartographer's ROS export write them.
- `merge_maps(a, b, a_T_b)`: B resampled into A's frame (nearest on the classes by default, see
  `rhaml_jax.mapping._merge` for why) and the union on A's lattice; `resample`.
- `LidarConfig`, `GridSpec`, `cast_rays`, `integrate_scans`, `occupancy_from_log_odds`: a simulated
  2D lidar and log-odds grid mapping, vectorised in JAX.
- `Field`, `random_field`, `true_map`: simulated fields with random obstacles.
- `ExploreConfig`, `simulate_exploration`, `robot_map`: the simulated two-robot exploration
  (frontier planner, lidar along noisy odometry) that `python -m rhaml_jax.explore` runs.
- `map_scores`: occupied-cell IoU and false-occupied fraction of a map against the truth.
- `plot_merged`: the merged map's figure with trajectories.
- `estimate_a0_T_b0(sequence_dir)`: A_0 T B_0 from a rendezvous sequence (IML or truth + noise
  observations, then `pgo.rhaml_pgo`); `read_sequence`.
"""

from rhaml_jax.mapping._lidar import (GridSpec, LidarConfig, beam_angles, cast_rays, empty_log_odds, integrate_scans,
                                      occupancy_from_log_odds)
from rhaml_jax.mapping._mapfile import OccupancyMap, read_map, read_pgm, write_map, write_pgm
from rhaml_jax.mapping._merge import MergeReport, merge_maps, resample, transform_points
from rhaml_jax.mapping._explore import ExploreConfig, ExploreRun, robot_map, simulate_exploration
from rhaml_jax.mapping._figure import plot_merged
from rhaml_jax.mapping._rendezvous import RendezvousEstimate, Sequence, estimate_a0_T_b0, read_sequence
from rhaml_jax.mapping._world import Field, map_scores, random_field, true_map

__all__ = ["OccupancyMap", "read_map", "write_map", "read_pgm", "write_pgm", "MergeReport", "merge_maps", "resample",
           "transform_points", "GridSpec", "LidarConfig", "beam_angles", "cast_rays", "empty_log_odds",
           "integrate_scans", "occupancy_from_log_odds", "Field", "random_field", "true_map", "map_scores", "plot_merged", "RendezvousEstimate", "Sequence",
           "estimate_a0_T_b0", "read_sequence", "ExploreConfig", "ExploreRun", "robot_map",
           "simulate_exploration"]
