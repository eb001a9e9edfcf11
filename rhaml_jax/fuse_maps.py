"""`python -m rhaml_jax.fuse_maps --map-a A.yaml --map-b B.yaml (--transform X,Y,PSI | --sequence DIR) --out OUT.yaml`

Merges two ROS map_server maps (PGM + YAML): B is placed in A's frame by A_0 T B_0 (the pose
of B's map origin in A's, metres and radians) and the union is written in A's frame as
OUT.yaml + OUT.pgm, with a figure OUT.png. The transform is given, or estimated from a
rendezvous sequence (two BOP scenes with their TUM files, as `generate --scenario rendezvous`
and `explore` write): each robot's odometry there must be in the frame of its map.
Prints one JSON line (transform, its source, the frames used, the overlap, the files written).
"""

from __future__ import annotations

import dataclasses
import json
import re
import sys
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from rhaml_jax.errors import RhamlError, run_cli


@dataclasses.dataclass(frozen=True)
class Args:
    map_a: Path
    """map A's YAML (map_server format); the merged map is in A's frame"""
    map_b: Path
    """map B's YAML"""
    out: Path
    """merged map YAML (its PGM and a PNG figure are written beside it)"""
    transform: str | None = None
    """A_0 T B_0 as X,Y,PSI (m, m, rad): B's map origin in A's map frame"""
    sequence: Path | None = None
    """a rendezvous sequence folder: estimate A_0 T B_0 from it instead of --transform"""
    observations: Literal["iml", "truth"] = "iml"
    """with --sequence: the IML on the images, or the ground truth plus noise (tests, ablations)"""
    interpolation: Literal["nearest", "linear"] = "nearest"
    """how B's occupancy is resampled (nearest keeps the classes and thin walls; see rhaml_jax.mapping)"""
    trajectory_a: Path | None = None
    """TUM file of A's trajectory in A's map frame (drawn in the figure)"""
    trajectory_b: Path | None = None
    """TUM file of B's trajectory in B's map frame (drawn in the figure, placed by the transform)"""
    figure: Path | None = None
    """the figure's path (default: OUT with .png)"""
    seed: int = 0
    """noise seed of --observations truth"""


def parse_transform(text: str) -> np.ndarray:
    parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    try:
        vals = np.array([float(p) for p in parts], np.float64)
    except ValueError:
        raise RhamlError(f"--transform {text!r}: expected three numbers X,Y,PSI (m, m, rad)") from None
    if vals.shape != (3,) or not np.all(np.isfinite(vals)):
        raise RhamlError(f"--transform {text!r}: expected three finite numbers X,Y,PSI (m, m, rad)")
    return vals


def fuse(args: Args) -> dict:
    from rhaml_jax.data import read_tum
    from rhaml_jax.mapping import (estimate_a0_T_b0, merge_maps, plot_merged, read_map, read_sequence,
                                   transform_points, write_map)

    if (args.transform is None) == (args.sequence is None):
        raise RhamlError("give exactly one of --transform X,Y,PSI and --sequence DIR")
    a, b = read_map(args.map_a), read_map(args.map_b)
    out: dict = {}
    traj_a = read_tum(args.trajectory_a)[1] if args.trajectory_a else None
    traj_b = read_tum(args.trajectory_b)[1] if args.trajectory_b else None
    if args.transform is not None:
        T = parse_transform(args.transform)
        out["source"] = "--transform"
    else:
        est = estimate_a0_T_b0(args.sequence, args.observations, seed=args.seed)
        T = est.a0_T_b0
        out |= {"source": f"--sequence ({est.source})", "observations_used": len(est.used),
                "observations_rejected": len(est.rejected), "frames": est.frames,
                "used": [f"{w}:{i}" for w, i in est.used]}
        if traj_a is None and traj_b is None:  # draw the rendezvous part of both odometries
            seq = read_sequence(args.sequence)
            traj_a, traj_b = seq.odom_a, seq.odom_b
    merged, report = merge_maps(a, b, T, args.interpolation, names=(str(args.map_a), str(args.map_b)))
    for note in report.notes:
        print(f"note: {note}", file=sys.stderr)
    image = write_map(args.out, merged)
    trajectories, origins = {}, {"A_0": np.zeros(3), "B_0": T}
    if traj_a is not None:
        trajectories["A"] = traj_a[:, :2]
    if traj_b is not None:
        trajectories["B (placed)"] = transform_points(T, traj_b[:, :2])
    fig = args.figure or args.out.with_suffix(".png")
    plot_merged(fig, merged, trajectories, origins,
                f"B placed at ({T[0]:.3f} m, {T[1]:.3f} m, {np.degrees(T[2]):.2f} deg) in A's frame")
    return out | {"a0_T_b0": [float(v) for v in T], "overlap_cells": report.overlap_cells,
                  "overlap_fraction": round(report.overlap_fraction, 4), "notes": list(report.notes),
                  "yaml": str(args.out), "image": str(image), "figure": str(fig)}


def _join_negative_values(argv: list[str]) -> list[str]:
    """`--transform -1,2,0.3` -> `--transform=-1,2,0.3` (argparse would read -1,2,0.3 as a flag)."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--transform" and i + 1 < len(argv) and re.match(r"^-[\d.]", argv[i + 1]):
            out.append(f"--transform={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def main(argv: list[str] | None = None) -> dict:
    argv = _join_negative_values(list(sys.argv[1:] if argv is None else argv))
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    res = fuse(args)
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    run_cli(main)
