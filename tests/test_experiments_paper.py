"""experiments/table_i.py, table_iii.py, fig5_violin.py and fig6_trajectories.py at tiny size: a 13-image
training set, 6-frame circle and sine scenarios (ours and the held-out look, the built-in robot so
the shipped networks' fingerprint checks pass), tiny_frontnet trained 2 steps, 4 frames per
scenario; every row and set in the JSON, finite metrics where the robot was detected, the
per-frame .npz, both figures."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import HeldoutConfig, write_scenario, write_training_set

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import fig5_violin  # noqa: E402
import fig6_trajectories  # noqa: E402
import table_i  # noqa: E402

CAM = DEFAULT_CAMERA.resized(160, 120)


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    root = tmp_path_factory.mktemp("paper")
    write_training_set(root / "train", "pioneer3dx", CAM, seed=3, num=10, negatives=3, workers=1)
    for set_name, look in (("ours", None), ("heldout", HeldoutConfig())):
        for sc in ("circle", "sine"):
            write_scenario(root / set_name / sc, sc, "pioneer3dx", CAM, seed=0, frames=6, workers=1, heldout=look)
    out = root / "res" / "table_i.json"
    res = table_i.main(["--data", str(root / "train"), "--ours", str(root / "ours"), "--heldout", str(root / "heldout"),
                        "--runs", str(root / "runs"), "--out", str(out), "--steps", "2", "--batch", "4", "--frames", "4",
                        "--frontnet-config", "tiny_frontnet", "--train-args", "--val-batches", "1"])
    return out, res


def test_table_i_json_and_npz(table):
    out, res = table
    assert json.loads(out.read_text()) == json.loads(json.dumps(res))
    assert list(res["rows"]) == list(table_i.ROWS)
    assert "tiny_frontnet" in res["frontnet_training"]["command"] and res["frontnet_training"]["curve"]
    z = np.load(out.with_suffix(".npz"))
    assert all(z[f"truth/{s}/{sc}"].shape == (4, 3) for s in ("ours", "heldout") for sc in ("circle", "sine"))
    for key, row in res["rows"].items():
        assert row["params"] > 0 and row["macs"] > 0
        for s in ("ours", "heldout"):
            m = row[s]
            assert m["frames"] == 8 and m["observed_frames"] == 8  # 4 of each scenario, the robot always in view
            est, gt, scen = (z[f"{key}/{s}/{f}"] for f in ("est", "gt", "scenario"))
            assert est.shape == gt.shape == (m["detection"]["tp"], 3) and scen.shape == (len(est),)
            assert set(scen) <= {"circle", "sine"}
            if m["detection"]["tp"]:
                assert np.isfinite(est).all()
                assert all(math.isfinite(v) for k in ("dx_cm", "dy_cm", "dpsi_deg") for v in m[k])
                assert math.isfinite(m["ate"]) and m["fps"] > 0
    # RHAML's size is IML's plus the IR cascade's: the refiner's four iterations, the fine ensemble's
    # two members' iterations, each read twice (the default mirrors the fine iterations of this robot),
    # the front/back scorer's two hypotheses and the segmenter's one mask
    from rhaml_jax.refine import DEFAULT_MIRROR, RefineConfig

    r, ir = res["rows"], table_i.refiner_size()
    k = RefineConfig().fine_iter * (2 if DEFAULT_MIRROR != "none" else 1)
    assert [n.split(" (")[0] for n in ir["networks"]] == ["refiner_paint_cpu x 4", f"refiner_fine_paint_cpu x {k}",
                                                         f"refiner_fine_native_cpu x {k}", "scorer_flip_wide_cpu x 2",
                                                         "segmenter_fine_cpu x 1"]
    assert r["rhaml"]["params"] == r["iml"]["params"] + ir["params"] and r["rhaml"]["macs"] == r["iml"]["macs"] + ir["macs"]
    assert r["rhaml"]["params"] > r["iml"]["params"] > r["amlnet"]["params"]
    assert r["rhaml"]["macs"] > r["iml"]["macs"] > r["amlnet"]["macs"]


def test_figures(table):
    out, _ = table
    npz = out.with_suffix(".npz")
    q = fig5_violin.main(["--npz", str(npz), "--out", str(out.parent / "fig5.png"), "--rows", "frontnet", "rhaml"])
    assert (out.parent / "fig5.png").stat().st_size > 0
    assert json.loads((out.parent / "fig5.json").read_text()) == json.loads(json.dumps(q))
    for s in ("ours", "heldout"):
        qs = q["quantiles"]["rhaml"][s]
        if qs["n"]:
            assert all(qs[d]["p5"] <= qs[d]["median"] <= qs[d]["p95"] for d in ("dx", "dy", "dpsi"))
    png = fig6_trajectories.main(["--npz", str(npz), "--out", str(out.parent / "fig6.png")])
    assert png.stat().st_size > 0


def test_signed_errors_wrap_psi():
    e = fig5_violin.signed_errors(np.array([[1.0, 2.0, 3.1]]), np.array([[0.9, 2.05, -3.1]]))
    np.testing.assert_allclose(e, [[10.0, -5.0, np.degrees(6.2 - 2 * np.pi)]], atol=1e-9)


def test_stage_diagnostics(table, tmp_path):
    """experiments/stage_diagnostics.py: AMLNet alone and the zoom stage on oracle crops, one
    row per (network, data set), fractions in [0, 1], every frame with the robot in view."""
    import stage_diagnostics

    from rhaml_jax.amlnet import shipped_checkpoint

    out, _ = table
    ours = out.parents[1] / "ours"
    res = tmp_path / "diag.json"
    d = stage_diagnostics.main(["--amlnet", str(shipped_checkpoint("amlnet_cpu")), "--zoom", str(shipped_checkpoint("zoom_cpu")),
                                "--data", str(ours / "circle"), str(ours / "sine"), "--frames", "4", "--out", str(res)])
    assert json.loads(res.read_text()) == d
    assert [r["data"] for r in d["amlnet_alone"]] == [str(ours / "circle"), str(ours / "sine")]
    for r in d["amlnet_alone"]:
        assert r["n"] == 4 and math.isfinite(r["median_bearing_deg"]) and r["median_range_ratio"] > 0
        assert all(0 <= r[k] <= 1 for k in ("bearing_within_5deg", "range_within_12pct", "detected"))
    for r in d["zoom_oracle"]:
        assert r["n"] == 4 and 0 <= r["flips"] <= 1 and 0 <= r["median_dpsi_deg"] <= 180
        assert r["dx_cm"] >= 0 and r["median_range_ratio"] > 0


def test_table_iii_names_the_cascade(table):
    """experiments/table_iii.py with the shipped cascade named (--refiner, --fine-refiner,
    --segmenter) gives Table I's RHAML row (the same networks on the same frames; table_iii names
    no scorer, and the default stage's scorer keeps every heading of these frames, so the two
    compiled programs differ and their rows agree to rounding: IR maps single frames, whose
    floats XLA rounds per program), for both information models; without the fine refiner it
    gives another."""
    import table_iii

    from rhaml_jax.amlnet import shipped_checkpoint
    from rhaml_jax.refine import DEFAULT_FINE_REFINERS, DEFAULT_REFINER, DEFAULT_SEGMENTER

    out, res = table
    args = ["--ours", str(out.parents[1] / "ours"), "--frames", "4", "--combos", "iml,ir,pgo", "--out", str(out.parent / "t3.json"),
            "--refiner", str(shipped_checkpoint(DEFAULT_REFINER)), "--segmenter", str(shipped_checkpoint(DEFAULT_SEGMENTER))]
    fines = ["--fine-refiner", *(str(shipped_checkpoint(n)) for n in DEFAULT_FINE_REFINERS)]
    cascade = table_iii.main([*args, *fines])
    assert [r["information"] for r in cascade["rows"]] == ["noise_model", "paper"]
    assert json.loads((out.parent / "t3.json").read_text()) == json.loads(json.dumps(cascade))
    row = cascade["rows"][0]
    ref = res["rows"]["rhaml"]["ours"]
    assert row["detection"] == ref["detection"]
    for k in ("dx_cm", "dy_cm", "dpsi_deg", "ate"):
        np.testing.assert_allclose(row[k], ref[k], rtol=2e-3, err_msg=k)
    assert row["detection"]["tp"] == 8  # IR ran on every frame
    ir = [table_iii.main([*args, *more, "--combos", "iml,ir"])["rows"][0]["dx_cm"]
          for more in (fines, [])]
    assert ir[0] != ir[1]  # the fine refiner ran in the first only
