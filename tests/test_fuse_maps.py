"""`python -m rhaml_jax.fuse_maps` and `python -m rhaml_jax.explore`: placement, bad input, end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rhaml_jax.errors import run_cli
from rhaml_jax.mapping import read_map, random_field, transform_points, true_map, write_map


def _cli(module, argv, capsys):
    """Runs a command's main as the console script does: (exit status, stdout, stderr)."""
    try:
        run_cli(lambda: module.main(argv))
        code = 0
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A known world; A's map (knows x < 6 m) in the field's frame, B's (knows x > 4 m) made in a
    frame moved by a known transform T: B's map frame's pose in A's is T."""
    d = tmp_path_factory.mktemp("world")
    f = random_field(7)
    T = np.array([6.2, 5.1, 2.4])
    a = true_map(f, 0.05, supersample=1)
    b = true_map(f, 0.05, frame=T, supersample=1)
    ca = a.cell_centres()
    a = a.replace(occupancy=np.where(ca[..., 0] < 6.0, a.occupancy, np.nan))
    cb = transform_points(T, b.cell_centres())
    b = b.replace(occupancy=np.where(cb[..., 0] > 4.0, b.occupancy, np.nan))
    write_map(d / "a.yaml", a)
    write_map(d / "b.yaml", b)
    b10 = true_map(f, 0.1, frame=T, supersample=1)
    write_map(d / "b10.yaml", b10)
    return d, f, T


def _iou_vs_truth(m, field):
    """Occupied-cell IoU against the truth over the field and a 0.2 m band around it (outside the
    walls everything is occupied and would swamp the obstacles), after checking m knows it all."""
    c = m.cell_centres()
    x0, y0 = m.origin[0], m.origin[1]
    t = true_map(field, m.resolution, (0, 0, 0), (x0, y0, x0 + m.shape[1] * m.resolution, y0 + m.shape[0] * m.resolution),
                 supersample=1).occupied[: m.shape[0], : m.shape[1]]
    near = (c[..., 0] > -0.2) & (c[..., 0] < field.width + 0.2) & (c[..., 1] > -0.2) & (c[..., 1] < field.height + 0.2)
    in_field = (c[..., 0] > 0) & (c[..., 0] < field.width) & (c[..., 1] > 0) & (c[..., 1] < field.height)
    assert m.known[in_field].mean() > 0.99
    got = m.occupied & near & m.known
    return (got & t).sum() / (got | (t & near & m.known)).sum()


def test_transform_places_b_exactly(world, capsys, tmp_path):
    from rhaml_jax import fuse_maps

    d, field, T = world
    code, out, err = _cli(fuse_maps, ["--map-a", str(d / "a.yaml"), "--map-b", str(d / "b.yaml"), "--transform",
                                      ",".join(map(str, T)), "--out", str(tmp_path / "m.yaml")], capsys)
    assert code == 0, err
    res = json.loads(out)
    assert res["overlap_cells"] > 0 and (tmp_path / "m.png").stat().st_size > 1000
    m = read_map(tmp_path / "m.yaml")
    assert _iou_vs_truth(m, field) >= 0.9
    # B's map alone placed by a transform off by 0.3 m would not pass: the check can fail
    code, out, err = _cli(fuse_maps, ["--map-a", str(d / "a.yaml"), "--map-b", str(d / "b.yaml"), "--transform",
                                      f"{T[0] + 0.3},{T[1]},{T[2]}", "--out", str(tmp_path / "w.yaml")], capsys)
    assert _iou_vs_truth(read_map(tmp_path / "w.yaml"), field) < 0.8


def test_different_resolutions_are_resampled_and_said(world, capsys, tmp_path):
    from rhaml_jax import fuse_maps

    d, field, T = world
    code, out, err = _cli(fuse_maps, ["--map-a", str(d / "a.yaml"), "--map-b", str(d / "b10.yaml"), "--transform",
                                      ",".join(map(str, T)), "--out", str(tmp_path / "m.yaml")], capsys)
    assert code == 0
    assert "resolution 0.1 m" in err and "resampled to 0.05 m" in err
    assert read_map(tmp_path / "m.yaml").resolution == 0.05


def test_no_overlap_is_said_and_the_union_written(world, capsys, tmp_path):
    from rhaml_jax import fuse_maps

    d, _, _ = world
    code, out, err = _cli(fuse_maps, ["--map-a", str(d / "a.yaml"), "--map-b", str(d / "b.yaml"), "--transform",
                                      "-40,0,0", "--out", str(tmp_path / "m.yaml")], capsys)
    assert code == 0 and "do not overlap" in err
    assert json.loads(out)["overlap_cells"] == 0
    m = read_map(tmp_path / "m.yaml")
    a = read_map(d / "a.yaml")
    assert m.known.sum() > a.known.sum()  # B is in it too


@pytest.mark.parametrize("case,message", [
    ("missing_image", "points to"), ("no_resolution", "'resolution' is missing"), ("no_origin", "'origin' is missing"),
    ("bad_transform", "expected three"), ("both", "exactly one of"),
])
def test_bad_input_one_line_exit_2(world, capsys, tmp_path, case, message):
    from rhaml_jax import fuse_maps

    d, _, _ = world
    text = (d / "b.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    if case == "missing_image":
        bad.write_text(text.replace("image: b.pgm", "image: gone.pgm"))
    elif case == "no_resolution":
        bad.write_text("\n".join(l for l in text.splitlines() if not l.startswith("resolution")))
    elif case == "no_origin":
        bad.write_text("\n".join(l for l in text.splitlines() if not l.startswith("origin")))
    else:
        bad = d / "b.yaml"
    argv = ["--map-a", str(d / "a.yaml"), "--map-b", str(bad), "--out", str(tmp_path / "m.yaml"),
            "--transform", "1,2" if case == "bad_transform" else "1,2,0.5"]
    if case == "both":
        argv += ["--sequence", str(tmp_path)]
    code, out, err = _cli(fuse_maps, argv, capsys)
    assert code == 2 and message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "m.yaml").exists()


def test_sequence_without_rendezvous_frames(world, capsys, tmp_path):
    """A sequence in which no image shows the other robot: exit 2, nothing written."""
    from rhaml_jax import fuse_maps
    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import write_sequence

    d, _, _ = world
    n = 3
    a = np.stack([np.linspace(1, 2, n), np.full(n, 1.0), np.zeros(n)], 1)
    b = np.stack([np.linspace(5, 6, n), np.full(n, 3.0), np.zeros(n)], 1)  # both face +x: B never sees A...
    b[:, 1] = 5.0  # ... and A looks past B (far to the side)
    a[:, 2] = -1.2
    write_sequence(tmp_path / "seq", [(0, a, b, a, b), (1, b, a, b, a)], (0, 10, 0, 7), "pioneer3dx",
                   DEFAULT_CAMERA.resized(80, 60), 0, workers=1)
    code, out, err = _cli(fuse_maps, ["--map-a", str(d / "a.yaml"), "--map-b", str(d / "b.yaml"), "--sequence",
                                      str(tmp_path / "seq"), "--observations", "truth", "--out",
                                      str(tmp_path / "m.yaml")], capsys)
    assert code == 2 and "no rendezvous frames" in err
    assert not (tmp_path / "m.yaml").exists()


def test_explore_end_to_end_tiny(capsys, tmp_path):
    """The whole application at a tiny size (short exploration, small images, truth + noise
    observations): the maps, the sequence, the merged map, and A_0 T B_0 close to the truth."""
    from rhaml_jax import explore, fuse_maps

    code, out, err = _cli(explore, ["--out", str(tmp_path), "--seed", "1", "--explore-steps", "60", "--observations",
                                    "truth", "--image-width", "160", "--image-height", "120"], capsys)
    assert code == 0, err
    s = json.loads(out.strip().splitlines()[-1])
    for f in ("map_a.yaml", "map_b.yaml", "merged.yaml", "merged.pgm", "merged.png", "trajectory_a.txt",
              "sequence/test/000000/scene_gt.json", "sequence/test/000001/observer_odometry.txt"):
        assert (tmp_path / f).exists(), f
    assert s["observations_used"] >= 5
    assert s["translation_error_cm"] < 25 and s["rotation_error_deg"] < 3
    assert s["merged"]["iou"] > 0.4
    # fuse_maps --sequence on what explore wrote gives the same transform
    code, out, err = _cli(fuse_maps, ["--map-a", str(tmp_path / "map_a.yaml"), "--map-b", str(tmp_path / "map_b.yaml"),
                                      "--sequence", str(tmp_path / "sequence"), "--observations", "truth", "--seed", "1",
                                      "--out", str(tmp_path / "again.yaml")], capsys)
    assert code == 0, err
    np.testing.assert_allclose(json.loads(out)["a0_T_b0"], s["a0_T_b0"], atol=1e-6)
