"""Loading and exporting the refinement stage's networks (the learned refiner, the segmenter):
Orbax run folders whose meta names the network's kind, config and robot."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.errors import RhamlError


def load_params(ckpt_dir: str | Path, kind: str, model, config_from_dict: Callable, init_params: Callable):
    """(params, cfg) of the latest checkpoint in `ckpt_dir`, which must hold a `kind` network;
    with `model` (a RobotModel) a checkpoint made for another robot is refused."""
    from rhaml_jax.amlnet.checkpoint import Checkpoints
    from rhaml_jax.refine.train import check_robot

    ck = Checkpoints(ckpt_dir, read_only=True)
    try:
        step = ck.latest_step()
        if step is None:
            raise RhamlError(f"{ckpt_dir}: no checkpoint saved yet")
        meta = ck.meta(step)
        if meta.get("kind") != kind:
            held = meta.get("kind") or meta.get("model_config", {}).get("name")
            raise RhamlError(f"{ckpt_dir}: not a {kind} checkpoint (it holds {held!r})")
        if model is not None:
            check_robot(meta, model, str(ckpt_dir))
        cfg = config_from_dict(meta["model_config"])
        like = {"params": init_params(cfg, jax.random.key(0)), "batch_stats": {}}
        if not meta.get("weights_only", False):
            from rhaml_jax.amlnet.steps import make_optimizer

            clip = meta.get("train_config", {}).get("clip")
            like["opt_state"] = jax.eval_shape(make_optimizer(1e-3, 2, clip=clip).init, like["params"])
        state = ck.restore(step, like)
    finally:
        ck.close()
    return jax.tree.map(lambda a: jnp.asarray(np.asarray(a)), state["params"]), cfg


def export_params(run_dir: str | Path, out_dir: str | Path, params) -> Path:
    """Writes `params` (the latest of run `run_dir`) with that checkpoint's meta and no optimizer
    state to `out_dir`, a folder `load_params` reads."""
    from rhaml_jax.amlnet.checkpoint import Checkpoints

    src = Checkpoints(run_dir, read_only=True)
    try:
        step = src.latest_step()
        meta = {**src.meta(step), "weights_only": True, "exported_from": str(run_dir)}
    finally:
        src.close()
    dst = Checkpoints(out_dir, keep=1)
    try:
        dst.save(step, {"params": jax.tree.map(np.asarray, params), "batch_stats": {}}, meta)
    finally:
        dst.close()
    return Path(out_dir)
