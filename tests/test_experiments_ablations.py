"""The paper's ablation scripts at tiny size, so that they keep working: Table II
(experiments/table_ii.py: trains, evaluates, resumes, summarises the seed spread) and the
end-to-end differentiable fine-tuning (experiments/e2e_finetune.py)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import write_training_set
from rhaml_jax.data._writer import write_scenario

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def _script(name: str):
    sys.path.insert(0, str(EXPERIMENTS))
    spec = importlib.util.spec_from_file_location(name, EXPERIMENTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("paper")
    cam = DEFAULT_CAMERA.resized(160, 120)
    write_training_set(root / "train", "pioneer3dx", cam, seed=1, num=20, negatives=4, workers=1)
    for name in ("circle", "sine"):
        write_scenario(root / "ours" / name, name, "pioneer3dx", cam, seed=0, frames=4, workers=1)
    for seed in (3, 4):
        write_scenario(root / f"rv{seed}", "rendezvous", "pioneer3dx", cam, seed=seed, frames=40, workers=1)
    return root


def test_table_ii_trains_evaluates_and_resumes(tiny):
    t2 = _script("table_ii")
    out = tiny / "t2" / "table_ii.json"
    argv = ["--data", str(tiny / "train"), "--ours", str(tiny / "ours"), "--runs", str(tiny / "t2runs"), "--out", str(out),
            "--configs", "tiny", "--seeds", "0", "--steps", "2", "--batch", "4", "--frames", "4",
            "--train-args", "--val-batches", "1", "--log-every", "1"]
    res = t2.main(argv)
    assert [(r["config"], r["K"]) for r in res["rows"]] == [("tiny", "{3,5,7}")]
    for r in res["rows"]:
        assert r["params"] > 0 and r["val"]["step"] == 2
        for col in ("ours/amlnet", "ours/amlnet+zoom"):
            assert r[col]["frames"] == 8 and np.isfinite(r[col]["dx_cm"][0])
    assert out.with_suffix(".png").stat().st_size > 0
    assert json.loads(out.read_text())["rows"] == res["rows"]
    # a second call keeps the evaluated runs: nothing is trained again
    stamp = {p: p.stat().st_mtime for p in (tiny / "t2runs").rglob("metrics.jsonl")}
    again = t2.main(argv)
    assert again["rows"] == res["rows"]
    assert {p: p.stat().st_mtime for p in stamp} == stamp


def test_table_ii_labels_and_seed_spread():
    t2 = _script("table_ii")
    assert [t2.kernel_label(c) for c in t2.SCALES["cpu"]] == ["{} (plain 3x3)", "{3}", "{3,5}", "{3,5,7}"]
    m = lambda dx, ate: {"dx_cm": [dx, 1.0], "dy_cm": [2.0, 1.0], "dpsi_deg": [3.0, 1.0], "ate": ate, "flips": 0}  # noqa: E731
    rows = [{"K": "{3}", "seed": s, "ours/amlnet": m(dx, ate)} for s, dx, ate in ((0, 10.0, 0.5), (1, 14.0, 0.3))]
    (row,) = t2.summarize(rows)
    assert row["K"] == "{3}" and row["seeds"] == 2
    assert row["dx_cm"] == [12.0, 4.0] and row["ate"] == pytest.approx([0.4, 0.2])


def test_e2e_windows_are_pure_and_observed(tiny):
    e2e = _script("e2e_finetune")
    seqs = e2e.load_sequences([tiny / "rv3", tiny / "rv4"], 2)
    a, b = e2e.window(seqs, 2, 0, 5), e2e.window(seqs, 2, 0, 5)
    np.testing.assert_array_equal(a[0].images, b[0].images)
    assert a[2].all() and a[0].images.shape[0] == 2
    t = [e2e.window(seqs, 2, 0, k)[0].odom_b for k in range(6)]
    assert any(not np.array_equal(t[0], x) for x in t[1:])  # steps draw different windows


def test_e2e_finetune_runs_and_resumes(tiny):
    e2e = _script("e2e_finetune")
    runs, out = tiny / "e2e", tiny / "e2e" / "e2e.json"
    argv = ["--train", str(tiny / "rv3"), "--val", str(tiny / "rv4"), "--ours", str(tiny / "ours"), "--runs", str(runs),
            "--out", str(out), "--through", "iml,pgo", "--steps", "2", "--window", "2", "--ckpt-every", "1",
            "--alone-steps", "1", "--frames", "4", "--train-args", "--log-every", "1"]
    res = e2e.main(argv)
    log = [json.loads(s) for s in (runs / "e2e" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2] and all(np.isfinite(r["loss"]) for r in log)
    for name in ("shipped", "alone", "e2e"):
        for stage in ("iml", "ir", "fused"):
            assert np.isfinite(res["eval"][name]["ours"][stage]["dx_cm"][0])
    assert out.with_suffix(".png").stat().st_size > 0 and set(np.load(out.with_suffix(".npz")).files) == {
        f"{n}/ours/{st}" for n in ("shipped", "alone", "e2e") for st in ("iml", "ir", "fused")}
    assert set(res["change_vs_shipped"]) == {f"{n}/ours/{st}" for n in ("alone", "e2e") for st in ("iml", "ir", "fused")}
    # the fine-tuned stage moved, and evaluate reads it as a zoom-in stage checkpoint
    assert res["eval"]["e2e"]["ours"]["iml"] != res["eval"]["shipped"]["ours"]["iml"]
    # a step logged after the last checkpoint (a killed run) is done again on resume, its line replaced
    with (runs / "e2e" / "metrics.jsonl").open("a") as fh:
        fh.write(json.dumps({"step": 3, "loss": -1.0}) + "\n")
    with_steps = lambda *kv: e2e.parse([*argv[: argv.index("--steps")], *kv, *argv[argv.index("--steps") + 2:]])  # noqa: E731
    assert e2e.train_e2e(with_steps("--steps", "3"), runs / "e2e")["steps"] == 3
    log = [json.loads(s) for s in (runs / "e2e" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3] and log[-1]["loss"] >= 0
    # other settings than the stored run's are refused before anything changes
    with pytest.raises(SystemExit, match="other settings"):
        e2e.train_e2e(with_steps("--steps", "3", "--lr", "0.5"), runs / "e2e")
