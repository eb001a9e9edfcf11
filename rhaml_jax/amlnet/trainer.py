"""AMLNet's (and its zoom stage's) training task: AdamW + cosine, the AMLNet loss, pose and
detection validation, its metrics plot. The loop itself (Orbax checkpoints with exact resume,
metrics.jsonl, NaN guard, progress, data parallelism) is `rhaml_jax.training.fit`, shared with
the refiner.

Data parallelism: parameters replicated, the batch sharded on its first axis; one jit computes
the global loss (and global BatchNorm statistics), so N devices give the 1-device loss up to
float reassociation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax.amlnet.checkpoint import check_config, load_model
from rhaml_jax.amlnet.config import ModelConfig, config_to_dict
from rhaml_jax.amlnet.data import BatchSource, check_batch
from rhaml_jax.amlnet.functional import build
from rhaml_jax.amlnet.loss import decode
from rhaml_jax.amlnet.metrics import pose_metrics
from rhaml_jax.amlnet.steps import make_optimizer, make_schedule, make_steps
from rhaml_jax.errors import RhamlError
from rhaml_jax.training import Task, devices, fit, mesh_shardings

__all__ = ["TrainConfig", "amlnet_task", "train_amlnet"]


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings of a run (stored in its checkpoints; `--resume` requires equal ones)."""

    steps: int = 5000
    """optimizer steps (the cosine schedule spans them)"""
    batch: int = 32
    """global batch size (a multiple of the device count)"""
    lr: float = 1e-3
    """AdamW peak learning rate (cosine annealing to 0)"""
    weight_decay: float = 0.05
    """AdamW weight decay"""
    warmup: int = 200
    """linear learning-rate warm-up steps (0: none, the paper's plain cosine)"""
    clip: float | None = 5.0
    """clip the gradient's global norm to this (None: no clipping)"""
    seed: int = 0
    """seed of initialisation, data order and augmentation"""
    w_psi: float = 3.0
    """weight of the heading term in L_p"""
    w_p: float = 2.0
    """weight of L_p in L_A = L_o + w_p L_p"""
    w_xy: tuple[float, float] = (1.0, 1.0)
    """weights of the x and y terms in L_p (the zoom stage: its log-range and bearing corrections)"""
    log_every: int = 10
    """steps between metrics.jsonl lines"""
    val_every: int = 500
    """steps between validations"""
    val_batches: int = 8
    """validation batches per validation"""
    ckpt_every: int = 250
    """steps between checkpoints"""
    keep: int = 2
    """checkpoints kept"""


@functools.lru_cache(maxsize=4)
def _compiled(cfg: ModelConfig, lr, steps, weight_decay, warmup, clip, w_psi, w_p, w_xy, devices):
    """Jitted steps for one (model, optimizer, device set), reused by later runs in the same
    process (XLA's CPU compiler is slow: minutes for the paper network)."""
    rep, bat = mesh_shardings(devices)
    net = build(cfg, abstract=True)
    tx = make_optimizer(lr, steps, weight_decay, warmup, clip)
    return tx, make_schedule(lr, steps, warmup), make_steps(net, tx, w_psi, w_p, shardings=(rep, bat), w_xy=w_xy), rep, bat


def plot_metrics(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    tr = [r for r in rows if "loss" in r]
    axes[0].semilogy([r["step"] for r in tr], [r["loss"] for r in tr], label="L_A")
    for k, lab in (("loss_o", "L_o"), ("loss_p", "L_p"), ("loss_psi", "heading term")):
        axes[0].semilogy([r["step"] for r in tr if k in r], [r[k] for r in tr if k in r], label=lab, alpha=0.7)
    axes[0].set_title("training loss"); axes[0].set_xlabel("step"); axes[0].legend()
    va = [r for r in rows if "val_dpsi_deg" in r]
    for k, lab in (("val_dx_cm", "|dx| cm"), ("val_dy_cm", "|dy| cm"), ("val_range_pct", "|d range| %"),
                   ("val_bearing_deg", "|d bearing| deg"), ("val_dpsi_deg", "|dpsi| deg")):
        if any(k in r for r in va):
            axes[1].plot([r["step"] for r in va if k in r], [r[k] for r in va if k in r], "o-", label=lab)
    axes[1].set_title("validation pose error"); axes[1].set_xlabel("step"); axes[1].legend()
    vd = [r for r in rows if "val_detection_acc" in r]
    axes[2].plot([r["step"] for r in vd], [r["val_detection_acc"] for r in vd], "o-")
    axes[2].set_title("validation detection accuracy"); axes[2].set_xlabel("step")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def validate(predict, params, stats, val_source, n_batches: int, cfg, batch: int, put) -> dict:
    preds, obs, poses = [], [], []
    for i in range(n_batches):
        b = val_source(i)
        check_batch(cfg, b, batch, f"validation batch {i}")
        out = np.asarray(predict(params, stats, put(b.images)))
        preds.append({k: np.asarray(v) for k, v in decode(jnp.asarray(out), cfg.angle_head).items()})
        obs.append(np.asarray(b.observed)); poses.append(np.asarray(b.pose))
    pred = {k: np.concatenate([p[k] for p in preds]) for k in preds[0]}
    return pose_metrics(pred, np.concatenate(obs), np.concatenate(poses), getattr(cfg, "task", "localize"))


WEIGHTLESS_FIELDS = ("luma", "zoom_length_m", "zoom_centre_z_m", "zoom_factor")  # config fields no parameter depends on


def initial_weights(cfg: ModelConfig, init: str | Path) -> tuple[object, object]:
    """(params, batch_stats) of the checkpoint folder `init` (a run or an exported one, e.g.
    `rhaml_jax/checkpoints/amlnet_cpu`), to fine-tune from; it must hold the model `cfg` up to
    the fields that change no weight: its name, input colours (`luma`: a colour network can start
    a luminance one) and the zoom crop's geometry (`zoom_length_m`, `zoom_centre_z_m`,
    `zoom_factor`: one robot's zoom stage can start another's); a luminance network starts a
    `chroma` or `log_luma` one with the same outputs (`luma_channel_freed`)."""
    if not (Path(init) / "checkpoints").is_dir():
        raise RhamlError(f"--init {init}: not a checkpoint folder (no checkpoints/ inside)")
    net, params, stats = load_model(init)
    free = {k: getattr(cfg, k) for k in WEIGHTLESS_FIELDS + ("chroma", "chroma_window", "log_luma") if hasattr(cfg, k)}
    if type(net.cfg) is not type(cfg) or replace(net.cfg, name=cfg.name, **free) != cfg:
        mine, theirs = config_to_dict(cfg), config_to_dict(net.cfg)
        differ = sorted(k for k in set(mine) | set(theirs) if k != "name" and k not in free and mine.get(k) != theirs.get(k))
        raise RhamlError(f"--init {init}: holds model config {net.cfg.name!r}, not the {cfg.name!r} being trained "
                         f"(they differ in {', '.join(differ) or 'kind'})")
    for field, channel in (("chroma", 2), ("log_luma", 1)):  # an input channel the checkpoint did not see
        new, old = getattr(cfg, field, False), getattr(net.cfg, field, False)
        if old and not new:
            raise RhamlError(f"--init {init}: a {field} network cannot start {cfg.name!r}, which has no {field} channel")
        if new and not old:  # exact for the luminance copies `cfg` sees (it has luma), whatever `net` saw
            params = luma_channel_freed(params, channel)
    return params, stats


def luma_channel_freed(params, channel: int):
    """The stem of a luminance network (three normalised copies of the luminance in) rewritten
    so that copy `channel` (1 or 2) can carry another input (the log luminance, the chroma
    contrast) with the outputs unchanged: its weights go onto the first copy (rescaled to its
    normalisation, the offset into the bias) and start at zero."""
    from rhaml_jax.amlnet.model import IMAGENET_MEAN as M, IMAGENET_STD as S

    w, b = np.asarray(params["stem"][...]), np.asarray(params["stem_b"][...])  # (4, 4, 3, C), (C,)
    wc = w[:, :, channel, :]
    new_w = w.copy()
    new_w[:, :, 0, :] += wc * S[0] / S[channel]  # luminance = S0 n0 + M0 = Sc nc + Mc, nc channel c's input
    new_w[:, :, channel, :] = 0.0
    new_b = b + wc.sum((0, 1)) * (M[0] - M[channel]) / S[channel]
    params = jax.tree.map(lambda x: x, params)  # a copy: the caller's state stays as loaded
    params["stem"] = params["stem"].replace(jnp.asarray(new_w, params["stem"][...].dtype))
    params["stem_b"] = params["stem_b"].replace(jnp.asarray(new_b, params["stem_b"][...].dtype))
    return params


def amlnet_task(cfg: ModelConfig, tc: TrainConfig, val_source: BatchSource | None = None,
                num_devices: int | None = None, init: str | Path | None = None,
                robot: dict | None = None) -> tuple[Task, tuple]:
    """(the `rhaml_jax.training.Task` of AMLNet or its zoom stage, its shardings). `init`: a
    checkpoint folder to start from instead of a random initialisation (fine-tuning); `robot`:
    the fingerprint of the robot the data show (`robots.fingerprint(...).to_dict()`), stored in
    every checkpoint; a resumed run must be of the same robot."""
    devs = devices(num_devices)
    if tc.batch % len(devs):
        raise RhamlError(f"--batch {tc.batch}: must be a multiple of the {len(devs)} devices")
    net = build(cfg, jax.random.key(tc.seed))
    params, stats = (net.params, net.batch_stats) if init is None else initial_weights(cfg, init)
    tx, sched, steps, rep, bat = _compiled(cfg, tc.lr, tc.steps, tc.weight_decay, tc.warmup, tc.clip,
                                           tc.w_psi, tc.w_p, tuple(tc.w_xy), devs)

    def val(params, stats, put):
        return validate(steps.predict, params, stats, val_source, tc.val_batches, cfg, tc.batch, put)

    meta = {"model_config": config_to_dict(cfg)}
    if init is not None:
        meta["initialised_from"] = str(init)
    if robot is not None:
        meta["robot"] = robot

    def check_resume(stored, where):
        check_config(stored, cfg, where)
        if robot is not None and stored.get("robot") is not None:
            from rhaml_jax.robots import RobotFingerprint, require_same_robot

            a, b = (RobotFingerprint.from_dict(r, where) for r in (stored["robot"], robot))
            require_same_robot(a, b, f"{where}: this run trains robot {{mine}}, not {{theirs}}")

    task = Task(name=cfg.name, params=params, batch_stats=stats, opt_init=tx.init,
                grad_step=steps.grad_step, update=steps.update, schedule=sched, meta=meta,
                check_resume=check_resume,
                check_batch=lambda b, where: check_batch(cfg, b, tc.batch, where),
                validate=None if val_source is None else val, plot=plot_metrics)
    return task, (rep, bat)


def train_amlnet(cfg: ModelConfig, tc: TrainConfig, out_dir: str | Path, source: BatchSource,
                 val_source: BatchSource | None = None, *, resume: bool = False, data_label: str = "",
                 num_devices: int | None = None, progress: bool = True, stop_at: int | None = None,
                 log: Callable[[str], None] = print, init: str | Path | None = None,
                 robot: dict | None = None) -> dict:
    """Trains `cfg` (from the weights in the checkpoint folder `init`, if given); returns
    {"step", "loss", "val": {...}, "params", "batch_stats"}. `stop_at` ends the run early at that
    step (as a kill would, after its checkpoint)."""
    task, shardings = amlnet_task(cfg, tc, val_source, num_devices, init, robot)
    return fit(task, tc, out_dir, source, shardings=shardings, resume=resume, data_label=data_label,
               progress=progress, stop_at=stop_at, log=log)
