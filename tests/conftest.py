"""Shared test fixtures: where ../shared/data is, and a skip when it is absent."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def shared_path(*parts: str) -> Path:
    """A path under ../shared/data; skips the test with a reason when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"shared data not found: {p} (tests that use ../shared/data need it beside the repo)")
    return p


@pytest.fixture(scope="session")
def tiny_bop_set(tmp_path_factory):
    """21 training images of the built-in robot at 160 x 120 (seed 5), with splits: the data of
    the refinement networks' tests (refiner, scorer)."""
    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import write_training_set

    root = tmp_path_factory.mktemp("tiny_bop") / "set"
    write_training_set(root, "pioneer3dx", DEFAULT_CAMERA.resized(160, 120), seed=5, num=21, negatives=0, workers=1)
    return root


def train_tiny(stage: str, config: str, data, out) -> tuple:
    """A refinement-stage network trained through the `train` CLI for 4 steps of 2 (logs at 2 and
    4, a checkpoint every 2, validation at 4): (out, the CLI's result, its arguments)."""
    from rhaml_jax.train import main

    args = ["--stage", stage, "--config", config, "--data", str(data), "--out", str(out),
            "--steps", "4", "--batch", "2", "--log-every", "2", "--val-every", "4", "--val-batches", "1",
            "--ckpt-every", "2", "--no-progress"]
    return out, main(args), args
