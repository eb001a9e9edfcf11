"""The main job (README's first command, `python -m rhaml_jax.demo`) end to end at a few frames:
it generates both scenarios, runs the four module combinations with the shipped networks and
writes its table, results.json and both figures. Measured at 6 frames per scenario: IML ATE
0.14, IML+IR+PGO 0.05, every robot detected."""

from __future__ import annotations

import json

import numpy as np


def test_demo_runs_every_combination_with_the_shipped_networks(tmp_path, capsys):
    from rhaml_jax.demo import COMBINATIONS, main

    res = main(["--out", str(tmp_path), "--frames", "6", "--workers", "1"])
    assert json.loads((tmp_path / "results.json").read_text())["rows"].keys() == res["rows"].keys()
    assert set(res["rows"]) == {",".join(m) for m in COMBINATIONS}
    for key, row in res["rows"].items():
        assert "skipped" not in row, (key, row)
        assert row["detection"]["tp"] == 12 and np.isfinite(row["ate"]), (key, row)
    # the shipped networks, not a stand-in: ranges of a working pipeline, far from a blind guess's
    assert res["rows"]["iml"]["ate"] < 0.5 and res["rows"]["iml,ir,pgo"]["ate"] < 0.2, res["rows"]
    assert all((tmp_path / name).stat().st_size > 10_000 for name in ("fig6_trajectories.png", "fig5_violin.png"))
    assert "IML+IR+PGO" in capsys.readouterr().out  # the Table III layout printed
