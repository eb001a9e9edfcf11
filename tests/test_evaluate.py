"""`python -m rhaml_jax.evaluate`: per-frame estimates equal a direct network call, metrics
equal `metrics.summarize` of them, the JSON layout of DESIGN.md section 5, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rhaml_jax import metrics
from rhaml_jax.amlnet import decode, get_config, load_model
from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import load_rgb, network_image, read_bop
from rhaml_jax.data import write_training_set
from rhaml_jax.errors import RhamlError
from rhaml_jax.evaluate import main
from tests.conftest import random_checkpoint


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    write_training_set(root / "set", "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=3, num=10, negatives=3, workers=1)
    random_checkpoint(root / "ckpt", "micro")
    return root


def test_estimates_and_metrics_match_a_direct_call(setup):
    out = setup / "eval.json"
    main(["--data", str(setup / "set"), "--amlnet", str(setup / "ckpt"), "--json", str(out), "--batch", "4",
          "--modules", "iml"])
    res = json.loads(out.read_text())
    frames = read_bop(setup / "set")
    assert [(f["scene_id"], f["im_id"]) for f in res["frames"]] == [(f.scene_id, f.im_id) for f in frames]
    net, params, stats = load_model(setup / "ckpt")
    imgs = np.stack([network_image(load_rgb(f.rgb), f.K, net.cfg.input_hw) for f in frames]).astype(np.float32) / 255
    d = {k: np.asarray(v) for k, v in decode(net.apply(params, stats, imgs), net.cfg.angle_head).items()}
    est = np.stack([d["x"], d["y"], d["psi"]], 1)
    det = d["o"] >= 0.5
    obs = np.array([f.observed for f in frames])
    for row, e, dd, f in zip(res["frames"], est, det, frames):
        assert row["observed"] == f.observed
        assert (row["est"] is None) == (not dd)
        if dd:
            np.testing.assert_allclose(row["est"], e, atol=1e-5)
        assert (row["gt"] is None) == (not f.observed)
    gt = np.array([f.xypsi for f in frames if f.observed])
    ref = metrics.summarize(est[obs], gt)
    m = res["metrics"]
    for k in ("dx_cm", "dy_cm", "dpsi_deg"):
        np.testing.assert_allclose(m[k], ref[k], rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(m["ate"], ref["ate"], rtol=1e-4)
    assert m["detection"] == {"tp": int((det & obs).sum()), "fp": int((det & ~obs).sum()),
                              "fn": int((~det & obs).sum()), "tn": int((~det & ~obs).sum())}
    assert m["frames"] == len(frames) and m["fps"] > 0
    seen = det & obs
    gt_seen = np.array([f.xypsi for f, s in zip(frames, seen) if s]).reshape(-1, 3)
    assert m["iml_flips_by_view"] == metrics.flips_by_view(est[seen, 2], gt_seen)
    assert sum(n for _, n in m["iml_flips_by_view"].values()) == int(seen.sum())


def test_bad_input(setup, tmp_path):
    with pytest.raises(RhamlError, match="--modules iml,nope"):
        main(["--data", str(setup / "set"), "--modules", "iml,nope", "--amlnet", str(setup / "ckpt")])
    with pytest.raises(RhamlError, match="data set folder not found"):
        main(["--data", str(tmp_path / "none"), "--amlnet", str(setup / "ckpt")])
    with pytest.raises(RhamlError, match="no Orbax checkpoints"):
        main(["--data", str(setup / "set"), "--amlnet", str(tmp_path)])
    with pytest.raises(RhamlError, match="scene 99 not found"):
        main(["--data", str(setup / "set"), "--scene", "99", "--amlnet", str(setup / "ckpt")])


def test_a_scene_without_its_camera_file(setup, tmp_path):
    import shutil

    shutil.copytree(setup / "set", tmp_path / "set")
    cam = next((tmp_path / "set").rglob("scene_camera.json"))
    cam.unlink()
    with pytest.raises(RhamlError, match=r"scene_camera.json: file not found"):
        main(["--data", str(tmp_path / "set"), "--amlnet", str(setup / "ckpt"), "--modules", "iml"])


def test_networks_made_for_another_robot(setup, tmp_path):
    """A zoom stage sized for a 90 cm robot on the 46 cm Pioneer's data set: refused, naming both."""
    from dataclasses import replace

    random_checkpoint(tmp_path / "zoom", replace(get_config("tiny_zoom"), zoom_length_m=0.9), seed=1)
    with pytest.raises(RhamlError, match=r"obj_000001.ply: this robot is 4\d cm long, but the networks "
                                         r"were made for a 90 cm robot"):
        main(["--data", str(setup / "set"), "--amlnet", str(setup / "ckpt"), "--zoom", str(tmp_path / "zoom"),
              "--modules", "iml"])


def test_fingerprint_of_another_robot_is_refused_unless_allowed(setup, tmp_path):
    """A checkpoint that stores the TurtleBot-sized robot's fingerprint, on the Pioneer's data set:
    refused naming both robots; --allow-other-robot runs it anyway."""
    from rhaml_jax.robots import RobotFingerprint

    other = RobotFingerprint("turtlebot3_burger", (0.138, 0.178, 0.191), 0.295, "8866043173b6941b")
    random_checkpoint(tmp_path / "other", "micro", robot=other.to_dict())
    args = ["--data", str(setup / "set"), "--amlnet", str(tmp_path / "other"), "--modules", "iml"]
    with pytest.raises(RhamlError, match=r"AMLNet checkpoint .* was made for robot 'turtlebot3_burger' \(13.8 x 17.8 x "
                                         r"19.1 cm.*but .*obj_000001.ply is robot 'obj_000001' \(45.5 x 38.1"):
        main(args)
    assert main(args + ["--allow-other-robot"])["metrics"]["frames"] == 13


def test_pgo_metrics_match_its_own_per_frame_json(setup, tmp_path):
    """With the pose graph: every frame carries a fused estimate; the metrics are
    `metrics.summarize` of the observed rows, the rejected count is the rows' own."""
    from rhaml_jax.data import write_scenario

    write_scenario(tmp_path / "circle", "circle", "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=0,
                   frames=16, workers=1)
    out = tmp_path / "eval.json"
    main(["--data", str(tmp_path / "circle"), "--amlnet", str(setup / "ckpt"), "--json", str(out),
          "--modules", "iml,pgo"])
    res = json.loads(out.read_text())
    rows, m = res["frames"], res["metrics"]
    assert len(rows) == 16 and all(r["est"] is not None for r in rows)
    obs = [r for r in rows if r["observed"]]
    ref = metrics.summarize(np.array([r["est"] for r in obs]), np.array([r["gt"] for r in obs]))
    for k in ("dx_cm", "dy_cm", "dpsi_deg"):
        np.testing.assert_allclose(m[k], ref[k], rtol=1e-5)
    np.testing.assert_allclose(m["ate"], ref["ate"], rtol=1e-4)
    assert m["pgo_rejected"] == sum(r["detected"] and not r["pgo_inlier"] for r in rows)
    assert m["modules"] == ["iml", "pgo"] and m["pgo_mode"] == "batch" and m["information"] == "noise_model"
    assert len(m["range_model"]) == 1 and len(m["range_model"][0]) == 2  # one scene: its range model's c


def test_the_convergence_check_option_follows_the_library():
    """`--max-final-step` defaults to `RefineConfig`'s and turns off with None."""
    import tyro

    from rhaml_jax.evaluate import Args
    from rhaml_jax.refine import RefineConfig

    assert tyro.cli(Args, args=["--data", "x"]).max_final_step == RefineConfig().max_final_step
    assert tyro.cli(Args, args=["--data", "x", "--max-final-step", "None"]).max_final_step is None
    assert tyro.cli(Args, args=["--data", "x", "--max-final-step", "0.02"]).max_final_step == 0.02
    assert tyro.cli(Args, args=["--data", "x"]).fine_iter is None  # the library's RefineConfig.fine_iter
    assert tyro.cli(Args, args=["--data", "x", "--fine-iter", "2"]).fine_iter == 2
