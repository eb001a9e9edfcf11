"""experiments/compare_validation.py, the rule the defaults are chosen by: its bootstrap on
synthetic per-frame errors (no networks)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def _cv():
    sys.path.insert(0, str(EXPERIMENTS))
    spec = importlib.util.spec_from_file_location("compare_validation", EXPERIMENTS / "compare_validation.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _looks(rng, scales):
    """Look -> sequences of per-frame squared errors, each sequence at its own scale."""
    return {"ours": [rng.gamma(2.0, s, size=200) for s in scales[:3]], "ood": [rng.gamma(2.0, s, size=150) for s in scales[3:]]}


def test_a_uniform_gain_is_better_and_an_identical_run_level():
    cv = _cv()
    a = _looks(np.random.default_rng(0), [1e-3, 4e-3, 1e-2, 0.5, 1.0])
    half = {k: [0.25 * q for q in v] for k, v in a.items()}  # every error halved: RMS ratio 0.5
    r = cv.compare(a, half, block=25, draws=300, seed=0)
    assert r["verdict"] == "better" and abs(r["ratio"] - 0.5) < 1e-9 and r["ratio_95"][1] < 1
    assert cv.compare(a, a, 25, 300, 0)["verdict"] == "level"
    worse = {k: [4.0 * q for q in v] for k, v in a.items()}
    assert cv.compare(a, worse, 25, 300, 0)["verdict"] == "worse"


def test_one_sequence_gaining_much_while_the_others_lose_is_level():
    """The case the rule was made for: the pooled RMS is dominated by the sequence that gained,
    but the sequences disagree, so the interval straddles 1."""
    cv = _cv()
    rng = np.random.default_rng(1)
    a = _looks(rng, [1e-3, 1e-3, 1e-3, 1e-3, 1.0])
    b = {"ours": [1.6 * q for q in a["ours"]], "ood": [a["ood"][0] * 1.6, a["ood"][1] * 0.2]}
    r = cv.compare(a, b, 25, 500, 0)
    assert r["rms_b"] < r["rms_a"]  # pooled: "better"
    assert r["verdict"] == "level", r


def test_blocks_cover_the_sequence_and_stay_inside_it():
    cv = _cv()
    rng = np.random.default_rng(2)
    for n, block in ((200, 25), (7, 25), (101, 10)):
        i = cv.block_indices(rng, n, block)
        assert len(i) == n and i.min() >= 0 and i.max() < n


def test_an_extra_sequence_must_name_a_look(tmp_path, monkeypatch, capsys):
    """`--extra LOOK SET` must name a look, and `--metric-b` a pose-graph metric and a JSON value:
    otherwise one clear line, exit status 2, as for a label whose runs are missing (the file it
    looked for named)."""
    import pytest

    cv = _cv()
    for argv, msg in ((["a", "b", "--extra", "nope", "val_x/circle"], "no look 'nope'"),
                      (["a", "b", "--looks", "ood", "--extra", "ood", "val_x/circle", "--ev", str(tmp_path)], "a_val_ood_circle.json: not found"),
                      (["a", "a", "--metric-b", "range_window_max_scale", "two"], "the value is not JSON"),
                      (["a", "a", "--metric-b", "range_windw", "null"], "not a pose-graph metric")):
        monkeypatch.setattr(sys, "argv", ["compare_validation.py", *argv])
        with pytest.raises(SystemExit) as e:
            cv.main()
        assert e.value.code == 2 and msg in capsys.readouterr().err


def test_the_second_look_counts_in_iml_ir_pgo_only():
    """pipeline_from_json.detections / second_look: a frame the graph's second look joined
    (`evaluate --track-iou`) is detected for IML+IR+PGO only (the other rows' pipelines have no
    second look); `--metric track_iou T` above the run's keeps only the joined frames whose mask IoU
    reaches T, and frames it did not join never count."""
    _cv()  # puts experiments/ on the path
    import pipeline_from_json as pj

    rows = [{"detected": True}, {"detected": True, "second_look": {"joined": True, "mask_iou": 0.6, "est": [3, 0, 0], "flip_prob": 0.1}},
            {"detected": True, "second_look": {"joined": True, "mask_iou": 0.9, "est": [3, 0, 0], "flip_prob": 0.1}},
            {"detected": False, "second_look": {"joined": False, "mask_iou": 0.95, "est": [3, 0, 0], "flip_prob": 0.1}},
            {"detected": False}]
    first, both = pj.detections(rows)
    np.testing.assert_array_equal(first, [True, False, False, False, False])
    np.testing.assert_array_equal(both, [True, True, True, False, False])
    np.testing.assert_array_equal(pj.detections(rows, {"track_iou": 0.7})[1], [True, False, True, False, False])
    np.testing.assert_array_equal(pj.second_look(rows, {"track_iou": 0.3}), [False, True, True, False, False])
