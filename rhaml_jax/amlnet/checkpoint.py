"""Orbax checkpoints of AMLNet training runs: one folder per run, the model config stored
beside the weights (a checkpoint alone rebuilds the model).

Layout: DIR/checkpoints/<step>/{state, meta}; `state` = {"params", "batch_stats",
"opt_state"} (Orbax StandardSave), `meta` = JSON {"model_config", "train_config", "step",
"data"}.  Orbax writes each step into a temporary folder and renames it when complete, so a
killed run leaves the previous checkpoints intact and never a half-written one."""

from __future__ import annotations

import logging
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp

from rhaml_jax.amlnet.config import ModelConfig, config_from_dict
from rhaml_jax.amlnet.functional import Net, build
from rhaml_jax.errors import RhamlError

__all__ = ["Checkpoints", "load_model", "export_weights", "shipped_checkpoint", "SHIPPED_DIR"]

SHIPPED_DIR = Path(__file__).resolve().parents[1] / "checkpoints"
"""Weights shipped inside the package (each a `load_model` folder; BENCHMARKS.md has the
command that reproduces each and its metrics)."""


class Checkpoints:
    def __init__(self, run_dir: str | Path, keep: int = 2, read_only: bool = False):
        self.dir = Path(run_dir).absolute() / "checkpoints"
        if read_only and not self.dir.is_dir():
            raise RhamlError(f"{run_dir}: no Orbax checkpoints (missing folder {self.dir})")
        if read_only:  # a read-only manager neither saves nor prunes
            opts = ocp.CheckpointManagerOptions(max_to_keep=None, save_interval_steps=0, create=False,
                                                enable_async_checkpointing=False, read_only=True)
        else:
            opts = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True, enable_async_checkpointing=False)
        absl = logging.getLogger("absl")
        level = absl.level
        if read_only:
            absl.setLevel(logging.ERROR)  # Orbax warns that the directory is read only
        try:
            self.mngr = ocp.CheckpointManager(self.dir, options=opts, item_names=("state", "meta"))
        finally:
            absl.setLevel(level)

    def latest_step(self) -> int | None:
        return self.mngr.latest_step()

    def save(self, step: int, state: dict, meta: dict) -> None:
        state = jax.tree.map(np.asarray, state)
        self.mngr.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)))
        self.mngr.wait_until_finished()

    def meta(self, step: int | None = None) -> dict:
        step = self.latest_step() if step is None else step
        if step is None:
            raise RhamlError(f"{self.dir}: no checkpoint saved yet")
        return self.mngr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]

    def restore(self, step: int, like: dict) -> dict:
        """Restores `state` at `step` into the structure (and dtypes) of `like`."""
        abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype), like)
        try:
            out = self.mngr.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))
        except (ValueError, KeyError, TypeError) as e:
            raise RhamlError(f"{self.dir}/{step}: checkpoint does not match the model: {str(e).splitlines()[0][:200]}") from None
        return out["state"]

    def close(self) -> None:
        self.mngr.close()


def check_config(meta: dict, cfg: ModelConfig, where) -> None:
    stored = config_from_dict(meta["model_config"])
    if stored != cfg:
        raise RhamlError(f"{where}: checkpoint holds model config {stored.name!r} ({meta['model_config']}), not {cfg.name!r}")


def load_model(run_dir: str | Path, step: int | None = None) -> tuple[Net, object, object]:
    """(net, params, batch_stats) from a run folder, rebuilt from the stored config alone."""
    from rhaml_jax.amlnet.steps import make_optimizer

    ck = Checkpoints(run_dir, read_only=True)
    try:
        step = ck.latest_step() if step is None else step
        if step is None:
            raise RhamlError(f"{run_dir}: no checkpoint saved yet")
        meta = ck.meta(step)
        cfg = config_from_dict(meta["model_config"])
        net = build(cfg, abstract=True)
        like = {"params": net.params, "batch_stats": net.batch_stats}
        if not meta.get("weights_only", False):  # a training run also holds the optimizer state
            clip = meta.get("train_config", {}).get("clip")  # the optimizer state's structure
            like["opt_state"] = jax.eval_shape(make_optimizer(1e-3, 2, clip=clip).init, net.params)
        state = ck.restore(step, like)
    finally:
        ck.close()
    return net, state["params"], state["batch_stats"]


def checkpoint_meta(run_dir: str | Path) -> dict:
    """A checkpoint folder's latest meta (module docstring)."""
    ck = Checkpoints(run_dir, read_only=True)
    try:
        step = ck.latest_step()
        if step is None:
            raise RhamlError(f"{run_dir}: no checkpoint saved yet")
        return ck.meta(step)
    finally:
        ck.close()


def checkpoint_robot(run_dir: str | Path) -> dict | None:
    """The robot fingerprint stored in a checkpoint folder's latest meta (`rhaml_jax.robots
    .fingerprint`), or None for a checkpoint from before fingerprints."""
    return checkpoint_meta(run_dir).get("robot")


def export_weights(run_dir: str | Path, out_dir: str | Path, step: int | None = None, extra_meta: dict | None = None) -> Path:
    """Writes the weights of a run's checkpoint (no optimizer state: a third of the size) as a
    checkpoint folder of the same layout, which `load_model` reads; returns `out_dir`."""
    net, params, batch_stats = load_model(run_dir, step)
    src = Checkpoints(run_dir, read_only=True)
    try:
        step = src.latest_step() if step is None else step
        meta = {**src.meta(step), "weights_only": True, "exported_from": str(run_dir), **(extra_meta or {})}
    finally:
        src.close()
    dst = Checkpoints(out_dir, keep=1)
    try:
        dst.save(step, {"params": params, "batch_stats": batch_stats}, meta)
    finally:
        dst.close()
    return Path(out_dir)


def shipped_checkpoint(name: str = "amlnet_cpu") -> Path:
    """The folder of a shipped checkpoint (e.g. "amlnet_cpu"), for `load_model`."""
    path = SHIPPED_DIR / name
    if not (path / "checkpoints").is_dir():
        known = sorted(p.name for p in SHIPPED_DIR.iterdir() if (p / "checkpoints").is_dir()) if SHIPPED_DIR.is_dir() else []
        raise RhamlError(f"shipped checkpoint {name!r}: not found in {SHIPPED_DIR} (shipped: {', '.join(known) or 'none'})")
    return path
