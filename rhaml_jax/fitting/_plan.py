"""What `fit` does for a robot within a time budget: a Plan (data sizes, training steps,
evaluation sizes), made at the start and stored, so that `--resume` continues the same run, and
paced as the run goes (below).

The budget rule (size "cpu": the configs of the networks that hold up best on the held-out
appearance set, `cpu_heat` + `zoom_cpu_luma`, on v3 data: appearance randomisation with half the
robots repainted, BENCHMARKS.md "A dense first stage, luminance input, repainted robots"). The budget is split into
shares, and each share is turned into a count with a rate measured here (BENCHMARKS.md):

| stage | share | rate (2-core CPU) | count |
| --- | --- | --- | --- |
| data: v3 training images at 320 x 256, 0.3 as many without carts for AMLNet's last phase, a tenth as many at 640 x 480 for the refiner, and a twentieth as many plain-look ones at 640 x 480 for its first steps | 15 % | per image at 604 mesh faces: 0.029 s (320 x 256), 0.122 s (the refiner's, 640 x 480), 0.05 s (its plain-look ones); at 91,104 faces 0.136, 0.26 and 0.13 s; linear between (2 processes) | images (7/8 with the robot) |
| amlnet: `cpu_heat`, batch 32, then 3/8 as many steps on the no-cart images | 45 % | 0.9 s per step (validation and checkpoints included: 0.87 and 0.91 in session 27's fit) | steps (of the first phase) |
| zoom: `zoom_cpu_luma`, batch 32 | 12 % | 0.1 s per step | steps |
| refiner: `refiner_cpu`, batch 16, then a third as many steps of the fine refiner `refiner_fine_cpu` | 10 % | 0.13 s per step of either at 604 faces, 0.5 s at 91,104 (it renders) | steps (of `refiner_cpu`) |
| evaluation: scenarios, held-out set, evaluate | 18 % | 0.13 s per frame at 604 faces, 1.17 s at 91,104 (render + IML + IR) | frames per scenario |

Before the split, the evaluation's fixed cost is taken off the budget: its 16 `evaluate` runs
compile their pipelines (`EVAL_COMPILE_S`, 13.6 s per run, as session 26's 140-minute run measured:
in one process the first run of each module combination and frame count compiles, 20-58 s, and
the later ones reuse it, 2-6 s; with the per-frame rate the rule charges its evaluation 608 s, it
took 613: BENCHMARKS.md), whatever the number of frames, and the export stage writes the weights
and compiles the flip calibration (`calibrate_flips` on the training set's validation split;
`EXPORT_S`, 32 s): 4.2 min in all. The shares split the rest.

The seconds a capped stage leaves (below) go to AMLNet and the zoom stage, in proportion to
their shares, up to their caps, and then to the refiner: the budget is spent on training, not
left unused.

Rendering cost grows with the robot's mesh, so the data, refiner and evaluation rates do: two
points measured on this machine, the built-in Pioneer (604 faces: 0.13 s per refiner step in the
from-scratch 110-minute run; the images' rates in the 163-minute one of session 23; 0.13 s per
evaluated frame in the 140-minute one of session 26) and the TurtleBot3 Burger URDF (91,104
faces: 0.5 s per refiner step, 1.17 s per evaluated frame; the images in the 45-minute run of
session 23), joined by a line (BENCHMARKS.md, "Your own robot", "Pacing" and "The Pioneer from
nothing in one session").

Every distance of the robot's world is scaled by `RobotModel.world_scale`: the robot's length over
the built-in Pioneer's 0.455 m (1 for the Pioneer, whose scenarios DESIGN.md fixes; 0.39 for the
0.178 m TurtleBot3), so that a small robot is seen at the pixel sizes a Pioneer is at its
distances: the training depths (1-8 m for the Pioneer), the circle and sine paths and their
rooms. At size "cpu" AMLNet and its zoom stage start from the shipped Pioneer networks of
their configs, `heat_cpu` and `zoom_luma_cpu` (`warm_start`: fine-tuning at half the learning
rate; `fit --from-scratch` starts from random weights, as reproducing the shipped networks must).

Counts are capped where more stops paying (AMLNet at 4000 steps, 20,000 images per training
pass, 500 frames per scenario as DESIGN.md fixes; the refiner at 3,000 steps of its share, and
up to 6,000 with what is left once AMLNet and the zoom stage are capped) and a stage below its minimum (AMLNet 100
steps when fine-tuning, 2,000 from scratch; 1,000 images) makes the budget too small: `fit`
says so and the smallest budget that would do, before it starts anything.

From scratch (`warm_start` False) the data stage also renders half as many plain-look (v1)
images (0.015 s each at 604 faces, measured; at 91,104 assumed as slow as v3 ones, since the
mesh dominates) and the zoom stage spends its first 12/17 on them (`zoom_v1_steps`), the rest
on v3 and v1 images together, with its cap raised to 17,000 steps: from random weights on v3
images the zoom stage found no front/back in 10,000 steps; on v1 images it did, better the longer
it ran (our circle's flips 41 of 434 after 4,000 steps, 0 after 12,000), and 5,000 steps on the
mix kept it (1 of 434) while the v3 validation split's flips fell (211 -> 166 of 492; BENCHMARKS.md,
"A curriculum for the heading"). Size "tiny" (the tests) ignores the rates: a few images and steps of
the test-size configs, evaluated on the circle and the held-out circle only.

AMLNet ends with a phase on images whose distractors hold no robot-like carts (boxes on four
wheels, `AppearanceConfig.cart_prob` 0.4 in the v3 data): a Pioneer seen end-on is a box on
wheels, and with the carts among its negatives AMLNet missed near robots seen within about 30 deg
of end-on. Measured as a fine-tune of the from-scratch `fit` AMLNet (`heat_fit_cpu`, 4,000 steps)
on 6,000 no-cart images for 1,500 steps from its weights at half the learning rate: robots
missed on the validation sequences 18/3/31/5 (ours) and 85/93 (OOD) -> 7/0/6/0 and 37/65, where
the same fine-tune with carts gave 25/3/59/13 and 95/86 (BENCHMARKS.md, "Carts and the end-on
misses"; the shipped `heat_nocart_cpu`). The phase keeps that ratio: 0.3 no-cart images
per v3 image (`NOCART_IMAGE_FRACTION`), 3/8 of a step per first-phase step
(`NOCART_STEP_FRACTION`); half as many steps found the same end-on robots but read them less
accurately (BENCHMARKS.md, "AMLNet's no-cart phase in `fit`"). The first phase keeps the carts,
which keep false positives down (OOD background frames called positive: 15 of 100 before the
fine-tune, 18 with carts, 20 without).

The refiner always starts from random weights, and likewise learns first on plain-look images
(a twentieth as many as the training images, at 640 x 480; 0.05 s each at 604 faces), for 2/3
of its steps, then on the v3 and v1 ones together from those weights. Crop by crop (eq. 8's
point-matching loss after four test-time iterations on the validation splits, v3 / v1): v3 alone
0.339 / 0.298, v1 then v3 0.310 / 0.198, v1 then v3 + v1 0.346 / 0.169, v1 alone 0.628 / 0.170
(BENCHMARKS.md, "A curriculum for the refiner"); through the pipeline, behind the same IML on the
validation sequences, v1 then v3 + v1 is the better second phase on both looks (IML+IR+PGO ATE
ours 0.025 against v3 alone's 0.027, the OOD look 0.023 against 0.050: BENCHMARKS.md, "The
refiner's second phase on the mix"). Twice as many steps (4,000 + 2,000) were better again on both
splits (0.279 / 0.174), so it takes up to 6,000 steps once AMLNet and the zoom stage are capped (the
zoom stage's heading comes first: at 131 minutes from scratch the extra steps would have cost
it 3,400 of its 17,000).

Then the fine refiner, the cascade's second network (`refiner_fine_cpu`, run once after the
refiner's iterations, as the shipped pair is), from the refiner's weights on the same v3 + v1
crops, its starts drawn as a refiner leaves them, for a third as many steps
(`FINE_STEP_FRACTION`, paid from the refiner's share: the share's steps cost 4/3 as much).
Measured behind session 28's 180-minute fit (its AMLNet and zoom stage, its refiner's 6,000
steps, then 2,000 fine steps, 4 min): on the 12 validation sequences IML+IR's RMS position error
0.88x (interval 0.84-0.91) and its ATE 0.99x (0.98-1.00), IML+IR+PGO level (1.00, 0.90-1.13),
nothing worse over all looks (BENCHMARKS.md, "`fit` trains the fine refiner").

Pacing: the rates are this machine's, alone; a busier or slower machine, or a rate measured
wrong, overruns the budget by as much. So before each stage begins, the finished stages' seconds
are compared with their planned ones (`slowness`, at least 1), and if the stages left, at that
many times their rates, do not fit in the time left, the counts of the stages not yet begun
(training steps, the evaluation's frames) are those of the plan as made scaled down by one
factor (`paced`; never below `PACED_MINIMA`, never above the plan as made: a later stage that
finds the run caught up gets its counts back). A stage's counts are fixed when it begins and stored in fit.json, so that
a killed training resumes with the steps it began with. The 45-minute TurtleBot3 run took 53.2
minutes with the rates before session 24; replayed at its measured speed per stage through today's
rates, 47.9 minutes unpaced and 46.3 paced (BENCHMARKS.md, "Pacing").
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

from rhaml_jax.errors import RhamlError

SHARES = {"data": 0.15, "amlnet": 0.45, "zoom": 0.12, "refiner": 0.10, "evaluation": 0.18}
RATES = {"amlnet_step_s": 0.9, "zoom_step_s": 0.1}
# seconds per image, per evaluated frame and per refiner step: the line through the two measured points above
MEASURED_FACES = (604, 91_104)
# measured in the from-scratch Pioneer run and the 45-minute TurtleBot3 run of session 23 (BENCHMARKS.md, "Pacing")
IMAGE_S = (0.029, 0.136)  # v3 at 320 x 256 (with or without carts)
V1_IMAGE_S = (0.015, 0.136)  # the plain look renders faster; at 91,104 faces assumed as slow as v3 (the mesh dominates)
REFINE_IMAGE_S = (0.122, 0.26)  # v3 at 640 x 480, the refiner's
V1_REFINE_IMAGE_S = (0.05, 0.13)  # v1 at 640 x 480
EVAL_FRAME_S = (0.13, 1.17)
REFINER_STEP_S = (0.13, 0.5)
CAPS = {"images": 20_000, "amlnet_steps": 4000, "zoom_steps": 10_000, "refiner_steps": 3000, "frames": 500}
REFINER_SPARE_CAP = 6000  # the refiner's steps when AMLNet and the zoom stage are capped and seconds are left
EVAL_SETS = ("circle", "sine", "heldout/circle", "heldout/sine", "heldout/background", "heldout/random")
EVAL_COMPILE_S = 13.6
"""seconds an `evaluate` run is charged for compiling, whatever the frame count (session 26's
140-minute run measured 218 s over its 16 runs in one process, `compile_seconds` in their
results, and 0.13 s per frame-unit for the rest; the 110- and 30-minute runs, before compiled
programs were shared, 510 s over 16)"""
EXPORT_S = 32.0
"""the export stage: weights written, the flip calibration compiled and run (34 s in session 26)"""
V1_FRACTION = 0.5  # from scratch: v1 images per v3 training image (with or without the robot)
ZOOM_V1_FRACTION = 12 / 17  # from scratch: the zoom stage's steps spent on v1 images before the v3 ones
REFINER_V1_FRACTION = 2 / 3  # the refiner's steps spent on v1 images before the v3 + v1 mix
FINE_STEP_FRACTION = 1 / 3  # the fine refiner's steps per refiner step, after it, from its weights, on the mix
NOCART_IMAGE_FRACTION = 0.3  # AMLNet's last phase: no-cart images per v3 training image (6,000 of 20,000, as measured)
NOCART_STEP_FRACTION = 3 / 8  # ... and its steps per first-phase step (1,500 after 4,000, as measured)
MINIMA = {"images": 1000, "amlnet_steps": 100, "zoom_steps": 100, "refiner_steps": 50, "frames": 20}
# from random weights AMLNet needs far more: its validation detection accuracy was 0.14 after 901
# steps, 0.43 after 1,100 and 0.53 after 1,900 of 2,970 (BENCHMARKS.md, "The Pioneer from nothing")
MINIMA_FROM_SCRATCH = MINIMA | {"amlnet_steps": 2000}
# from random weights the zoom stage's heading keeps improving on v1 images long after 4,000
# steps: our circle's flips 41 -> 0 of 434 at 12,000 (BENCHMARKS.md, "A curriculum for the heading")
CAPS_FROM_SCRATCH = CAPS | {"zoom_steps": 17_000}


@dataclasses.dataclass(frozen=True)
class Plan:
    size: str
    """"cpu" (the robust configs, module docstring) or "tiny" (test-size configs)"""
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
    scale: float
    """every distance of the robot's world (training depths, scenario paths and rooms) times this"""
    warm_start: bool
    """AMLNet and the zoom stage start from the shipped Pioneer networks (fine-tuning)"""
    v1_images: int
    """from scratch, the curriculum's plain-look (v1) training images (0 when warm-started)"""
    zoom_v1_steps: int
    """from scratch, the zoom stage's first steps, on the v1 images (of `zoom_steps`; 0 when warm-started)"""
    refine_v1_images: int
    """the refiner's plain-look (v1) training images, at the evaluation size"""
    refiner_v1_steps: int
    """the refiner's first steps, on those images (of `refiner_steps`; it always starts from random weights)"""
    nocart_images: int
    """AMLNet's last phase: training images with the robot and no robot-like carts among the distractors"""
    nocart_negatives: int
    """... and without the robot"""
    amlnet_nocart_steps: int
    """AMLNet's last phase: steps on those images, after `amlnet_steps`, from that phase's weights"""
    fine_config: str
    """the fine refiner (a DeepIM cascade's second network: the pipeline runs it after the refiner)"""
    refiner_fine_steps: int
    """its steps, after `refiner_steps`, from the refiner's weights, on the same v3 + v1 crops"""

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


def make_plan(budget_minutes: float, size: Literal["cpu", "tiny"] = "cpu", faces: int = MEASURED_FACES[0], scale: float = 1.0,
              warm_start: bool = True) -> Plan:
    """The plan for a budget (module docstring) and a robot of `faces` mesh faces and world
    `scale`; RhamlError when it is too small to train anything."""
    if not budget_minutes > 0:
        raise RhamlError(f"--budget-minutes {budget_minutes}: must be positive")
    if size == "tiny":  # test-size networks have no shipped weights to start from
        return Plan("tiny", "tiny", "tiny_zoom", "refiner_micro", 160, 24, 6, 12, 4, 4, 4, 8, 8, 8, 8, 160,
                    ("circle", "heldout/circle"), budget_minutes, scale, False, 12, 2, 6, 2, 6, 2, 2, "refiner_micro_fine", 2)
    if size != "cpu":
        raise RhamlError(f"--size {size!r}: expected cpu or tiny")
    counts = _counts(budget_minutes * 60.0, faces, not warm_start)
    minima = MINIMA if warm_start else MINIMA_FROM_SCRATCH
    short = [k for k, v in counts.items() if v < minima[k]]
    if short:
        need = next((m for m in range(math.ceil(budget_minutes), 10_000)
                     if all(v >= minima[k] for k, v in _counts(m * 60.0, faces, not warm_start).items())), None)
        raise RhamlError(f"--budget-minutes {budget_minutes:g}: too small to train anything"
                         f"{'' if warm_start else ' from scratch'} ({', '.join(f'{k} {counts[k]} < {minima[k]}' for k in short)}); "
                         f"give at least {need} minutes")
    return _from_counts(counts, budget_minutes, scale, warm_start)


def _from_counts(counts: dict[str, int], budget_minutes: float, scale: float, warm_start: bool) -> Plan:
    """The size-"cpu" plan of `counts` (images, amlnet_steps, zoom_steps, refiner_steps, frames):
    what each count brings with it (module docstring)."""
    images = counts["images"]
    nocart = int(images * NOCART_IMAGE_FRACTION)
    return Plan("cpu", "cpu_heat", "zoom_cpu_luma", "refiner_cpu", 320, images * 7 // 8, images - images * 7 // 8, max(40, images // 10),
                counts["amlnet_steps"], counts["zoom_steps"], counts["refiner_steps"], 32, 32, 16, counts["frames"], 640,
                EVAL_SETS, budget_minutes, scale, warm_start, 0 if warm_start else int(images * V1_FRACTION),
                0 if warm_start else round(counts["zoom_steps"] * ZOOM_V1_FRACTION), max(20, images // 20),
                round(counts["refiner_steps"] * REFINER_V1_FRACTION), nocart * 7 // 8, nocart - nocart * 7 // 8,
                round(counts["amlnet_steps"] * NOCART_STEP_FRACTION), "refiner_fine_cpu",
                math.floor(counts["refiner_steps"] * FINE_STEP_FRACTION + 1e-9))  # rounded down: a plan never overspends


# count -> the stages whose seconds it buys (`stage_seconds`)
_COUNT_STAGES = {"images": ("data",), "amlnet_steps": ("amlnet", "amlnet_nocart"), "zoom_steps": ("zoom_v1", "zoom"),
                 "refiner_steps": ("refiner_v1", "refiner", "refiner_fine"), "frames": ("scenarios",)}


def _unit_seconds(faces: int, curriculum: bool) -> dict[str, float]:
    """Seconds per unit of each count, with all it brings: `stage_seconds` of a plan with a large
    count of each (so that the plan's roundings vanish), per unit."""
    n = 1_000_000
    seconds = stage_seconds(_from_counts(dict.fromkeys(_COUNT_STAGES, n), 0.0, 1.0, not curriculum), faces)
    return {k: sum(seconds[s] for s in stages) / n for k, stages in _COUNT_STAGES.items()}


def _mesh_rates(faces: int) -> tuple[float, ...]:
    """Seconds per v3 image, v1 image, v3 and v1 refiner image, evaluated frame and refiner step for a
    mesh of `faces`: the line through the two measured points, no cheaper than the smaller mesh."""
    grow = max(faces - MEASURED_FACES[0], 0) / (MEASURED_FACES[1] - MEASURED_FACES[0])
    return tuple(t[0] + (t[1] - t[0]) * grow for t in (IMAGE_S, V1_IMAGE_S, REFINE_IMAGE_S, V1_REFINE_IMAGE_S, EVAL_FRAME_S,
                                                       REFINER_STEP_S))


def _counts(budget_s: float, faces: int, curriculum: bool) -> dict[str, int]:
    """Images, steps and frames a budget buys (module docstring); zeros when the evaluation's
    compilations take it all."""
    s = budget_s - eval_compile_s() - EXPORT_S  # what the shares split
    unit = _unit_seconds(faces, curriculum)
    stage = {"images": "data", "amlnet_steps": "amlnet", "zoom_steps": "zoom", "refiner_steps": "refiner", "frames": "evaluation"}
    seconds = {k: SHARES[stage[k]] * max(s, 0.0) for k in unit}
    caps = CAPS_FROM_SCRATCH if curriculum else CAPS
    counts = {k: min(caps[k], int(seconds[k] / unit[k])) for k in unit}
    for _ in range(3):  # what capped stages leave goes to the trainings below their caps, by share
        spare = s - sum(counts[k] * unit[k] for k in unit)
        open_ = [k for k in ("amlnet_steps", "zoom_steps") if counts[k] < caps[k]]
        if not open_:  # then to the refiner, up to its larger cap
            caps = caps | {"refiner_steps": REFINER_SPARE_CAP}
            open_ = [k for k in ("refiner_steps",) if counts[k] < caps[k]]
        if spare < 1.0 or not open_:
            break
        total = sum(SHARES[stage[k]] for k in open_)
        for k in open_:  # what its count uses now, and its part of the spare (a capped count used less than its share)
            seconds[k] = counts[k] * unit[k] + spare * SHARES[stage[k]] / total
            counts[k] = min(caps[k], int(seconds[k] / unit[k]))
    return counts


def eval_modules(name: str) -> tuple[str, ...]:
    """The module combinations run on an evaluation set (pgo needs a scenario's odometry)."""
    scenario = name.split("/")[-1] in ("circle", "sine")
    return ("iml", "iml,ir", "iml,ir,pgo") if scenario else ("iml", "iml,ir")


def eval_compile_s(eval_sets: tuple[str, ...] = EVAL_SETS) -> float:
    """The `evaluate` runs' compilations, whatever their frame counts (with the export stage,
    `EXPORT_S`, the fixed cost taken off the budget before the shares split it)."""
    return EVAL_COMPILE_S * sum(len(eval_modules(name)) for name in eval_sets)


# Pacing (module docstring): the counts a stage runs, and their smallest paced values
PACED_MINIMA = {"amlnet": MINIMA["amlnet_steps"], "amlnet_nocart": 50, "zoom_v1": 50, "zoom": 50, "refiner_v1": 25, "refiner": 25, "refiner_fine": 25,
                "scenarios": MINIMA["frames"]}
MAX_SLOWNESS = 4.0  # a run this far behind its rates is a slower machine or a busy one; past it pacing would starve the rest


def stage_counts(plan: Plan) -> dict[str, int]:
    """stage -> the count it runs: training steps of each phase, or the evaluation's frames per set
    (fixed when the `scenarios` stage renders them)."""
    return {"amlnet": plan.amlnet_steps, "amlnet_nocart": plan.amlnet_nocart_steps, "zoom_v1": plan.zoom_v1_steps,
            "zoom": plan.zoom_steps - plan.zoom_v1_steps, "refiner_v1": plan.refiner_v1_steps,
            "refiner": plan.refiner_steps - plan.refiner_v1_steps, "refiner_fine": plan.refiner_fine_steps, "scenarios": plan.frames}


def with_counts(plan: Plan, counts: dict[str, int]) -> Plan:
    """`plan` running `counts` (stage_counts' keys)."""
    c = stage_counts(plan) | counts
    return dataclasses.replace(plan, amlnet_steps=c["amlnet"], amlnet_nocart_steps=c["amlnet_nocart"], zoom_v1_steps=c["zoom_v1"],
                               zoom_steps=c["zoom_v1"] + c["zoom"], refiner_v1_steps=c["refiner_v1"],
                               refiner_steps=c["refiner_v1"] + c["refiner"], refiner_fine_steps=c["refiner_fine"], frames=c["scenarios"])


def stage_seconds(plan: Plan, faces: int) -> dict[str, float]:
    """stage -> its seconds at the rule's rates: what is fixed (the data, the compilations) and what
    its count costs (`stage_counts`; `scenarios` is charged its frames' evaluation too, which its
    frame count fixes: two scenarios and four held-out parts of about that size; `evaluate` is
    charged its compilations). The single source of the rule's costs: `make_plan` splits the
    budget with them too (`_unit_seconds`)."""
    image_s, v1_s, refine_s, v1_refine_s, frame_s, refiner_s = _mesh_rates(faces)
    n = stage_counts(plan)
    images = plan.images + plan.negatives + plan.nocart_images + plan.nocart_negatives
    return {"data": images * image_s + plan.refine_images * refine_s + plan.v1_images * v1_s + plan.refine_v1_images * v1_refine_s,
            "amlnet": n["amlnet"] * RATES["amlnet_step_s"], "amlnet_nocart": n["amlnet_nocart"] * RATES["amlnet_step_s"],
            "zoom_v1": n["zoom_v1"] * RATES["zoom_step_s"], "zoom": n["zoom"] * RATES["zoom_step_s"],
            "refiner_v1": n["refiner_v1"] * refiner_s, "refiner": n["refiner"] * refiner_s, "refiner_fine": n["refiner_fine"] * refiner_s,
            "export": EXPORT_S, "scenarios": n["scenarios"] * frame_s * 6,
            "evaluate": eval_compile_s(plan.eval_sets), "report": 0.0}


def slowness(plan: Plan, done: dict[str, float], faces: int) -> float:
    """How much longer than the rule's rates the finished stages took (1 when on time or faster)."""
    planned = stage_seconds(plan, faces)
    timed = [k for k in done if planned.get(k, 0.0) > 0.0]
    if not timed:
        return 1.0
    return min(MAX_SLOWNESS, max(1.0, sum(done[k] for k in timed) / sum(planned[k] for k in timed)))


def paced(plan: Plan, todo: list[str], seconds_left: float, slow: float, faces: int, first: Plan | None = None) -> tuple[Plan, float]:
    """`plan` with the counts of the stages in `todo` (those not yet begun) set to `first`'s (the
    plan as made; default `plan`) scaled down by one factor, so that `todo` at `slow` times the
    rates fits in `seconds_left`; none below PACED_MINIMA, none above `first`'s (a run that was
    behind and caught up gets its counts back). Returns (plan, factor): 1 when they fit unscaled."""
    first = plan if first is None else first
    counts = stage_counts(first)
    free = [k for k in todo if k in counts and counts[k] > 0]
    plan = with_counts(plan, {k: counts[k] for k in free})
    if plan.size == "tiny":  # test-size runs ignore the rates
        return plan, 1.0
    cost = stage_seconds(plan, faces)
    need, scalable = slow * sum(cost[k] for k in todo), slow * sum(cost[k] for k in free)
    if need <= seconds_left or scalable <= 0.0:
        return plan, 1.0
    f = max(0.0, 1.0 - (need - seconds_left) / scalable)
    lo = PACED_MINIMA | ({} if plan.warm_start else {"amlnet": MINIMA_FROM_SCRATCH["amlnet_steps"]})
    return with_counts(plan, {k: max(min(counts[k], lo[k]), int(counts[k] * f)) for k in free}), f
