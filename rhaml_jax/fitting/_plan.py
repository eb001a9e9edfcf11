"""What `fit` does for a robot within a time budget: a Plan (data sizes, training steps,
evaluation sizes), fixed once at the start and stored, so that `--resume` continues the same run.

The budget rule (sizes "cpu": the shipped configs on this 2-core CPU). The budget is split into
shares, and each share is turned into a count with a rate measured here (BENCHMARKS.md):

| stage | share | rate (2-core CPU) | count |
| --- | --- | --- | --- |
| data: v2 training images at 320 x 256 | 15 % | 25 images/s (2 processes) | images (7/8 with the robot) |
| amlnet: `cpu`, batch 32 | 45 % | 0.6 s per step | steps |
| zoom: `zoom_cpu`, batch 32 | 12 % | 0.25 s per step | steps |
| refiner: `refiner_cpu`, batch 16 | 10 % | 0.6 s per step | steps |
| evaluation: scenarios, held-out set, evaluate | 18 % | 2 frames/s (render + IML + IR) | frames per scenario |

Counts are capped where more stops paying (AMLNet at 4000 steps, 20,000 images per training
pass, 500 frames per scenario as DESIGN.md fixes) and a stage below its minimum (AMLNet 100
steps, 1,000 images) makes the budget too small: `fit` says so and the budget that would do,
before it starts anything. Size "tiny" (the tests) ignores the rates: a few images and steps of
the test-size configs, evaluated on the circle and the held-out circle only.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from rhaml_jax.errors import RhamlError

SHARES = {"data": 0.15, "amlnet": 0.45, "zoom": 0.12, "refiner": 0.10, "evaluation": 0.18}
RATES = {"images_per_s": 25.0, "amlnet_step_s": 0.6, "zoom_step_s": 0.25, "refiner_step_s": 0.6, "eval_frames_per_s": 2.0}
CAPS = {"images": 20_000, "amlnet_steps": 4000, "zoom_steps": 10_000, "refiner_steps": 3000, "frames": 500}
EVAL_SETS = ("circle", "sine", "heldout/circle", "heldout/sine", "heldout/background", "heldout/random")
MINIMA = {"images": 1000, "amlnet_steps": 100, "zoom_steps": 100, "refiner_steps": 50, "frames": 20}


@dataclasses.dataclass(frozen=True)
class Plan:
    size: str
    """"cpu" (the shipped configs) or "tiny" (test-size configs)"""
    amlnet_config: str
    zoom_config: str
    refiner_config: str
    width: int
    """training image width (px; height = 0.8 width)"""
    images: int
    """training images with the robot"""
    negatives: int
    """training images without it"""
    refine_images: int
    """the refiner's training images (at the evaluation size: it crops at native resolution)"""
    amlnet_steps: int
    zoom_steps: int
    refiner_steps: int
    amlnet_batch: int
    zoom_batch: int
    refiner_batch: int
    frames: int
    """frames per evaluation scenario (circle, sine; the held-out set's parts alike)"""
    eval_width: int
    """evaluation image width (px; 640 for DESIGN.md's camera)"""
    eval_sets: tuple[str, ...]
    """what is evaluated: circle, sine (ours) and heldout/PART (the held-out appearance set)"""
    budget_minutes: float

    @classmethod
    def from_dict(cls, d: dict, where: str = "plan") -> "Plan":
        names = {f.name for f in dataclasses.fields(cls)}
        if set(d) != names:
            raise RhamlError(f"{where}: not a fit plan of this version (fields {sorted(set(d) ^ names)} differ)")
        return cls(**{**d, "eval_sets": tuple(d["eval_sets"])})

    @property
    def height(self) -> int:
        return self.width * 4 // 5

    @property
    def eval_height(self) -> int:
        return self.eval_width * 3 // 4


def make_plan(budget_minutes: float, size: Literal["cpu", "tiny"] = "cpu") -> Plan:
    """The plan for a budget (module docstring); RhamlError when it is too small to train anything."""
    if not budget_minutes > 0:
        raise RhamlError(f"--budget-minutes {budget_minutes}: must be positive")
    if size == "tiny":
        return Plan("tiny", "tiny", "tiny_zoom", "refiner_micro", 160, 24, 6, 12, 4, 4, 4, 8, 8, 8, 8, 160,
                    ("circle", "heldout/circle"), budget_minutes)
    if size != "cpu":
        raise RhamlError(f"--size {size!r}: expected cpu or tiny")
    s = budget_minutes * 60.0
    images = min(CAPS["images"], int(SHARES["data"] * s * RATES["images_per_s"]))
    counts = {"images": images,
              "amlnet_steps": min(CAPS["amlnet_steps"], int(SHARES["amlnet"] * s / RATES["amlnet_step_s"])),
              "zoom_steps": min(CAPS["zoom_steps"], int(SHARES["zoom"] * s / RATES["zoom_step_s"])),
              "refiner_steps": min(CAPS["refiner_steps"], int(SHARES["refiner"] * s / RATES["refiner_step_s"])),
              # two scenarios and four held-out parts of about the same size, each evaluated
              "frames": min(CAPS["frames"], int(SHARES["evaluation"] * s * RATES["eval_frames_per_s"] / 6))}
    short = [k for k, v in counts.items() if v < MINIMA[k]]
    if short:
        need = max(MINIMA[k] / counts[k] * budget_minutes if counts[k] else float("inf") for k in short)
        raise RhamlError(f"--budget-minutes {budget_minutes:g}: too small to train anything "
                         f"({', '.join(f'{k} {counts[k]} < {MINIMA[k]}' for k in short)}); "
                         f"give at least {need:.0f} minutes")
    return Plan("cpu", "cpu", "zoom_cpu", "refiner_cpu", 320, images * 7 // 8, images - images * 7 // 8, max(40, images // 10),
                counts["amlnet_steps"], counts["zoom_steps"], counts["refiner_steps"], 32, 32, 16, counts["frames"], 640,
                EVAL_SETS, budget_minutes)
