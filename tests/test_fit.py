"""`python -m rhaml_jax.fit` at tiny size: end to end on the TurtleBot3 URDF, killed after a stage
and resumed, and its refusals (another robot's folder, no visual geometry, a robot in the wrong
units, a budget too small), each one line with exit status 2 and nothing trained lost."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rhaml_jax.errors import RhamlError
from rhaml_jax.fitting import STAGES, load_checked_robot, make_plan, run_fit
from tests.conftest import shared_path

ROOT = Path(__file__).resolve().parents[1]


def _turtlebot() -> str:
    return str(shared_path("robots", "turtlebot3_burger", "urdf", "turtlebot3_burger.main.urdf"))


@pytest.fixture(scope="module")
def killed_and_resumed(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "tb"
    robot = _turtlebot()
    plan = make_plan(5, "tiny", scale=load_checked_robot(robot).world_scale)
    first = run_fit(robot, out, plan, workers=1, stop_after="amlnet", log=lambda s: None)
    assert list(first.done) == ["data", "amlnet"]
    amlnet_ckpt = sorted((out / "runs" / "amlnet" / "checkpoints").iterdir())
    logs = []
    state = run_fit(robot, out, plan, resume=True, workers=1, log=logs.append)
    return out, state, amlnet_ckpt, logs


def test_end_to_end_after_a_kill_and_resume(killed_and_resumed):
    out, state, amlnet_ckpt, logs = killed_and_resumed
    assert list(state.done) == list(STAGES)
    assert any("amlnet: done" in line and "skipped" in line for line in logs)  # not trained again
    assert sorted((out / "runs" / "amlnet" / "checkpoints").iterdir()) == amlnet_ckpt
    for net in ("amlnet", "zoom", "refiner", "fine"):
        assert (out / "networks" / net / "checkpoints").is_dir()
    # from scratch (tiny plans are): the zoom stage's curriculum, v1 images first, then v3 and v1 together
    assert (out / "runs" / "zoom_v1" / "checkpoints").is_dir()
    # AMLNet's last phase, on the no-cart images, from the first phase's weights; it is what is exported
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta

    assert checkpoint_meta(out / "runs" / "amlnet_nocart").get("initialised_from") == str(out / "runs" / "amlnet")
    assert (out / "data" / "train_nocart" / "train").is_dir()
    assert checkpoint_meta(out / "networks" / "amlnet").get("exported_from") == str(out / "runs" / "amlnet_nocart")
    assert {p.resolve().parents[1].name for p in (out / "data" / "train_mix" / "train").iterdir()} == {"train", "train_v1"}
    # the refiner's: v1 images first, then v3 and v1 together from that run's weights
    assert (out / "runs" / "refiner_v1" / "checkpoints").is_dir() and (out / "data" / "refine_v1" / "train").is_dir()
    assert checkpoint_meta(out / "runs" / "refiner").get("initialised_from") == str(out / "runs" / "refiner_v1")
    assert {p.resolve().parents[1].name for p in (out / "data" / "refine_mix" / "train").iterdir()} == {"refine", "refine_v1"}
    # the cascade's fine refiner, from the refiner's weights; the evaluation runs it after the refiner
    assert checkpoint_meta(out / "runs" / "refiner_fine").get("initialised_from") == str(out / "runs" / "refiner")
    assert checkpoint_meta(out / "networks" / "fine").get("exported_from") == str(out / "runs" / "refiner_fine")
    assert (out / "runs" / "refiner" / "metrics.png").stat().st_size > 1000  # the report's curves
    report = (out / "report.md").read_text()
    assert "turtlebot3_burger" in report and "| heldout/circle | iml,ir |" in report and "| circle | iml,ir,pgo |" in report
    assert (out / "report_trajectories.png").stat().st_size > 1000
    # the flip probability's quality per set (a tiny run has too few validation frames to calibrate it)
    assert "## Flip probability" in report and "raw front/back ranking (not calibrated)" in report
    assert "| back / side / front views |" in report and "| circle | " in report.split("## Flip probability")[1]
    # the TurtleBot's world is 0.39 of the Pioneer's: the circle 2.5-6.5 m becomes 0.98-2.54 m
    assert "Distances x 0.39" in report
    frames = json.loads((out / "eval/results/circle_iml.json").read_text())["frames"]
    ranges = [np.hypot(*f["gt"][:2]) for f in frames if f["observed"]]
    assert 0.39 * 2.5 - 1e-3 <= min(ranges) and max(ranges) <= 0.39 * 6.5 + 1e-3


def test_networks_carry_the_robot_and_its_crop_size(killed_and_resumed):
    from rhaml_jax.amlnet import load_model
    from rhaml_jax.amlnet.checkpoint import checkpoint_robot
    from rhaml_jax.robots import fingerprint

    out = killed_and_resumed[0]
    tb = fingerprint(load_checked_robot(_turtlebot())).to_dict()
    for net in ("amlnet", "zoom"):
        assert checkpoint_robot(out / "networks" / net) == tb
    zoom, _, _ = load_model(out / "networks" / "zoom")
    np.testing.assert_allclose(zoom.cfg.zoom_length_m, tb["extents_m"][0], atol=1e-4)


def test_networks_are_refused_on_another_robots_data(killed_and_resumed, tmp_path):
    """The TurtleBot's networks on a Pioneer data set: evaluate names both robots."""
    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import write_scenario
    from rhaml_jax.evaluate import main as evaluate_main

    out = killed_and_resumed[0]
    write_scenario(tmp_path / "circle", "circle", "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=0, frames=4, workers=1)
    with pytest.raises(RhamlError, match=r"was made for robot 'turtlebot3_burger.main' .* is robot 'obj_000001' \(45.5"):
        evaluate_main(["--data", str(tmp_path / "circle"), "--amlnet", str(out / "networks" / "amlnet"),
                       "--zoom", str(out / "networks" / "zoom")])


def test_resume_on_another_robots_folder_changes_nothing(killed_and_resumed):
    out = killed_and_resumed[0]
    before = (out / "fit.json").read_text()
    with pytest.raises(RhamlError, match=r"this run fits robot 'turtlebot3_burger.main' .*not --robot pioneer3dx"):
        run_fit("pioneer3dx", out, make_plan(5, "tiny"), resume=True)
    with pytest.raises(RhamlError, match=r"holds a fit run already"):
        run_fit(_turtlebot(), out, make_plan(5, "tiny"))
    assert (out / "fit.json").read_text() == before


def _cli(tmp_path, *args):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "rhaml_jax.fit", *args], cwd=ROOT, capture_output=True, text=True, env=env)


def test_bad_input_one_line_exit_2(tmp_path):
    no_visual = tmp_path / "no_visual.urdf"
    no_visual.write_text('<robot name="ghost"><link name="base_link"><collision><geometry><box size="0.3 0.2 0.1"/>'
                         "</geometry></collision></link></robot>")
    huge = tmp_path / "huge.obj"  # a 455 mm robot written in millimetres, read as metres
    v = np.array([[0, 0, 0], [455, 0, 0], [0, 380, 0], [0, 0, 240]], float)
    huge.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    for args, msg in (((str(no_visual),), "visual"),
                      ((str(huge),), "455 m across"),
                      (("pioneer3dx", "--size", "cpu", "--budget-minutes", "2"), "too small to train anything"),
                      (("pioneer3dx", "--resume"), "no fit run there")):
        r = _cli(tmp_path, "--robot", args[0], "--out", str(tmp_path / "out"), *args[1:])
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "out" / "fit.json").exists()


# the budget rule's rates (module docstring of _plan) at 604 faces: data 0.029 s per image and 0.3 of it
# without carts for AMLNet's last phase, 0.122 s per v3 image of the refiner's (a tenth) and 0.05 s per v1
# one (a twentieth); AMLNet 0.9 s per step and 3/8 of a no-cart step after each; the evaluation 0.13 s
# per frame and set; the refiner 0.13 s per step, and a third as many steps of the fine refiner after it
IMG = 0.029 * 1.3 + 0.122 / 10 + 0.05 / 20
STEP = 0.9 * 11 / 8
# off the top: the evaluation's 16 compilations (13.6 s each) and the export with its flip calibration (32 s)
F = 16 * 13.6 + 32.0


def _planned_s(r) -> float:
    """The seconds a Pioneer plan's counts take at those rates (compilations left out)."""
    return ((r.images + r.negatives) * IMG + r.v1_images * 0.015 + r.amlnet_steps * STEP + r.zoom_steps * 0.1
            + (r.refiner_steps + r.refiner_fine_steps) * 0.13 + 6 * r.frames * 0.13)


def test_budget_rule():
    p = make_plan(180)
    assert (p.amlnet_steps, p.images, p.frames) == (4000, 20000 * 7 // 8, 500)  # capped
    assert (p.scale, p.warm_start) == (1.0, True)
    # F comes off the top; the shares split the rest
    q = make_plan(40)  # 2400 s - F: data 15 %, AMLNet 45 % (604 faces; at 45 min the evaluation is capped)
    assert q.images + q.negatives == int(0.15 * (2400 - F) / IMG)
    # AMLNet's last phase: 0.3 as many no-cart images (7/8 with the robot), 3/8 as many steps
    nocart = int((q.images + q.negatives) * 0.3)
    assert (q.nocart_images, q.nocart_negatives) == (nocart * 7 // 8, nocart - nocart * 7 // 8)
    assert q.amlnet_nocart_steps == round(q.amlnet_steps * 3 / 8)
    # no stage capped: only the roundings' leftovers (about a second) go to the trainings
    assert abs(q.amlnet_steps - 0.45 * (2400 - F) / STEP) <= 2 and abs(q.zoom_steps - 0.12 * (2400 - F) / 0.1) <= 10
    # a 91,104-face mesh renders at 0.136 s per image (0.26 s and 0.13 s the refiner's) and evaluates at
    # 1.17 s per frame: fewer of both
    t = make_plan(40, faces=91_104, scale=0.39)
    assert t.images + t.negatives == int(0.15 * (2400 - F) / (0.136 * 1.3 + 0.26 / 10 + 0.13 / 20))
    assert t.frames == int(0.18 * (2400 - F) / 1.17 / 6)
    assert abs(t.amlnet_steps - q.amlnet_steps) <= 5 and t.scale == 0.39  # only the roundings' leftovers differ
    # the refiner renders too: 0.13 s per step at 604 faces, 0.5 s at 91,104; its share buys the fine
    # refiner's third as many steps too
    assert abs(q.refiner_steps - 0.1 * (2400 - F) / (0.13 * 4 / 3)) <= 1 and abs(t.refiner_steps - 0.1 * (2400 - F) / (0.5 * 4 / 3)) <= 1
    assert (q.refiner_fine_steps, t.refiner_fine_steps) == (q.refiner_steps // 3, t.refiner_steps // 3)
    # what a capped stage leaves goes to the trainings: at 95 min the refiner (3000 steps of its
    # share) and the evaluation (500 frames per set) are capped, and AMLNet and the zoom stage get
    # their seconds by share
    S = 95 * 60 - F
    r = make_plan(95)
    assert r.images + r.negatives == int(0.15 * S / IMG) and (r.refiner_steps, r.refiner_fine_steps, r.frames) == (3000, 1000, 500)
    spare = S - (r.images + r.negatives) * IMG - 0.45 * S - 0.12 * S - 4000 * 0.13 - 6 * r.frames * 0.13
    assert spare > 100
    assert abs(r.amlnet_steps - (0.45 * S + spare * 45 / 57) / STEP) <= 2
    assert abs(r.zoom_steps - (0.12 * S + spare * 12 / 57) / 0.1) <= 10  # a second of roundings' leftovers
    assert 0.99 * S <= _planned_s(r) <= S
    # at 123 min the data (20,000 images) and the zoom stage (10,000 steps) are capped too: AMLNet gets the rest
    S = 123 * 60 - F
    r = make_plan(123)
    assert (r.images + r.negatives, r.zoom_steps, r.refiner_steps, r.frames) == (20000, 10_000, 3000, 500)
    assert abs(r.amlnet_steps - (S - 20000 * IMG - 10_000 * 0.1 - 4000 * 0.13 - 6 * 500 * 0.13) / STEP) <= 2
    assert 0.99 * S <= _planned_s(r) <= S
    big = make_plan(100_000)
    assert big.amlnet_steps == 4000 and big.images + big.negatives == 20000
    # once AMLNet and the zoom stage are capped, what is left goes to the refiner, up to 6000 steps
    assert (big.refiner_steps, big.refiner_fine_steps) == (6000, 2000) and make_plan(110).refiner_steps == 3000
    mid = make_plan(137)  # AMLNet and zoom capped, the refiner between its caps
    assert (mid.amlnet_steps, mid.zoom_steps) == (4000, 10_000) and 3000 < mid.refiner_steps < 6000
    with pytest.raises(RhamlError, match="frames 0 < 20\\); give at least 10 minutes"):
        make_plan(3)  # less than the evaluation's compilations
    with pytest.raises(RhamlError, match=r"\(images 831 < 1000\); give at least 10 minutes"):
        make_plan(9)
    make_plan(10)  # the smallest budget it names is enough
    # from random weights AMLNet needs 2,000 steps (30 minutes, 901 steps, detected nothing)
    with pytest.raises(RhamlError, match=r"from scratch \(amlnet_steps 1354 < 2000\); give at least 83 minutes"):
        make_plan(60, warm_start=False)
    scratch = make_plan(83, warm_start=False)
    assert scratch.amlnet_steps >= 2000 and not scratch.warm_start
    # its curriculum: half as many v1 images as v3 ones, the zoom stage's first 12/17 on them
    assert scratch.v1_images == (scratch.images + scratch.negatives) // 2 and scratch.zoom_v1_steps == round(scratch.zoom_steps * 12 / 17)
    # from scratch the zoom stage may run longer (17,000 steps: 12,000 on v1 images, 5,000 on the mix)
    long = make_plan(155, warm_start=False)
    assert (long.zoom_steps, long.zoom_v1_steps) == (17_000, 12_000) and make_plan(184).zoom_steps == 10_000
    assert 3000 < long.refiner_steps < 6000  # the refiner's extra steps come after the zoom stage's
    assert (make_plan(75).v1_images, make_plan(75).zoom_v1_steps) == (0, 0)  # fine-tuning needs none
    # the refiner always starts from random weights: its first 2/3 on v1 images, a twentieth as many as v3 ones
    for q in (scratch, long, make_plan(75)):
        assert q.refiner_v1_steps == round(q.refiner_steps * 2 / 3) and q.refine_v1_images == (q.images + q.negatives) // 20
    assert not make_plan(5, "tiny").warm_start  # test-size networks have no shipped weights
    assert json.loads(json.dumps(p.__dict__))["eval_sets"] == list(p.eval_sets)


def test_a_plan_never_spends_more_than_its_budget():
    """Every count at its stage's rate (module docstring of _plan) adds up to at most the budget,
    also where the refiner's cap is raised (a capped refiner's unused share had gone to AMLNet and
    the zoom stage already: counting it again overspent by up to 4.7 %, at 131.5 minutes from scratch)."""
    for budget in np.arange(14.0, 260.0, 0.5):
        for warm in (True, False):
            try:
                r = make_plan(float(budget), warm_start=warm)
            except RhamlError:
                continue
            assert _planned_s(r) <= budget * 60 - F + 1e-6, (budget, warm, _planned_s(r))


def test_amlnets_last_phase_has_no_carts():
    """AMLNet's last phase learns on the v3 look without robot-like carts (_plan's docstring); every
    other factor is v3's, at the robot's world scale."""
    from rhaml_jax.fitting._run import training_looks

    v3, nocart, v1 = training_looks(0.39)
    assert v3.appearance.cart_prob > 0 and nocart.appearance.cart_prob == 0.0
    assert dataclasses.replace(nocart.appearance, cart_prob=v3.appearance.cart_prob) == v3.appearance
    assert dataclasses.replace(nocart, appearance=v3.appearance) == v3 and v1.appearance is None


def test_warm_start_networks_are_shipped_with_the_plans_configs():
    from rhaml_jax.amlnet import load_model
    from rhaml_jax.fitting._run import SHIPPED, WARM_START

    p = make_plan(45)
    for config in (p.amlnet_config, p.zoom_config):
        net, _, _ = load_model(SHIPPED / WARM_START[config])
        assert net.cfg.name == config


def test_report_plots_a_set_where_nothing_was_detected(tmp_path):
    """A 30-minute Pioneer run detected nothing in one set; its report must still be written."""
    from rhaml_jax.fitting._report import _plots

    seen = {"observed": True, "est": [2.5, 0.1, 0.2], "gt": [2.5, 0.0, 0.0]}
    missed = {"observed": True, "est": None, "gt": [2.5, 0.0, 0.0]}
    results = {("circle", "iml"): {"frames": [missed, missed]}, ("circle", "iml,ir,pgo"): {"frames": [missed]},
               ("sine", "iml"): {"frames": [seen, missed]}, ("sine", "iml,ir"): {"frames": [seen]}}
    assert _plots(tmp_path, results) == ["report_trajectories.png", "report_errors.png"]
    assert (tmp_path / "report_trajectories.png").stat().st_size > 0


def _timed_run(tmp_path, monkeypatch, budget: float, slow: float, fail_in: str | None = None, resume: bool = False):
    """run_fit on the Pioneer with stages that do nothing but take `slow` times the rule's seconds
    on a fake clock; `fail_in` writes a file halfway through that stage and dies, as a kill would.
    Returns (fake seconds, stage -> the plan it ran with, the state)."""
    from rhaml_jax.fitting import _run
    from rhaml_jax.fitting._plan import stage_seconds

    # the epoch's seconds, as file times are; a resumed run starts hours after the last attempt began
    path = tmp_path / "p" / "fit.json"
    begun = json.loads(path.read_text()).get("begun", {"": path.stat().st_mtime}) if resume else {"": 1.7e9 - 1e4}
    clock, ran = [max(begun.values()) + 1e4], {}

    def stages(out, robot_spec, plan, workers, seed):
        def stage(name):
            def run():
                ran[name] = plan
                if name == fail_in:
                    clock[0] += 0.5 * slow * stage_seconds(plan, 604)[name]
                    (out / f"{name}.part").write_text("")
                    os.utime(out / f"{name}.part", (clock[0], clock[0]))
                    raise KeyboardInterrupt
                clock[0] += slow * stage_seconds(plan, 604)[name]
            return run
        return {name: stage(name) for name in STAGES}

    monkeypatch.setattr(_run, "stage_functions", stages)
    monkeypatch.setattr(_run, "_now", lambda: clock[0])
    t0, state = clock[0], None
    try:
        state = run_fit("pioneer3dx", tmp_path / "p", make_plan(budget), resume=resume, log=lambda s: None)
    except KeyboardInterrupt:
        pass
    return clock[0] - t0, ran, state


def test_a_run_behind_its_rates_is_paced_to_its_budget(tmp_path, monkeypatch):
    """Every stage 30 % slower than the rule's rates (the 45-minute TurtleBot3 run took 18 % more
    than its budget): from the second stage on, the later stages' counts shrink by one factor and
    the run ends within its budget; on time, nothing changes."""
    from rhaml_jax.fitting._plan import stage_counts

    assert len(load_checked_robot("pioneer3dx").faces) == 604
    plan = make_plan(60)
    seconds, ran, _ = _timed_run(tmp_path / "on_time", monkeypatch, 60, 1.0)
    assert all(stage_counts(p) == stage_counts(plan) for p in ran.values()) and seconds <= 3600
    seconds, ran, _ = _timed_run(tmp_path / "slow", monkeypatch, 60, 1.3)
    assert 0.98 * 3600 <= seconds <= 3600 + 1.0, seconds  # unpaced: 1.3 x 3600
    # paced when the data stage came in late, by one factor; the later stages then kept to time
    shrunk = {k: v / stage_counts(plan)[k] for k, v in stage_counts(ran["report"]).items() if stage_counts(plan)[k]}
    assert max(shrunk.values()) < 0.85 and max(shrunk.values()) - min(shrunk.values()) < 0.02, shrunk
    stored = json.loads((tmp_path / "slow" / "p" / "fit.json").read_text())
    assert list(stored["begun"]) == list(STAGES) and stored["plan"]["zoom_steps"] == ran["zoom"].zoom_steps


def test_a_killed_stage_keeps_its_counts_and_its_time(tmp_path, monkeypatch):
    """Killed halfway through the zoom stage and resumed hours later: its training continues from
    its checkpoint with the steps it began with, so the stage is not paced again, though the
    half it ran before the kill (up to its last file) now counts as used and the stages after it
    are cut; the stage's recorded seconds are both attempts', not the wait between them."""
    from rhaml_jax.fitting._plan import stage_seconds

    _, before, _ = _timed_run(tmp_path, monkeypatch, 60, 1.2, fail_in="zoom")
    _, after, state = _timed_run(tmp_path, monkeypatch, 60, 1.2, resume=True)
    assert "amlnet" not in after and after["zoom"].zoom_steps == before["zoom"].zoom_steps
    assert after["refiner"].refiner_steps < before["zoom"].refiner_steps
    zoom_s = 1.2 * stage_seconds(before["zoom"], 604)["zoom"]
    assert state.lost == {"zoom": pytest.approx(0.5 * zoom_s, abs=0.1)}
    assert state.done["zoom"] == pytest.approx(1.5 * zoom_s, abs=0.2)


def test_a_run_of_an_older_version_resumes_its_stage_in_progress(tmp_path, monkeypatch):
    """fit.json of a version before pacing (no `begun`, `lost` or `planned`), killed in the zoom
    stage: the stage keeps its counts, and its attempt counts from when fit.json was last written."""
    from rhaml_jax.fitting._plan import stage_seconds

    _, before, _ = _timed_run(tmp_path, monkeypatch, 60, 1.2, fail_in="zoom")
    path = tmp_path / "p" / "fit.json"
    stored = json.loads(path.read_text())
    zoom_began = stored.pop("begun")["zoom"]
    del stored["lost"], stored["planned"]
    path.write_text(json.dumps(stored))
    os.utime(path, (zoom_began, zoom_began))  # the old version wrote it when the stage before finished
    _, after, state = _timed_run(tmp_path, monkeypatch, 60, 1.2, resume=True)
    assert "amlnet" not in after and after["zoom"].zoom_steps == before["zoom"].zoom_steps
    assert state.lost == {"zoom": pytest.approx(0.5 * 1.2 * stage_seconds(before["zoom"], 604)["zoom"], abs=0.1)}


def test_pacing_stays_between_the_minima_and_the_plan_as_made():
    from rhaml_jax.fitting._plan import PACED_MINIMA, paced, stage_counts, stage_seconds

    plan = make_plan(120, warm_start=False)
    total = sum(stage_seconds(plan, 604).values())
    assert paced(plan, list(STAGES[1:]), 2 * total, 1.0, 604) == (plan, 1.0)  # ahead: unchanged, not raised
    short, f = paced(plan, list(STAGES[2:]), 60.0, 2.0, 604)  # far behind, AMLNet's first phase begun
    assert f == 0.0 and short.amlnet_steps == plan.amlnet_steps  # not in `todo`: kept
    assert paced(plan, list(STAGES[1:]), 60.0, 2.0, 604)[0].amlnet_steps == 2000  # from random weights AMLNet needs 2,000
    # caught up again (time to spare at the refiner): the stages not begun get the plan's counts back, no more
    back, f = paced(short, list(STAGES[5:]), 2 * total, 1.0, 604, first=plan)
    assert f == 1.0 and stage_counts(back) == stage_counts(short) | {"refiner_v1": plan.refiner_v1_steps,
                                                                     "refiner": plan.refiner_steps - plan.refiner_v1_steps,
                                                                     "refiner_fine": plan.refiner_fine_steps,
                                                                     "scenarios": plan.frames}
    assert PACED_MINIMA["amlnet"] == 100 and {k: v for k, v in stage_counts(short).items() if k != "amlnet"} == {
        k: v for k, v in PACED_MINIMA.items() if k != "amlnet"}
