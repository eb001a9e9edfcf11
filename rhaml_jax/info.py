"""`python -m rhaml_jax.info`: a robot model as loaded, or a network config's size, as JSON.

  python -m rhaml_jax.info --robot pioneer3dx
  python -m rhaml_jax.info --robot path/to/robot.urdf [--max-faces 2000]
  python -m rhaml_jax.info --config paper [--bench] [--batch 8]
"""

from __future__ import annotations

import dataclasses
import json
import warnings

import tyro

from rhaml_jax.errors import RhamlError, run_cli


@dataclasses.dataclass(frozen=True)
class Args:
    robot: str | None = None
    """Built-in robot name (pioneer3dx) or a URDF / STL / OBJ / PLY / DAE path."""
    max_faces: int | None = None
    """Simplify the robot model to about this many faces (silhouette-preserving)."""
    config: str | None = None
    """AMLNet / baseline network config name (paper, cpu, frontnet, ...)."""
    bench: bool = False
    """With --config: also measure inference and training images per second."""
    batch: int = 8
    """With --bench: batch size of the measurement."""


def info(args: Args) -> dict:
    if (args.robot is None) == (args.config is None):
        raise RhamlError("give exactly one of --robot or --config")
    if args.robot is not None:
        from rhaml_jax.robots import load_robot

        return load_robot(args.robot, args.max_faces).describe()
    try:
        from rhaml_jax.amlnet import describe
    except ImportError as e:
        raise RhamlError(f"--config: the network package is not available ({e})") from None
    return describe(args.config, bench=args.bench, batch=args.batch)


def main() -> None:
    args = tyro.cli(Args, description=__doc__)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = info(args)
    for w in caught:
        print(f"warning: {w.message}", file=__import__("sys").stderr)
    print(json.dumps(out))


if __name__ == "__main__":
    run_cli(main)
