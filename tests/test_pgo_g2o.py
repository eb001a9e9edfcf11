"""g2o reading/writing, bad-input errors (file:line, missing vertex, disconnected graph,
non-PD information, NaN) and the `python -m rhaml_jax.pgo` command."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from rhaml_jax.errors import RhamlError
from rhaml_jax.pgo import graph_cost, parse_g2o, read_g2o, validate_graph, write_g2o
from tests.conftest import shared_path

REPO = Path(__file__).resolve().parents[1]
TOY = """# a square with one loop closure
VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.1 0 1.6
VERTEX_SE2 2 1 1.05 3.1
VERTEX_SE2 3 0 0.9 -1.5
EDGE_SE2 0 1 1 0 1.5707963 100 0 0 100 0 400
EDGE_SE2 1 2 1 0 1.5707963 100 0 0 100 0 400
EDGE_SE2 2 3 1 0 1.5707963 100 0 0 100 0 400
EDGE_SE2 3 0 1 0 1.5707963 100 0 0 100 0 400
"""


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


def test_round_trip_keeps_everything(tmp_path):
    g = parse_g2o(TOY, "toy")
    write_g2o(tmp_path / "toy.g2o", g)
    h = read_g2o(tmp_path / "toy.g2o")
    for a, b in zip(g[:5], h[:5]):
        np.testing.assert_array_equal(a, b)
    assert g.fixed == h.fixed == 0


def test_upper_triangle_order_and_unwrapped_angles():
    g = parse_g2o("VERTEX_SE2 5 0 0 7.0\nVERTEX_SE2 9 1 0 0\nEDGE_SE2 5 9 1 0 0 1 2 3 14 5 26\n")
    np.testing.assert_array_equal(g.information[0], [[1, 2, 3], [2, 14, 5], [3, 5, 26]])
    np.testing.assert_array_equal(g.ids, [5, 9])
    assert g.poses[0, 2] == 7.0  # kept as given; the solver works with cos/sin


def test_vertexless_file_gets_chained_guess():
    g = parse_g2o("EDGE_SE2 0 1 1 0 1.5707963267948966 1 0 0 1 0 1\nEDGE_SE2 2 1 1 0 0 1 0 0 1 0 1\n")
    np.testing.assert_allclose(g.poses[1], [1, 0, np.pi / 2], atol=1e-12)
    # x_1 = x_2 z  =>  x_2 = x_1 z^-1: one metre behind x_1 along its heading
    np.testing.assert_allclose(g.poses[2], [1, -1, np.pi / 2], atol=1e-12)
    assert graph_cost(g) == pytest.approx(0.0, abs=1e-20)


def test_csail_chained_initial_cost_matches_reference():
    g = read_g2o(shared_path("pgo", "CSAIL.g2o"))
    assert g.num_nodes == 1045 and g.num_edges == 1172
    assert graph_cost(g) == pytest.approx(1.072e6, rel=1e-3)  # REFERENCE_VALUES.md


@pytest.mark.parametrize(
    "text,match",
    [
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 0\n", r"bad:2: VERTEX_SE2 needs"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", r"bad:3: EDGE_SE2 needs"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n\nEDGE_SE2 0 1 1 0 zero 1 0 0 1 0 1\n", r"bad:4: .*'zero' is not a number"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 nan 0 0 1 0 0 1 0 1\n", r"bad:3: .*non-finite"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 inf 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", r"bad:2: .*non-finite"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 7 1 0 0 1 0 0 1 0 1\n", r"bad:3: EDGE_SE2 0 7 refers to vertex 7"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", r"bad:2: VERTEX_SE2 0 defined twice"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n", r"bad:3: .*not positive definite"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 0\n", r"bad:3: .*not positive definite"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 1 0 0\nVERTEX_SE2 3 1 0 0\n"
         "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n", r"disconnected .*vertex 2"),
        ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n", r"disconnected"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 0 1 0 0 1 0 0 1 0 1\n", r"bad:2: .*itself"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", r"bad:1: unsupported g2o tag"),
        ("VERTEX_SE2 0 0 0 0\n", r"no EDGE_SE2"),
        ("VERTEX_SE2 a 0 0 0\n", r"bad:1: .*'a' is not an integer"),
    ],
)
def test_bad_input_names_the_culprit(text, match):
    with pytest.raises(RhamlError, match=match):
        parse_g2o(text, "bad")


def test_validate_graph_rejects_nan_and_bad_index():
    g = parse_g2o(TOY, "toy")
    with pytest.raises(RhamlError, match="not finite"):
        validate_graph(g._replace(measurements=np.where(np.arange(12).reshape(4, 3) == 4, np.nan, g.measurements)))
    with pytest.raises(RhamlError, match="does not exist"):
        validate_graph(g._replace(edges=np.array([[0, 1], [1, 2], [2, 3], [3, 9]], np.int32)))


def _cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "rhaml_jax.pgo", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_cli_solves_and_writes(tmp_path):
    src = tmp_path / "toy.g2o"
    src.write_text(TOY)
    out = tmp_path / "out.g2o"
    r = _cli(str(src), "--out", str(out), "--method", "lm")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout.strip().splitlines()[-1])
    assert {"initial_cost", "final_cost", "iterations", "seconds", "compile_seconds"} <= set(rep)
    assert rep["final_cost"] < rep["initial_cost"] and rep["iterations"] >= 1
    solved = read_g2o(out)
    assert graph_cost(solved) == pytest.approx(rep["final_cost"], rel=1e-9, abs=1e-12)
    # bad input: one line, exit 2, no traceback
    bad = tmp_path / "bad.g2o"
    bad.write_text(TOY.replace("EDGE_SE2 2 3 1 0", "EDGE_SE2 2 3 1 O"))
    r = _cli(str(bad))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{bad}:8:" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = _cli(str(tmp_path / "missing.g2o"))
    assert r.returncode == 2 and "missing.g2o" in r.stderr
    r = _cli("--help")
    assert r.returncode == 0 and "--method" in r.stdout and "--out" in r.stdout
