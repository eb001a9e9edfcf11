"""`fit`'s stages, in order, each resumable: a stage that finished is recorded in DIR/fit.json and
skipped by `--resume`; one that was killed is run again (data are pure functions of (seed,
index), trainings continue from their last checkpoint).

DIR/
  fit.json            robot fingerprint, the plan (as made and as paced), stages begun and finished,
                      and their seconds (a killed attempt's included, up to its last file)
  data/train          v3 training set (BOP)            data/refine   the refiner's (BOP, 640 x 480)
  data/train_nocart   v3 without robot-like carts: AMLNet's last phase (BOP)
  data/train_v1       from scratch: the curriculum's plain-look (v1) images (BOP); data/train_mix: both (links)
  data/refine_v1      the refiner's plain-look (v1) images (BOP, 640 x 480); data/refine_mix: both (links)
  runs/{amlnet,amlnet_nocart,zoom_v1,zoom,refiner_v1,refiner,refiner_fine}   training runs (checkpoints, metrics.jsonl, metrics.png)
  networks/{amlnet,zoom,refiner,fine}                  exported weights for evaluate --amlnet/--zoom/--refiner/--fine-refiner
  eval/{circle,sine,heldout/...}, eval/results/*.json  evaluation data and evaluate's JSON
  report.md, report_*.png                              the report
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Callable

from rhaml_jax.errors import RhamlError
from rhaml_jax.fitting._plan import Plan, eval_modules, paced, slowness, stage_counts

SHIPPED = Path(__file__).resolve().parents[1] / "checkpoints"  # rhaml_jax/checkpoints: the shipped networks
WARM_START = {"cpu_heat": "heat_cpu", "zoom_cpu_luma": "zoom_luma_cpu"}  # config -> shipped network to fine-tune
REPAINT_PROB = 0.5
STAGES = ("data", "amlnet", "amlnet_nocart", "zoom_v1", "zoom", "refiner_v1", "refiner", "refiner_fine", "export", "scenarios", "evaluate", "report")
MIN_LENGTH_M, MAX_LENGTH_M = 0.03, 5.0
_now = time.time  # the wall clock stages are timed with, comparable with file times (tests replace it)


def load_checked_robot(spec: str):
    """The robot model, refused with one line when it has no visual geometry or a size no robot has
    (a mesh in millimetres read as metres is 1000 times too large)."""
    import warnings

    from rhaml_jax.robots import load_robot

    with warnings.catch_warnings():  # the too-large warning of load_robot becomes the error below
        warnings.simplefilter("ignore", UserWarning)
        model = load_robot(spec)
    if len(model.faces) == 0 or float(model.face_areas.sum()) <= 0:
        raise RhamlError(f"--robot {spec}: the model has no visual geometry (no faces with area)")
    length = float(max(model.extents))
    if not MIN_LENGTH_M <= length <= MAX_LENGTH_M:
        hint = (" (a mesh in millimetres read as metres? scale it by 0.001, e.g. scale=\"0.001 0.001 0.001\" in the URDF)"
                if length > MAX_LENGTH_M else " (a mesh scaled down too far?)")
        raise RhamlError(f"--robot {spec}: the model is {length:.4g} m across, outside the {MIN_LENGTH_M}-{MAX_LENGTH_M} m "
                         f"of a mobile robot{hint}")
    return model


@dataclasses.dataclass
class FitState:
    robot: dict
    plan: dict
    done: dict = dataclasses.field(default_factory=dict)
    """stage -> wall seconds it took"""
    planned: dict | None = None
    """the plan as made, before pacing (_plan's docstring)"""
    begun: dict = dataclasses.field(default_factory=dict)
    """stage -> wall clock (s since the epoch) when its latest attempt began; a begun stage's counts
    in `plan` are fixed (pacing changes only the stages not yet begun)"""
    lost: dict = dataclasses.field(default_factory=dict)
    """stage -> seconds it ran in attempts that were killed, each up to its last output file
    (counted in `done` once it finishes: the wall time of a run that was killed and resumed)"""

    def save(self, path: Path) -> None:
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(dataclasses.asdict(self), indent=1))
        os.replace(tmp, path)  # atomic: a kill leaves the old state or the new one


def open_state(out: Path, robot_spec: str, plan: Plan, resume: bool) -> tuple[FitState, Plan]:
    """The run's state: new (refusing a folder that holds a run, unless `resume`), or the stored
    one on `resume` (refusing another robot's folder; the stored plan wins)."""
    from rhaml_jax.robots import RobotFingerprint, fingerprint, require_same_robot

    model = load_checked_robot(robot_spec)
    fp = fingerprint(model)
    path = out / "fit.json"
    if path.exists():
        if not resume:
            raise RhamlError(f"{out}: holds a fit run already (fit.json): --resume continues it; or choose another --out")
        stored = json.loads(path.read_text())
        require_same_robot(RobotFingerprint.from_dict(stored["robot"], str(path)), fp,
                           f"--resume {out}: this run fits robot {{mine}}, not --robot {robot_spec} {{theirs}}; nothing was changed")
        done = stored.get("done", {})
        begun = stored.get("begun")
        # a run of a version before pacing: the stage after the finished ones may have begun when
        # fit.json was last written
        if begun is None:
            todo = [k for k in STAGES if k not in done]
            begun = {todo[0]: path.stat().st_mtime} if todo else {}
        return (FitState(stored["robot"], stored["plan"], done, stored.get("planned", stored["plan"]), begun, stored.get("lost", {})),
                Plan.from_dict(stored["plan"], f"{path}: plan"))
    if resume:
        raise RhamlError(f"--resume {out}: no fit run there (fit.json not found)")
    out.mkdir(parents=True, exist_ok=True)
    state = FitState(fp.to_dict(), dataclasses.asdict(plan), planned=dataclasses.asdict(plan))
    state.save(path)
    return state, plan


def _camera(width: int, height: int):
    from rhaml_jax.camera import DEFAULT_CAMERA

    return DEFAULT_CAMERA if (width, height) == (DEFAULT_CAMERA.width, DEFAULT_CAMERA.height) else DEFAULT_CAMERA.resized(width, height)


def _train(argv: list[str], run: Path) -> None:
    from rhaml_jax.train import main as train_main

    train_main(argv + ["--out", str(run)] + (["--resume"] if (run / "checkpoints").is_dir() else []))


def _mirror_flag(model) -> list[str]:
    from rhaml_jax.iml import check_mirror_symmetric

    try:
        check_mirror_symmetric(model, model.name)
    except RhamlError:
        return []
    return ["--zoom-mirror"]


def training_looks(scale: float) -> tuple:
    """(v3, no-cart, v1) SynthConfigs of the training data for a world `scale`: v3 is the v2
    appearance randomisation with half the robots repainted (_plan's docstring); no-cart the same
    without robot-like carts among the distractors (AMLNet's last phase); v1 the plain look of
    the curriculums' first steps."""
    from rhaml_jax.data import AppearanceConfig, SynthConfig

    v3 = SynthConfig(appearance=AppearanceConfig(repaint_prob=REPAINT_PROB)).scaled(scale)
    nocart = dataclasses.replace(v3, appearance=dataclasses.replace(v3.appearance, cart_prob=0.0))
    return v3, nocart, SynthConfig(appearance=None).scaled(scale)


def stage_functions(out: Path, robot_spec: str, plan: Plan, workers: int, seed: int) -> dict[str, Callable[[], None]]:
    """stage name -> a function that runs it (resumably)."""
    from rhaml_jax.data import write_heldout, write_scenario, write_training_set

    data, runs, nets, ev = out / "data", out / "runs", out / "networks", out / "eval"
    model = load_checked_robot(robot_spec)
    length = float(model.extents[0])

    def data_stage():
        v3, nocart, v1 = training_looks(plan.scale)
        write_training_set(data / "train", robot_spec, _camera(plan.width, plan.height), seed, plan.images, plan.negatives,
                           workers, cfg=v3)
        write_training_set(data / "train_nocart", robot_spec, _camera(plan.width, plan.height), seed + 4, plan.nocart_images,
                           plan.nocart_negatives, workers, cfg=nocart)  # amlnet_nocart_stage's
        write_training_set(data / "refine", robot_spec, _camera(plan.eval_width, plan.eval_height), seed + 1,
                           plan.refine_images, 0, workers, cfg=v3)
        if plan.v1_images:  # zoom_v1_stage's
            write_training_set(data / "train_v1", robot_spec, _camera(plan.width, plan.height), seed + 2, plan.v1_images, 0,
                               workers, cfg=v1)
        write_training_set(data / "refine_v1", robot_spec, _camera(plan.eval_width, plan.eval_height), seed + 3,
                           plan.refine_v1_images, 0, workers, cfg=v1)  # refiner_v1_stage's

    def train(stage: str, config: str, folder: str, steps: int, batch: int, val_times: int, val_batches: int, *extra,
              stage_dir: str | None = None):
        """One `train` run in runs/STAGE (or runs/STAGE_DIR), resumed if it has checkpoints."""
        tiny = plan.size == "tiny"
        _train(["--stage", stage, "--robot", robot_spec, "--config", config, "--data", str(data / folder), *extra,
                "--steps", str(steps), "--batch", str(batch), "--seed", str(seed),
                "--val-every", str(max(1, steps // val_times)), "--ckpt-every", str(max(1, min(250, steps // 4))),
                "--no-progress" if tiny else "--progress", "--val-batches", str(1 if tiny else val_batches)], runs / (stage_dir or stage))

    def init_from(weights: Path) -> list[str]:
        """Fine-tuning: --init from `weights`, at half the default learning rate."""
        return ["--init", str(weights), "--lr", "5e-4", "--warmup", "100"]

    def warm(config: str) -> list[str]:
        """From the shipped network of `config` (Plan.warm_start), else from random weights."""
        return init_from(SHIPPED / WARM_START[config]) if plan.warm_start else []

    amlnet_stage = lambda: train("amlnet", plan.amlnet_config, "train", plan.amlnet_steps, plan.amlnet_batch, 8, 8,  # noqa: E731
                                 *warm(plan.amlnet_config))

    def amlnet_nocart_stage():
        """AMLNet's last phase, from the first one's weights: no robot-like carts among the
        distractors, which taught it to reject robots seen end-on (_plan's docstring)."""
        train("amlnet", plan.amlnet_config, "train_nocart", plan.amlnet_nocart_steps, plan.amlnet_batch, 4, 8,
              *init_from(runs / "amlnet"), stage_dir="amlnet_nocart")

    zoom_args = ("--zoom-length-m", f"{length:.5f}", "--w-xy", "69.4", "526")

    def zoom_v1_stage():
        """From scratch, the zoom stage first learns on plain-look images, where the front/back cue is
        found (BENCHMARKS.md, "A curriculum for the heading"); warm-started, nothing."""
        if plan.zoom_v1_steps:
            train("zoom", plan.zoom_config, "train_v1", plan.zoom_v1_steps, plan.zoom_batch, 4, 8, *zoom_args, stage_dir="zoom_v1")

    def zoom_stage():
        if plan.zoom_v1_steps:  # the curriculum's second part: v3 and v1 images together, from zoom_v1
            from rhaml_jax.data import mix_sets

            mix_sets(data / "train_mix", [data / "train", data / "train_v1"])
            folder, start = "train_mix", init_from(runs / "zoom_v1")
        else:
            folder, start = "train", warm(plan.zoom_config)
        train("zoom", plan.zoom_config, folder, plan.zoom_steps - plan.zoom_v1_steps, plan.zoom_batch, 8, 8, *zoom_args, *start)

    def refiner_v1_stage():
        """The refiner first learns on plain-look images: from random weights on v3 images alone it
        hardly learns (BENCHMARKS.md, "A curriculum for the refiner")."""
        train("refiner", plan.refiner_config, "refine_v1", plan.refiner_v1_steps, plan.refiner_batch, 4, 4, stage_dir="refiner_v1")

    def refiner_stage():
        """Then v3 and v1 crops together, from refiner_v1's weights: better than v3 alone behind the
        same IML on both validation looks (BENCHMARKS.md, "The refiner's second phase on the mix")."""
        from rhaml_jax.data import mix_sets

        mix_sets(data / "refine_mix", [data / "refine", data / "refine_v1"])
        train("refiner", plan.refiner_config, "refine_mix", plan.refiner_steps - plan.refiner_v1_steps, plan.refiner_batch, 4, 4,
              *init_from(runs / "refiner_v1"))

    def refiner_fine_stage():
        """The cascade's fine refiner (the pipeline runs it after the refiner), from the refiner's
        weights on the same crops, its starts drawn as a refiner leaves them (_plan's docstring)."""
        train("refiner", plan.fine_config, "refine_mix", plan.refiner_fine_steps, plan.refiner_batch, 4, 4,
              "--init", str(runs / "refiner"), "--lr", "3e-4", "--warmup", "100", stage_dir="refiner_fine")

    def export_stage():
        from rhaml_jax.amlnet import export_weights
        from rhaml_jax.refine import export_refiner

        import shutil

        for name, run, export in (("amlnet", "amlnet_nocart", export_weights), ("zoom", "zoom", export_weights),
                                  ("refiner", "refiner", export_refiner), ("fine", "refiner_fine", export_refiner)):
            shutil.rmtree(nets / name, ignore_errors=True)  # derived from runs/: a killed export is redone whole
            export(runs / run, nets / name)
        # IML's flip probability calibrated on the training set's own validation split
        from rhaml_jax.calibrate_flips import Args as CalArgs, calibrate

        try:
            calibrate(CalArgs(data / "train", nets / "zoom", amlnet=nets / "amlnet", split="val",
                              zoom_mirror=bool(_mirror_flag(model)), batch=plan.zoom_batch))
        except RhamlError as e:  # a test-size run: too few detected frames; the raw ranking stays
            if plan.size != "tiny":
                raise
            print(f"rhaml_jax.fit: flip probability not calibrated: {e}", file=sys.stderr)

    def scenarios_stage():
        cam = _camera(plan.eval_width, plan.eval_height)
        for name in ("circle", "sine"):
            write_scenario(ev / name, name, robot_spec, cam, seed, plan.frames, workers, scale=plan.scale)
        write_heldout(ev / "heldout", robot_spec, cam, seed, plan.frames, plan.frames, max(4, plan.frames // 5), workers,
                      scale=plan.scale)

    def evaluate_stage():
        from rhaml_jax.evaluate import main as evaluate_main

        (ev / "results").mkdir(parents=True, exist_ok=True)
        nets_args = ["--amlnet", str(nets / "amlnet"), "--zoom", str(nets / "zoom"), "--refiner", str(nets / "refiner"),
                     "--fine-refiner", str(nets / "fine"), *_mirror_flag(model)]
        for name in plan.eval_sets:
            folder = eval_folder(ev, name)
            for modules in eval_modules(name):
                target = ev / "results" / f"{name.replace('/', '_')}_{modules.replace(',', '+')}.json"
                if not target.exists():
                    evaluate_main(["--data", str(folder), "--modules", modules, "--json", str(target), *nets_args])

    def report_stage():
        from rhaml_jax.fitting._report import write_report

        write_report(out, model, plan)

    return {"data": data_stage, "amlnet": amlnet_stage, "amlnet_nocart": amlnet_nocart_stage, "zoom_v1": zoom_v1_stage, "zoom": zoom_stage,
            "refiner_v1": refiner_v1_stage, "refiner": refiner_stage, "refiner_fine": refiner_fine_stage,
            "export": export_stage, "scenarios": scenarios_stage, "evaluate": evaluate_stage, "report": report_stage}


def eval_folder(ev: Path, name: str) -> Path:
    """The BOP folder of an evaluation set: our scenario (circle, sine) or a held-out part (heldout/PART)."""
    return ev.joinpath(*name.split("/"))


def run_fit(robot_spec: str, out: Path, plan: Plan, resume: bool = False, workers: int = 2, seed: int = 0,
            stop_after: str | None = None, log: Callable[[str], None] = print) -> FitState:
    """Runs (or, with `resume`, continues) every stage; `stop_after` ends the run after that stage
    as a kill would (for tests)."""
    out = Path(out)
    state, plan = open_state(out, robot_spec, plan, resume)
    faces = len(load_checked_robot(robot_spec).faces)
    funcs = stage_functions(out, robot_spec, plan, workers, seed)
    budget = plan.budget_minutes * 60.0
    for k, name in enumerate(STAGES, 1):
        if name in state.done:
            log(f"[fit {k}/{len(STAGES)}] {name}: done ({state.done[name]:.0f} s), skipped")
            continue
        if name in state.begun:  # killed in an earlier attempt: what it ran then counts
            ran = _ran_before_kill(out, state.begun[name])
            state.lost[name] = round(state.lost.get(name, 0.0) + ran, 1)
            log(f"[fit] {name}: its attempt killed after {ran:.0f} s counts towards its time")
        used = sum(state.done.values()) + sum(v for s, v in state.lost.items() if s not in state.done)
        log(f"[fit {k}/{len(STAGES)}] {name}: {used / 60:.1f} min used, {max(0.0, budget - used) / 60:.1f} min left of "
            f"the {plan.budget_minutes:g} min budget")
        if name not in state.begun:
            plan = _pace(state, plan, name, budget - used, faces, log)
            funcs = stage_functions(out, robot_spec, plan, workers, seed)
        ts = state.begun[name] = _now()
        state.save(out / "fit.json")  # the paced plan, and when this attempt began
        funcs[name]()
        state.done[name] = round(state.lost.get(name, 0.0) + _now() - ts, 1)
        state.save(out / "fit.json")
        if name == stop_after:
            break
    return state


def _ran_before_kill(out: Path, begun: float) -> float:
    """Seconds a killed attempt that began at `begun` ran, up to the newest file it wrote under
    `out` (fit.json aside): every stage writes as it goes (images, metrics, checkpoints, results)."""
    newest = begun
    for root, _, names in os.walk(out):
        for n in names:
            if n != "fit.json":
                try:
                    newest = max(newest, os.stat(os.path.join(root, n)).st_mtime)
                except OSError:  # removed while we looked
                    pass
    return newest - begun


def _pace(state: FitState, plan: Plan, stage: str, seconds_left: float, faces: int, log: Callable[[str], None]) -> Plan:
    """Before `stage` begins: the plan with this and the later stages' counts scaled down when the
    run is behind its budget (_plan's docstring, "Pacing"), stored in `state`."""
    todo = [k for k in STAGES[STAGES.index(stage):] if k not in state.done]
    slow = slowness(plan, state.done, faces)
    first = Plan.from_dict(state.planned, "fit.json: planned")
    new, f = paced(plan, todo, seconds_left, slow, faces, first)
    before, after = stage_counts(plan), stage_counts(new)
    changed = ", ".join(f"{'frames per evaluation set' if k == 'scenarios' else k + ' steps'} {before[k]} -> {after[k]}"
                        for k in before if before[k] != after[k])
    if changed:
        log(f"[fit] paced: the finished stages took {slow:.2f}x their planned seconds; {changed} "
            f"({f:.2f} of the plan as made)")
    state.plan = dataclasses.asdict(new)
    return new
