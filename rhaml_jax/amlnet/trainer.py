"""The AMLNet training loop: AdamW + cosine, Orbax checkpoints with exact resume, validation,
JSON-lines metrics and a plot, data parallelism over the visible devices.

Exact resume: the data are a pure function of (seed, step) (see data.py), the per-step PRNG
key is fold_in(key(seed), step), and a checkpoint holds params, BatchNorm statistics and the
optimizer state (with its step count); so a run killed and resumed computes the same
parameters as one that ran through (tests/test_train.py checks this).

Data parallelism: a 1-D mesh over all (or `num_devices`) devices; parameters replicated, the
batch sharded on its first axis; one jit computes the global loss (and global BatchNorm
statistics), so N devices give the 1-device loss up to float reassociation.
"""

from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from rhaml_jax.amlnet.checkpoint import Checkpoints, check_config
from rhaml_jax.amlnet.config import ModelConfig, config_to_dict
from rhaml_jax.amlnet.data import BatchSource, check_batch
from rhaml_jax.amlnet.functional import build
from rhaml_jax.amlnet.loss import decode
from rhaml_jax.amlnet.metrics import pose_metrics
from rhaml_jax.amlnet.steps import make_optimizer, make_schedule, make_steps
from rhaml_jax.errors import RhamlError

__all__ = ["TrainConfig", "train_amlnet"]


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


def _devices(num_devices: int | None):
    devs = jax.devices()
    if num_devices is not None:
        if num_devices > len(devs):
            raise RhamlError(f"num_devices: {num_devices} requested, {len(devs)} visible")
        devs = devs[:num_devices]
    return tuple(devs)


@functools.lru_cache(maxsize=4)
def _compiled(cfg: ModelConfig, lr, steps, weight_decay, warmup, clip, w_psi, w_p, w_xy, devices):
    """Jitted steps for one (model, optimizer, device set), reused by later runs in the same
    process (XLA's CPU compiler is slow: minutes for the paper network)."""
    mesh = Mesh(np.array(devices), ("data",))
    rep, bat = NamedSharding(mesh, P()), NamedSharding(mesh, P("data"))
    net = build(cfg, abstract=True)
    tx = make_optimizer(lr, steps, weight_decay, warmup, clip)
    return tx, make_schedule(lr, steps, warmup), make_steps(net, tx, w_psi, w_p, shardings=(rep, bat), w_xy=w_xy), rep, bat


def _read_metrics(path: Path, upto: int) -> list[dict]:
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut by a kill
        if row.get("step", math.inf) <= upto:
            rows.append(row)
    return rows


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


def train_amlnet(cfg: ModelConfig, tc: TrainConfig, out_dir: str | Path, source: BatchSource,
                 val_source: BatchSource | None = None, *, resume: bool = False, data_label: str = "",
                 num_devices: int | None = None, progress: bool = True, stop_at: int | None = None,
                 log: Callable[[str], None] = print) -> dict:
    """Trains `cfg`; returns {"step", "loss", "val": {...}, "params", "batch_stats"}.
    `stop_at` ends the run early at that step (as a kill would, after its checkpoint)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    devices = _devices(num_devices)
    ndev = len(devices)
    if tc.batch % ndev:
        raise RhamlError(f"--batch {tc.batch}: must be a multiple of the {ndev} devices")
    ck = Checkpoints(out, keep=tc.keep)
    try:
        net = build(cfg, jax.random.key(tc.seed))
        tx, sched, steps, rep, bat = _compiled(cfg, tc.lr, tc.steps, tc.weight_decay, tc.warmup, tc.clip,
                                                    tc.w_psi, tc.w_p, tuple(tc.w_xy), devices)
        params, stats = net.params, net.batch_stats
        opt_state = tx.init(params)
        start = 0
        latest = ck.latest_step()
        settings = json.loads(json.dumps(asdict(tc)))  # as stored (tuples become lists)
        meta_base = {"model_config": config_to_dict(cfg), "train_config": settings, "data": data_label}
        if latest is not None and not resume:
            raise RhamlError(f"--out {out}: already holds a checkpoint (step {latest}); pass --resume or choose another folder")
        if resume and latest is not None:
            meta = ck.meta(latest)
            check_config(meta, cfg, f"--resume {out}")
            # settings added since the checkpoint was written count as their defaults
            stored = json.loads(json.dumps(asdict(TrainConfig()))) | meta.get("train_config", {})
            if stored != settings:
                diff = {k: (stored.get(k), v) for k, v in settings.items() if stored.get(k) != v}
                raise RhamlError(f"--resume {out}: training settings differ from the checkpoint's (stored, given): {diff}")
            state = ck.restore(latest, {"params": params, "batch_stats": stats, "opt_state": opt_state})
            params, stats, opt_state = state["params"], state["batch_stats"], state["opt_state"]
            start = latest
            log(f"resuming {out} at step {start}")
        params, stats, opt_state = jax.device_put((params, stats, opt_state), rep)
        put = lambda x: jax.device_put(np.asarray(x), bat)
        metrics_path = out / "metrics.jsonl"
        rows = _read_metrics(metrics_path, start)
        metrics_path.write_text("".join(json.dumps(r) + "\n" for r in rows))
        base_key = jax.random.key(tc.seed)
        last = {"step": start, "loss": float("nan"), "val": {}}
        end = tc.steps if stop_at is None else min(tc.steps, stop_at)
        bar = _progress(progress)
        task = bar.add_task(cfg.name, total=tc.steps, completed=start, loss=float("nan")) if bar else None
        if bar:
            bar.start()
        t_last, n_last = time.perf_counter(), start
        try:
            for step in range(start, end):
                b = source(step)
                check_batch(cfg, b, tc.batch, f"training batch at step {step}")
                key = jax.random.fold_in(base_key, step)
                loss, parts, new_stats, grads = steps.grad_step(params, stats, put(b.images), put(b.observed), put(b.pose), key)
                loss_v = float(loss)
                if not math.isfinite(loss_v):
                    good = ck.latest_step()
                    raise RhamlError(f"step {step}: loss is {loss_v}; training stopped, last good checkpoint: "
                                     f"{'none' if good is None else f'{ck.dir}/{good}'}")
                params, opt_state = steps.update(params, opt_state, grads)
                stats = new_stats
                done = step + 1
                row = None
                if done % tc.log_every == 0 or done == end or done % tc.val_every == 0:
                    now = time.perf_counter()
                    row = {"step": done, **{k: float(v) for k, v in parts.items()},
                           "lr": float(sched(step)), "images_per_s": (done - n_last) * tc.batch / max(now - t_last, 1e-9)}
                    t_last, n_last = now, done
                if val_source is not None and (done % tc.val_every == 0 or done == tc.steps):
                    v = validate(steps.predict, params, stats, val_source, tc.val_batches, cfg, tc.batch, put)
                    row.update({f"val_{k}": x for k, x in v.items()})
                    last["val"] = v
                if row is not None:
                    with metrics_path.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                    rows.append(row)
                if done % tc.ckpt_every == 0 or done == end:
                    ck.save(done, {"params": params, "batch_stats": stats, "opt_state": opt_state}, {**meta_base, "step": done})
                if row is not None and (done % tc.val_every == 0 or done == end):
                    plot_metrics(rows, out / "metrics.png")
                last.update(step=done, loss=loss_v)
                if bar:
                    bar.update(task, completed=done, loss=loss_v)
        finally:
            if bar:
                bar.stop()
        last["params"], last["batch_stats"] = params, stats
        return last
    finally:
        ck.close()


def _progress(enabled: bool):
    if not enabled:
        return None
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("loss {task.fields[loss]:.4f}"), TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn())
