"""The training loop every network of the pipeline shares (AMLNet, its zoom stage, the refiner):
Orbax checkpoints with exact resume, validation, JSON-lines metrics and a plot, a NaN guard,
a progress bar and data parallelism over the visible devices. What a network learns is a
`Task`: its initial state, jitted gradient and update steps, its validation and its metadata;
the loop knows nothing else about it.

Exact resume: the data are a pure function of (seed, step), the per-step PRNG key is
fold_in(key(seed), step), and a checkpoint holds params, batch statistics and the optimizer
state (with its step count); so a run killed and resumed computes the same parameters as one
that ran through (tests/test_train.py checks this for AMLNet).

Data parallelism: `mesh_shardings` gives (replicated, batch-sharded) NamedShardings of a 1-D
mesh; a task's jitted steps take the batch sharded on its first axis.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

from rhaml_jax.errors import RhamlError

__all__ = ["Task", "fit", "devices", "mesh_shardings", "read_metrics", "progress_bar"]


@dataclass(frozen=True)
class Task:
    """What one network learns, for `fit`.

    name: progress-bar label. params, batch_stats: the initial state (batch_stats may be {}).
    opt_init: params -> optimizer state. grad_step: (params, stats, *batch_fields, key) ->
    (loss, parts: dict of scalars, new_stats, grads). update: (params, opt_state, grads) ->
    (params, opt_state). schedule: step -> learning rate (logged). meta: JSON stored with every
    checkpoint (the model config, so that a checkpoint alone rebuilds the model). check_resume:
    (stored meta, where) -> None, raises RhamlError if the checkpoint is not this task's.
    check_batch: (batch, where) -> None, raises RhamlError naming the field at fault.
    validate: (params, stats, put) -> dict of floats (logged as val_*), or None. plot: (rows,
    path) -> None, draws metrics.png, or None.
    """

    name: str
    params: Any
    batch_stats: Any
    opt_init: Callable
    grad_step: Callable
    update: Callable
    schedule: Callable
    meta: dict
    check_resume: Callable[[dict, str], None]
    check_batch: Callable[[Any, str], None]
    validate: Callable | None = None
    plot: Callable | None = None


def devices(num_devices: int | None):
    devs = jax.devices()
    if num_devices is not None:
        if num_devices > len(devs):
            raise RhamlError(f"num_devices: {num_devices} requested, {len(devs)} visible")
        devs = devs[:num_devices]
    return tuple(devs)


def mesh_shardings(devs) -> tuple[NamedSharding, NamedSharding]:
    """(replicated, batch-sharded) over a 1-D mesh of `devs`."""
    mesh = Mesh(np.array(devs), ("data",))
    return NamedSharding(mesh, P()), NamedSharding(mesh, P("data"))


def read_metrics(path: Path, upto: int) -> list[dict]:
    """The rows of metrics.jsonl with step <= upto (a line cut by a kill is skipped)."""
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


def _settings(tc) -> dict:
    return json.loads(json.dumps(asdict(tc)))  # as stored (tuples become lists)


def fit(task: Task, tc, out_dir: str | Path, source, *, shardings, resume: bool = False, data_label: str = "",
        progress: bool = True, stop_at: int | None = None, log: Callable[[str], None] = print) -> dict:
    """Trains `task` with the optimisation settings `tc` (a frozen dataclass with at least steps,
    batch, seed, log_every, val_every, ckpt_every, keep; stored, and `--resume` requires equal
    ones; fields added since a checkpoint was written count as their defaults). `source(step)`
    gives the batch of a step (a tuple of arrays). Returns {"step", "loss", "val", "params",
    "batch_stats"}. `stop_at` ends the run early at that step (as a kill would, after its
    checkpoint)."""
    from rhaml_jax.amlnet.checkpoint import Checkpoints  # here: amlnet's trainer imports this module

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep, bat = shardings
    ck = Checkpoints(out, keep=tc.keep)
    try:
        params, stats = task.params, task.batch_stats
        opt_state = task.opt_init(params)
        start = 0
        latest = ck.latest_step()
        settings = _settings(tc)
        meta_base = {**task.meta, "train_config": settings, "data": data_label}
        if latest is not None and not resume:
            raise RhamlError(f"--out {out}: already holds a checkpoint (step {latest}); pass --resume or choose another folder")
        if resume and latest is not None:
            meta = ck.meta(latest)
            task.check_resume(meta, f"--resume {out}")
            stored = _settings(type(tc)()) | meta.get("train_config", {})
            if stored != settings:
                diff = {k: (stored.get(k), v) for k, v in settings.items() if stored.get(k) != v}
                raise RhamlError(f"--resume {out}: training settings differ from the checkpoint's (stored, given): {diff}")
            state = ck.restore(latest, {"params": params, "batch_stats": stats, "opt_state": opt_state})
            params, stats, opt_state = state["params"], state["batch_stats"], state["opt_state"]
            start = latest
            log(f"resuming {out} at step {start}")
        params, stats, opt_state = jax.device_put((params, stats, opt_state), rep)
        put = lambda x: jax.device_put(np.asarray(x), bat)  # noqa: E731
        metrics_path = out / "metrics.jsonl"
        rows = read_metrics(metrics_path, start)
        metrics_path.write_text("".join(json.dumps(r) + "\n" for r in rows))
        base_key = jax.random.key(tc.seed)
        last = {"step": start, "loss": float("nan"), "val": {}}
        end = tc.steps if stop_at is None else min(tc.steps, stop_at)
        bar = progress_bar(progress)
        bar_task = bar.add_task(task.name, total=tc.steps, completed=start, loss=float("nan")) if bar else None
        if bar:
            bar.start()
        t_last, n_last = time.perf_counter(), start
        try:
            for step in range(start, end):
                b = source(step)
                task.check_batch(b, f"training batch at step {step}")
                key = jax.random.fold_in(base_key, step)
                loss, parts, new_stats, grads = task.grad_step(params, stats, *(put(x) for x in b), key)
                loss_v = float(loss)
                if not math.isfinite(loss_v):
                    good = ck.latest_step()
                    raise RhamlError(f"step {step}: loss is {loss_v}; training stopped, last good checkpoint: "
                                     f"{'none' if good is None else f'{ck.dir}/{good}'}")
                params, opt_state = task.update(params, opt_state, grads)
                stats = new_stats
                done = step + 1
                row = None
                if done % tc.log_every == 0 or done == end or done % tc.val_every == 0:
                    now = time.perf_counter()
                    row = {"step": done, **{k: float(v) for k, v in parts.items()},
                           "lr": float(task.schedule(step)), "images_per_s": (done - n_last) * tc.batch / max(now - t_last, 1e-9)}
                    t_last, n_last = now, done
                if task.validate is not None and (done % tc.val_every == 0 or done == tc.steps):
                    v = task.validate(params, stats, put)
                    row.update({f"val_{k}": x for k, x in v.items()})
                    last["val"] = v
                if row is not None:
                    with metrics_path.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                    rows.append(row)
                if done % tc.ckpt_every == 0 or done == end:
                    ck.save(done, {"params": params, "batch_stats": stats, "opt_state": opt_state}, {**meta_base, "step": done})
                if task.plot is not None and row is not None and (done % tc.val_every == 0 or done == end):
                    task.plot(rows, out / "metrics.png")
                last.update(step=done, loss=loss_v)
                if bar:
                    bar.update(bar_task, completed=done, loss=loss_v)
        finally:
            if bar:
                bar.stop()
        last["params"], last["batch_stats"] = params, stats
        return last
    finally:
        ck.close()


def progress_bar(enabled: bool):
    if not enabled:
        return None
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("loss {task.fields[loss]:.4f}"), TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn())
