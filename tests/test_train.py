"""The AMLNet trainer: exact resume after a kill, 8-device data parallelism, NaN stop, bad
input.  All on the `micro` config and toy data (tiny compiles; no timing)."""

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import jax
import numpy as np
import pytest

from rhaml_jax.amlnet.checkpoint import load_model
from rhaml_jax.amlnet.config import get_config
from rhaml_jax.amlnet.data import ToyRectangles
from rhaml_jax.amlnet.trainer import TrainConfig, train_amlnet
from rhaml_jax.errors import RhamlError

CFG = get_config("micro")
TC = TrainConfig(steps=12, batch=8, log_every=2, val_every=6, val_batches=1, ckpt_every=2, seed=3)
ROOT = Path(__file__).resolve().parents[1]
CLI = ["-m", "rhaml_jax.train", "--stage", "amlnet", "--config", "micro", "--steps", "12", "--batch", "8", "--seed", "3",
       "--log-every", "2", "--val-every", "6", "--val-batches", "1", "--ckpt-every", "2", "--toy-data", "--no-progress"]


def _sources(tc=TC):
    return ToyRectangles(CFG.input_hw, tc.batch, tc.seed), ToyRectangles(CFG.input_hw, tc.batch, tc.seed + 10_000)


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    res = train_amlnet(CFG, TC, out, *_sources(), progress=False, num_devices=1, log=lambda s: None)
    return out, res


def _env(tmp_path):
    env = dict(os.environ)
    env["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path / "jax_cache")
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_run_writes_metrics_plot_and_checkpoints(reference_run):
    out, res = reference_run
    rows = [json.loads(l) for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [2, 4, 6, 8, 10, 12]
    assert all(np.isfinite(r["loss"]) for r in rows)
    assert "val_dx_cm" in rows[2] and "val_detection_acc" in rows[-1]
    assert (out / "metrics.png").stat().st_size > 1000
    net, params, stats = load_model(out)
    assert net.cfg == CFG
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(res["params"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_kill_and_resume_gives_the_uninterrupted_params(reference_run, tmp_path):
    _, ref = reference_run
    out = tmp_path / "run"
    env = _env(tmp_path)
    proc = subprocess.Popen([sys.executable, *CLI, "--out", str(out)], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    killed_at = None
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None:
        ck = out / "checkpoints"
        done = [int(p.name) for p in ck.iterdir() if p.name.isdigit()] if ck.is_dir() else []
        if done and 2 <= max(done) < 12:
            proc.send_signal(signal.SIGKILL)
            killed_at = max(done)
            break
        time.sleep(0.02)
    proc.wait()
    assert killed_at is not None, proc.stderr.read().decode()[-2000:]
    r = subprocess.run([sys.executable, *CLI, "--out", str(out), "--resume"], env=env, cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "resuming" in r.stdout
    _, params, _ = load_model(out)
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(ref["params"])):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-7)
    steps = [json.loads(l)["step"] for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert steps == sorted(set(steps)) and steps[-1] == 12


def test_eight_devices_give_the_one_device_loss(reference_run, tmp_path):
    ref_out, _ = reference_run
    script = f"""
import json, jax
from rhaml_jax.amlnet.config import get_config
from rhaml_jax.amlnet.data import ToyRectangles
from rhaml_jax.amlnet.trainer import TrainConfig, train_amlnet
assert len(jax.devices()) == 8, jax.devices()
cfg = get_config("micro")
tc = TrainConfig(**{TC.__dict__!r})
res = train_amlnet(cfg, tc, {str(tmp_path / 'dp')!r}, ToyRectangles(cfg.input_hw, 8, 3), None, progress=False, stop_at=4)
"""
    env = _env(tmp_path)
    env["XLA_FLAGS"] = env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=8"
    r = subprocess.run([sys.executable, "-c", script], env=env, cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    dp = [json.loads(l) for l in (tmp_path / "dp" / "metrics.jsonl").read_text().splitlines()]
    one = [json.loads(l) for l in (ref_out / "metrics.jsonl").read_text().splitlines()]
    assert [d["step"] for d in dp] == [2, 4]
    for d, o in zip(dp, one):
        np.testing.assert_allclose(d["loss"], o["loss"], rtol=1e-5)
        np.testing.assert_allclose(d["loss_p"], o["loss_p"], rtol=1e-5)


def test_nan_loss_stops_and_keeps_last_good_checkpoint(tmp_path):
    src, _ = _sources()

    def poisoned(step):
        b = src(step)
        return b._replace(images=np.full_like(b.images, np.nan)) if step >= 5 else b

    with pytest.raises(RhamlError, match=r"step 5: loss is nan.*last good checkpoint: .*/4"):
        train_amlnet(CFG, TC, tmp_path, poisoned, None, progress=False, num_devices=1, log=lambda s: None)
    net, params, _ = load_model(tmp_path)
    assert all(np.isfinite(np.asarray(p)).all() for p in jax.tree.leaves(params))


def test_resume_with_another_config_or_settings_fails(reference_run):
    out, _ = reference_run
    with pytest.raises(RhamlError, match="holds model config 'micro'"):
        train_amlnet(replace(CFG, name="micro2", dims=(8, 8)), TC, out, *_sources(), resume=True, progress=False)
    with pytest.raises(RhamlError, match="training settings differ"):
        train_amlnet(CFG, replace(TC, lr=0.5), out, *_sources(), resume=True, progress=False)
    with pytest.raises(RhamlError, match="w_xy"):
        train_amlnet(CFG, replace(TC, w_xy=(2.0, 1.0)), out, *_sources(), resume=True, progress=False)
    with pytest.raises(RhamlError, match="already holds a checkpoint"):
        train_amlnet(CFG, TC, out, *_sources(), progress=False)


def test_resume_accepts_a_checkpoint_from_before_a_new_setting(reference_run, tmp_path):
    """A setting added later (here w_xy) is absent from older checkpoints' metadata: it counts
    as its default, so such runs still resume."""
    import json
    import shutil

    out = tmp_path / "old"
    shutil.copytree(reference_run[0], out)
    metas = sorted(out.glob("checkpoints/*/meta/metadata"))
    assert metas
    for m in metas:
        meta = json.loads(m.read_text())
        del meta["train_config"]["w_xy"]
        m.write_text(json.dumps(meta))
    train_amlnet(CFG, TC, out, *_sources(), resume=True, progress=False, num_devices=1, log=lambda s: None)
    with pytest.raises(RhamlError, match="w_xy"):
        train_amlnet(CFG, replace(TC, w_xy=(3.0, 1.0)), out, *_sources(), resume=True, progress=False)


def test_bad_batches_are_named(tmp_path):
    src, _ = _sources()
    bad_size = lambda s: src(s)._replace(images=np.zeros((8, 24, 16, 3), np.float32))
    with pytest.raises(RhamlError, match=r"training batch at step 0.images: config micro takes 16 x 16"):
        train_amlnet(CFG, TC, tmp_path / "a", bad_size, None, progress=False)
    bad_dtype = lambda s: src(s)._replace(images=(src(s).images * 255).astype(np.uint8))
    with pytest.raises(RhamlError, match="dtype"):
        train_amlnet(CFG, TC, tmp_path / "b", bad_dtype, None, progress=False)
    bad_pose = lambda s: src(s)._replace(pose=np.zeros((8, 2), np.float32))
    with pytest.raises(RhamlError, match=r"pose: expected shape \(8, 3\)"):
        train_amlnet(CFG, TC, tmp_path / "c", bad_pose, None, progress=False)


def test_cli_errors(tmp_path):
    def run(*args):
        return subprocess.run([sys.executable, "-m", "rhaml_jax.train", *args], cwd=ROOT, capture_output=True, text=True,
                              env=_env(tmp_path))

    r = run("--stage", "amlnet", "--config", "nope", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "unknown model config 'nope'" in r.stderr and "Traceback" not in r.stderr
    r = run("--stage", "refiner", "--config", "cpu", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "refiner" in r.stderr
    r = run("--stage", "zoom", "--config", "tiny_zoom", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "needs --data" in r.stderr and "Traceback" not in r.stderr
    r = run("--stage", "zoom", "--config", "tiny", "--data", str(tmp_path), "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "not a zoom network" in r.stderr
    r = run("--stage", "amlnet", "--config", "tiny_zoom", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "use --stage zoom" in r.stderr
    if importlib.util.find_spec("rhaml_jax.data") is None:
        r = run("--stage", "amlnet", "--config", "cpu", "--out", str(tmp_path / "x"))
        assert r.returncode == 2 and "rhaml_jax.data" in r.stderr


def test_exported_weights_load_without_optimizer_state(reference_run, tmp_path):
    from rhaml_jax.amlnet.checkpoint import export_weights

    out, res = reference_run
    export_weights(out, tmp_path / "ship", extra_meta={"note": "test"})
    size = lambda d: sum(p.stat().st_size for p in Path(d).rglob("*") if p.is_file())  # noqa: E731
    assert size(tmp_path / "ship") < 0.6 * size(out / "checkpoints") / 2  # one step, no Adam moments
    net, params, stats = load_model(tmp_path / "ship")
    assert net.cfg == CFG
    for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(res["params"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_init_starts_from_the_given_weights(reference_run, tmp_path):
    """--init: a fine-tuning run starts at the checkpoint's weights (its first validation
    equals the checkpoint's), records where they came from, and refuses another model."""
    from rhaml_jax.amlnet.checkpoint import export_weights
    from rhaml_jax.amlnet.trainer import amlnet_task, initial_weights

    out, res = reference_run
    export_weights(out, tmp_path / "ship")
    params, stats = initial_weights(CFG, tmp_path / "ship")
    task, _ = amlnet_task(CFG, replace(TC, seed=99), num_devices=1, init=tmp_path / "ship")
    for a, b, c in zip(jax.tree.leaves(task.params), jax.tree.leaves(params), jax.tree.leaves(res["params"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))
    assert task.meta["initialised_from"] == str(tmp_path / "ship")
    fresh, _ = amlnet_task(CFG, replace(TC, seed=99), num_devices=1)
    assert any(not np.array_equal(np.asarray(a), np.asarray(b))
               for a, b in zip(jax.tree.leaves(fresh.params), jax.tree.leaves(task.params)))
    with pytest.raises(RhamlError, match=r"--init .*holds model config 'micro'.*not the 'tiny'"):
        initial_weights(get_config("tiny"), tmp_path / "ship")
    with pytest.raises(RhamlError, match=r"--init .*not a checkpoint folder"):
        initial_weights(CFG, tmp_path)


def test_checkpoints_store_the_robot_and_resume_refuses_another(tmp_path):
    from rhaml_jax.amlnet.checkpoint import checkpoint_robot
    from rhaml_jax.robots import RobotFingerprint

    pioneer = RobotFingerprint("pioneer3dx", (0.455, 0.381, 0.237), 1.011, "f1429b7d41f0e75c").to_dict()
    turtle = RobotFingerprint("turtlebot3_burger", (0.138, 0.178, 0.191), 0.295, "8866043173b6941b").to_dict()
    tc = replace(TC, steps=2, val_every=100)
    train_amlnet(CFG, tc, tmp_path, *_sources(tc), progress=False, num_devices=1, log=lambda s: None, robot=pioneer)
    assert checkpoint_robot(tmp_path) == pioneer
    with pytest.raises(RhamlError, match=r"--resume .*: this run trains robot 'pioneer3dx' .*not 'turtlebot3_burger'"):
        train_amlnet(CFG, replace(tc, steps=4), tmp_path, *_sources(tc), progress=False, num_devices=1,
                     log=lambda s: None, robot=turtle, resume=True)
