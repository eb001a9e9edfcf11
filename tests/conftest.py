"""Shared test fixtures: where ../shared/data is (and a skip when it is absent), a tiny BOP set,
and random-weight network checkpoints."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def pytest_configure(config):
    """Compiled programs kept on disk (`rhaml_jax.compile_cache`) in pytest's cache folder: many
    tests compile the same program for networks or models of their own, and a second run loads
    every program the first compiled. RHAML_JAX_CACHE_DIR=off turns it off here too."""
    import os

    from rhaml_jax.compile_cache import CACHE_ENV, enable_compile_cache

    if os.environ.get(CACHE_ENV, "").lower() != "off" and getattr(config, "cache", None) is not None:  # absent under -p no:cacheprovider
        os.environ.setdefault(CACHE_ENV, str(config.cache.mkdir("xla")))
    enable_compile_cache()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drops every compiled program after each test module. XLA:CPU maps each executable's code
    and data into 3 memory mappings that live as long as JAX's caches hold the executable; the
    whole suite in one process compiled about 20,000 programs (eager ops compile one per shape)
    and reached Linux's default vm.max_map_count (65,530), where the next compile or
    compilation-cache read crashed natively (SIGSEGV or SIGABRT, at whichever test came next).
    A later module that needs a program again reads it back from the persistent cache."""
    yield
    import gc

    import jax

    jax.clear_caches()
    gc.collect()


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


def random_checkpoint(folder: Path, config, seed: int = 5, **meta) -> Path:
    """A weights-only checkpoint of an AMLNet or zoom-stage config (a name or a config object) at
    random weights, with `meta` added to its meta: what `evaluate --amlnet/--zoom` and the
    calibration read, without training."""
    import jax

    from rhaml_jax.amlnet import build, get_config
    from rhaml_jax.amlnet.checkpoint import Checkpoints
    from rhaml_jax.amlnet.config import config_to_dict

    cfg = get_config(config) if isinstance(config, str) else config
    net = build(cfg, jax.random.key(seed))
    ck = Checkpoints(folder, keep=1)
    ck.save(0, {"params": net.params, "batch_stats": net.batch_stats},
            {"model_config": config_to_dict(cfg), "weights_only": True, "step": 0, **meta})
    ck.close()
    return folder
