"""`python -m rhaml_jax.generate`: synthetic BOP data sets and evaluation scenarios.

  python -m rhaml_jax.generate --out DIR --num 70000 --negatives 10000 [--robot R] [--seed S]
  python -m rhaml_jax.generate --out DIR --scenario circle|sine|rendezvous [--frames 500]
  python -m rhaml_jax.generate --out DIR --heldout [--frames 500 --num 500 --negatives 100]
  python -m rhaml_jax.generate --out DIR --heldout --scenario rendezvous [--frames 200]

Training sets use the v2 appearance randomisation (`--appearance v2`, ranges in
`rhaml_jax.data.AppearanceConfig`, each settable as `--ranges.FIELD LO HI`); `--appearance v1`
writes the data the shipped checkpoints were trained on. `--heldout` writes the held-out
appearance benchmark (DIR/circle, DIR/sine, DIR/background, DIR/random), rendered with settings
outside every training range (`rhaml_jax.data.HeldoutConfig`): a hemisphere light, teal robot
parts, Voronoi and `stereo_motorcycle` rooms. Scenarios keep the v1 look.

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
from rhaml_jax.data import AppearanceConfig, HeldoutConfig
from rhaml_jax.errors import RhamlError, run_cli


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path
    """Output data set folder (BOP layout)."""
    robot: str = "pioneer3dx"
    """Built-in robot name or a URDF / mesh path."""
    seed: int = 0
    """Data set seed: image i is a pure function of (seed, i)."""
    num: int | None = None
    """Training set: images with the robot in view (default 70000; with --heldout, the random split: 500)."""
    negatives: int | None = None
    """Training set: background-only images (default 10000; with --heldout: 100)."""
    appearance: Literal["v1", "v2"] = "v2"
    """Training-set look: v2 (appearance randomisation) or v1 (the shipped checkpoints' data)."""
    heldout: bool = False
    """Write the held-out appearance benchmark (circle, sine, background, random) instead."""
    ranges: AppearanceConfig = AppearanceConfig()
    """v2 appearance ranges (training; also what --heldout checks its settings against)."""
    heldout_ranges: HeldoutConfig = HeldoutConfig()
    """The held-out benchmark's settings (must lie outside --ranges)."""
    scenario: Literal["circle", "sine", "rendezvous"] | None = None
    """Write an evaluation scenario instead of a training set."""
    frames: int = 500
    """Scenario length (frames per camera)."""
    width: int = DEFAULT_CAMERA.width
    """Image width (px); the intrinsics scale with the size."""
    height: int = DEFAULT_CAMERA.height
    """Image height (px)."""
    scale: float = 1.0
    """Every distance (training depths, scenario paths and rooms) times this, for a robot of another size (fit uses its length over the Pioneer's 0.455 m); 1 gives DESIGN.md's scenarios."""
    max_faces: int | None = None
    """Simplify the robot model to about this many faces before rendering."""
    workers: int = min(2, os.cpu_count() or 1)
    """Rendering processes."""


def generate(args: Args) -> dict:
    from rhaml_jax.data import SynthConfig, check_heldout, write_heldout, write_scenario, write_training_set

    num = args.num if args.num is not None else 500 if args.heldout else 70000
    negatives = args.negatives if args.negatives is not None else 100 if args.heldout else 10000
    if num < 0 or negatives < 0 or (num + negatives == 0 and not args.heldout):
        raise RhamlError(f"--num and --negatives must be >= 0 and not both 0, got {num}, {negatives}")
    if args.heldout and args.scenario in ("circle", "sine"):
        raise RhamlError("--heldout writes its own circle and sine scenarios: drop --scenario "
                         "(--heldout --scenario rendezvous writes a held-out two-robot sequence)")
    if args.heldout and args.appearance != "v2":
        raise RhamlError("--heldout: its settings are checked against the v2 training ranges; drop --appearance v1")
    args.ranges.validate(), args.heldout_ranges.validate()  # (parsed with the checks deferred)
    if args.heldout:
        check_heldout(args.ranges, args.heldout_ranges)  # before any rendering
    if args.workers < 1:
        raise RhamlError(f"--workers must be at least 1, got {args.workers}")
    if args.width < 16 or args.height < 16:
        raise RhamlError(f"--width/--height must be at least 16 px, got {args.width}x{args.height}")
    from rhaml_jax.robots import load_robot

    load_robot(args.robot, args.max_faces)  # fail early on a bad model
    camera = DEFAULT_CAMERA if (args.width, args.height) == (DEFAULT_CAMERA.width, DEFAULT_CAMERA.height) else DEFAULT_CAMERA.resized(args.width, args.height)
    assert isinstance(camera, Camera)
    t = time.perf_counter()
    if args.heldout and args.scenario == "rendezvous":
        out = write_scenario(args.out, "rendezvous", args.robot, camera, args.seed, args.frames, args.workers,
                             max_faces=args.max_faces, heldout=args.heldout_ranges, scale=args.scale)
    elif args.heldout:
        out = write_heldout(args.out, args.robot, camera, args.seed, args.frames, num, negatives, args.workers, args.max_faces,
                            args.heldout_ranges, args.ranges, args.scale)
    elif args.scenario is not None:
        out = write_scenario(args.out, args.scenario, args.robot, camera, args.seed, args.frames, args.workers, max_faces=args.max_faces,
                             scale=args.scale)
    else:
        cfg = SynthConfig(appearance=args.ranges if args.appearance == "v2" else None).scaled(args.scale)
        out = write_training_set(args.out, args.robot, camera, args.seed, num, negatives, args.workers, max_faces=args.max_faces, cfg=cfg)
    out["seconds"] = round(time.perf_counter() - t, 2)
    return out


def main() -> None:
    from rhaml_jax.data import deferred_checks

    with deferred_checks():  # range errors come from generate() as one line, not tyro's box
        args = tyro.cli(Args, description=__doc__)
    print(json.dumps(generate(args)))


if __name__ == "__main__":
    run_cli(main)
