"""`python -m rhaml_jax.generate`: synthetic BOP data sets and evaluation scenarios.

  python -m rhaml_jax.generate --out DIR --num 70000 --negatives 10000 [--robot R] [--seed S]
  python -m rhaml_jax.generate --out DIR --scenario circle|sine|rendezvous [--frames 500]

Every image is a pure function of (seed, index): running the same command again writes the
same bytes, so an interrupted run is simply run again.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Literal

import tyro

from rhaml_jax.camera import DEFAULT_CAMERA, Camera
from rhaml_jax.errors import RhamlError, run_cli


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path
    """Output data set folder (BOP layout)."""
    robot: str = "pioneer3dx"
    """Built-in robot name or a URDF / mesh path."""
    seed: int = 0
    """Data set seed: image i is a pure function of (seed, i)."""
    num: int = 70000
    """Training set: images with the robot in view."""
    negatives: int = 10000
    """Training set: background-only images."""
    scenario: Literal["circle", "sine", "rendezvous"] | None = None
    """Write an evaluation scenario instead of a training set."""
    frames: int = 500
    """Scenario length (frames per camera)."""
    width: int = DEFAULT_CAMERA.width
    """Image width (px); the intrinsics scale with the size."""
    height: int = DEFAULT_CAMERA.height
    """Image height (px)."""
    max_faces: int | None = None
    """Simplify the robot model to about this many faces before rendering."""
    workers: int = min(2, os.cpu_count() or 1)
    """Rendering processes."""


def generate(args: Args) -> dict:
    from rhaml_jax.data._writer import write_scenario, write_training_set

    if args.num < 0 or args.negatives < 0 or args.num + args.negatives == 0:
        raise RhamlError(f"--num and --negatives must be >= 0 and not both 0, got {args.num}, {args.negatives}")
    if args.workers < 1:
        raise RhamlError(f"--workers must be at least 1, got {args.workers}")
    if args.width < 16 or args.height < 16:
        raise RhamlError(f"--width/--height must be at least 16 px, got {args.width}x{args.height}")
    from rhaml_jax.robots import load_robot

    load_robot(args.robot, args.max_faces)  # fail early on a bad model
    camera = DEFAULT_CAMERA if (args.width, args.height) == (DEFAULT_CAMERA.width, DEFAULT_CAMERA.height) else DEFAULT_CAMERA.resized(args.width, args.height)
    assert isinstance(camera, Camera)
    t = time.perf_counter()
    if args.scenario is not None:
        out = write_scenario(args.out, args.scenario, args.robot, camera, args.seed, args.frames, args.workers, max_faces=args.max_faces)
    else:
        out = write_training_set(args.out, args.robot, camera, args.seed, args.num, args.negatives, args.workers, max_faces=args.max_faces)
    out["seconds"] = round(time.perf_counter() - t, 2)
    return out


def main() -> None:
    print(json.dumps(generate(tyro.cli(Args, description=__doc__))))


if __name__ == "__main__":
    run_cli(main)
