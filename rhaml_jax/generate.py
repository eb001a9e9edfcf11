"""`python -m rhaml_jax.generate`: synthetic BOP data sets and evaluation scenarios.

  python -m rhaml_jax.generate --out DIR --num 70000 --negatives 10000 [--robot R] [--seed S]
  python -m rhaml_jax.generate --out DIR --scenario circle|sine|rendezvous [--frames 500]
  python -m rhaml_jax.generate --out DIR --heldout [--frames 500 --num 500 --negatives 100]
  python -m rhaml_jax.generate --out DIR --heldout --scenario rendezvous [--frames 200]
  python -m rhaml_jax.generate --out DIR --ood-validation --seed 1 [--frames 500 --num 500 --negatives 100]

Training sets use the v2 appearance randomisation (`--appearance v2`, ranges in
`rhaml_jax.data.AppearanceConfig`, each settable as `--ranges.FIELD LO HI`); `--appearance v1`
writes the data the shipped checkpoints were trained on. `--heldout` writes the held-out
appearance benchmark (DIR/circle, DIR/sine, DIR/background, DIR/random), rendered with settings
outside every training range (`rhaml_jax.data.HeldoutConfig`): a hemisphere light, teal robot
parts, Voronoi and `stereo_motorcycle` rooms. `--ood-validation` writes a set of the same kind
whose settings lie outside training's and apart from the held-out set's
(`rhaml_jax.data.OOD_VALIDATION`: ceiling lamps, a checker livery over the robot's own glossy colours, hexagon-tiled
and `retina` rooms), for the choices the held-out set must not make. Scenarios keep the v1 look.

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
    ood_validation: bool = False
    """Write the out-of-distribution validation set instead (the same four parts; `rhaml_jax.data.OOD_VALIDATION`: outside --ranges and apart from --heldout-ranges): choose designs, thresholds and checkpoints on it, not on the held-out set."""
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
    from rhaml_jax.data import (OOD_VALIDATION, SynthConfig, check_apart, check_heldout, write_heldout, write_scenario,
                                write_training_set)

    ood = args.heldout or args.ood_validation
    flag = "--ood-validation" if args.ood_validation else "--heldout"
    num = args.num if args.num is not None else 500 if ood else 70000
    negatives = args.negatives if args.negatives is not None else 100 if ood else 10000
    if num < 0 or negatives < 0 or (num + negatives == 0 and not ood):
        raise RhamlError(f"--num and --negatives must be >= 0 and not both 0, got {num}, {negatives}")
    if args.heldout and args.ood_validation:
        raise RhamlError("--heldout and --ood-validation: choose one (each writes its own set)")
    if ood and args.scenario in ("circle", "sine"):
        raise RhamlError(f"{flag} writes its own circle and sine scenarios: drop --scenario "
                         f"({flag} --scenario rendezvous writes a two-robot sequence in that look)")
    if ood and args.appearance != "v2":
        raise RhamlError(f"{flag}: its settings are checked against the v2 training ranges; drop --appearance v1")
    args.ranges.validate(), args.heldout_ranges.validate()  # (parsed with the checks deferred)
    held = OOD_VALIDATION if args.ood_validation else args.heldout_ranges
    if ood:  # before any rendering
        check_heldout(args.ranges, held)
    if args.ood_validation:
        check_apart(held, args.heldout_ranges)
    if args.workers < 1:
        raise RhamlError(f"--workers must be at least 1, got {args.workers}")
    if args.width < 16 or args.height < 16:
        raise RhamlError(f"--width/--height must be at least 16 px, got {args.width}x{args.height}")
    from rhaml_jax.robots import load_robot

    load_robot(args.robot, args.max_faces)  # fail early on a bad model
    camera = DEFAULT_CAMERA if (args.width, args.height) == (DEFAULT_CAMERA.width, DEFAULT_CAMERA.height) else DEFAULT_CAMERA.resized(args.width, args.height)
    assert isinstance(camera, Camera)
    t = time.perf_counter()
    if ood and args.scenario == "rendezvous":
        out = write_scenario(args.out, "rendezvous", args.robot, camera, args.seed, args.frames, args.workers,
                             max_faces=args.max_faces, heldout=held, scale=args.scale)
    elif ood:
        out = write_heldout(args.out, args.robot, camera, args.seed, args.frames, num, negatives, args.workers, args.max_faces,
                            held, args.ranges, args.scale)
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
