"""`python -m rhaml_jax.fit`: every network for your robot, in one resumable command.

  python -m rhaml_jax.fit --robot my_robot.urdf --out runs/my_robot [--budget-minutes 180] [--resume]

Loads and checks the robot (URDF or mesh), generates its appearance-randomised training data,
trains AMLNet (its last phase without robot-like carts among the distractors), its zoom stage
(its crop sized to the robot) and the refiner cascade (the refiner and the fine refiner),
exports them to DIR/networks/ (for `evaluate --amlnet/--zoom/--refiner/--fine-refiner` and the
pipeline), evaluates them on
generated circle + sine scenarios and on the held-out appearance set, and writes DIR/report.md.
Distances are scaled to the robot's size and AMLNet and the zoom stage fine-tune the shipped
Pioneer networks (heat_cpu, zoom_luma_cpu) unless --from-scratch (`rhaml_jax.fitting._plan`):
then the zoom stage learns on plain-look images first, where it finds the front/back cue.
The budget is split between the stages by the rule in `rhaml_jax.fitting._plan`, and a run
that falls behind is paced (the stages not yet begun get fewer steps or frames); killed
anywhere, `--resume` continues (finished stages are skipped, trainings resume exactly, and the
killed attempt's time still counts).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro

from rhaml_jax.allocator import tune_allocator
from rhaml_jax.errors import run_cli


@dataclass(frozen=True)
class Args:
    robot: str
    """built-in robot name (pioneer3dx) or a URDF / mesh path"""
    out: Path
    """run folder: fit.json, data/, runs/, networks/, eval/, report.md"""
    budget_minutes: float = 180.0
    """wall-time budget on this machine, split between the stages (rhaml_jax.fitting._plan)"""
    resume: bool = False
    """continue the run in --out (same robot; its stored plan wins over --budget-minutes)"""
    size: Literal["cpu", "tiny"] = "cpu"
    """network sizes: cpu (the robust pair and the refiner at shipped size, rhaml_jax.fitting._plan) or tiny (test-size, a smoke run)"""
    seed: int = 0
    """data and initialisation seed"""
    from_scratch: bool = False
    """AMLNet and its zoom stage from random weights instead of fine-tuning the shipped Pioneer networks (size cpu)"""
    workers: int = min(2, os.cpu_count() or 1)
    """rendering processes"""


def main(argv: list[str] | None = None):
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    tune_allocator()  # before JAX starts its threads; see rhaml_jax.allocator
    from rhaml_jax.fitting import load_checked_robot, make_plan, run_fit

    model = load_checked_robot(args.robot)
    plan = make_plan(args.budget_minutes, args.size, len(model.faces), model.world_scale, not args.from_scratch)
    state = run_fit(args.robot, args.out, plan, args.resume, args.workers, args.seed)
    print(f"fit: {args.out / 'report.md'} ({sum(state.done.values()) / 60:.1f} min); networks in {args.out / 'networks'}")
    return state


if __name__ == "__main__":
    run_cli(main)
