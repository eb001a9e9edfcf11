"""`python -m rhaml_jax.explore --out DIR [--seed S]`: one simulated two-robot exploration.

Two robots explore a field with random obstacles by frontiers, each mapping with a simulated 2D
lidar along its noisy odometry; they meet in the middle; the rendezvous frames are rendered from
each robot's camera (both robots the built-in pioneer3dx) and localise each robot in the other's
view; the pose graph gives A_0 T B_0 (the paper's eq. 13) and the maps are merged. Writes to DIR:
map_a.yaml/.pgm and map_b.yaml/.pgm (each robot's map in its own odometry frame),
trajectory_a.txt, trajectory_b.txt (TUM: odometry in each map's frame), truth_a.txt, truth_b.txt
(TUM: true poses in the field), sequence/ (the rendezvous: a BOP data set, one scene per
robot's camera, with the four TUM files), merged.yaml/.pgm/.png and summary.json; prints the
summary as one JSON line.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from rhaml_jax.errors import RhamlError, run_cli


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path
    """output folder"""
    seed: int = 0
    """the world, the robots' starts, the noise: all a pure function of the seed"""
    observations: Literal["iml", "truth"] = "iml"
    """the rendezvous observations: the IML on the rendered images, or ground truth plus noise"""
    explore_steps: int = 450
    """steps (0.1 s each) of frontier exploration before the robots head for the rendezvous"""
    overlap: float = 1.0
    """m: A explores x < 5 + overlap/2, B x > 5 - overlap/2 (negative: their maps overlap little)"""
    lidar_range: float = 3.5
    """lidar maximum range (m)"""
    obstacles: int = 12
    """random obstacles in the field"""
    image_width: int = 640
    """rendered camera image width (px; the intrinsics scale with it)"""
    image_height: int = 480
    """rendered camera image height (px)"""
    workers: int = 1
    """rendering processes"""


def explore(args: Args) -> dict:
    from rich.progress import Progress

    from rhaml_jax import planar
    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import write_sequence, write_tum
    from rhaml_jax.fuse_maps import Args as FuseArgs
    from rhaml_jax.fuse_maps import fuse
    from rhaml_jax.mapping import (ExploreConfig, LidarConfig, estimate_a0_T_b0, map_scores, merge_maps, read_map,
                                   robot_map, simulate_exploration, write_map)

    if args.explore_steps < 0 or args.lidar_range <= 0.5 or args.obstacles < 0 or args.workers < 1:
        raise RhamlError("--explore-steps, --obstacles must be >= 0, --lidar-range > 0.5 m, --workers >= 1")
    cfg = ExploreConfig(obstacles=args.obstacles, explore_steps=args.explore_steps, overlap=args.overlap,
                        lidar=LidarConfig(max_range=args.lidar_range))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with Progress() as p:
        task = p.add_task("exploring", total=cfg.max_steps)
        run = simulate_exploration(args.seed, cfg, progress=lambda step, _: p.update(task, completed=step + 1))
        p.update(task, completed=cfg.max_steps)
    maps = {}
    for tag, odo, ranges, truth in (("a", run.odom_a, run.ranges_a, run.truth_a), ("b", run.odom_b, run.ranges_b, run.truth_b)):
        maps[tag] = robot_map(odo, ranges, cfg)
        write_map(out / f"map_{tag}.yaml", maps[tag])
        t = np.arange(len(odo)) * cfg.dt
        write_tum(out / f"trajectory_{tag}.txt", odo, t)
        write_tum(out / f"truth_{tag}.txt", truth, t)
    f = run.rendezvous
    camera = DEFAULT_CAMERA if (args.image_width, args.image_height) == (DEFAULT_CAMERA.width, DEFAULT_CAMERA.height) \
        else DEFAULT_CAMERA.resized(args.image_width, args.image_height)
    scenes = [(0, run.truth_a[f], run.truth_b[f], run.odom_a[f], run.odom_b[f]),
              (1, run.truth_b[f], run.truth_a[f], run.odom_b[f], run.odom_a[f])]
    seen = write_sequence(out / "sequence", scenes, (0.0, cfg.width, 0.0, cfg.height), "pioneer3dx", camera, args.seed,
                          args.workers, timestamps=f * cfg.dt, label="rendering the rendezvous")
    est = estimate_a0_T_b0(out / "sequence", args.observations, seed=args.seed)
    truth_T = run.a0_T_b0
    fused = fuse(FuseArgs(map_a=out / "map_a.yaml", map_b=out / "map_b.yaml", out=out / "merged.yaml",
                          transform=",".join(repr(float(v)) for v in est.a0_T_b0),
                          trajectory_a=out / "trajectory_a.txt", trajectory_b=out / "trajectory_b.txt"))
    merged = read_map(out / "merged.yaml")
    merged_true, _ = merge_maps(maps["a"], maps["b"], truth_T)
    err = planar.between(truth_T, est.a0_T_b0)
    summary = {
        "seed": args.seed, "observations": est.source, "steps": len(run.truth_a), "rendezvous_frames": len(f),
        "frames_robot_in_view": seen, "observations_used": len(est.used), "observations_rejected": len(est.rejected),
        "a0_T_b0": [float(v) for v in est.a0_T_b0], "true_a0_T_b0": [float(v) for v in truth_T],
        "translation_error_cm": float(100 * np.hypot(*(est.a0_T_b0[:2] - truth_T[:2]))),
        "rotation_error_deg": float(np.degrees(abs(err[2]))),
        "overlap_fraction": fused["overlap_fraction"],
        "merged": map_scores(merged, run.field, run.truth_a[0]),
        "merged_with_true_transform": map_scores(merged_true, run.field, run.truth_a[0]),
        "files": {k: fused[k] for k in ("yaml", "image", "figure")},
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    from rhaml_jax import tune_allocator

    tune_allocator()
    res = explore(args)
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    run_cli(main)
