"""The one `rhaml_jax.training.Task` shape of the refinement stage's networks (the learned
refiner, the segmenter, the heading scorer): a loss over a batch of arrays, its gradient and
the optimizer update jitted apart (fused, XLA's CPU backend ran such steps several times slower:
DESIGN.md section 8), validation means, and checkpoints that store the config, the kind and the
robot's fingerprint (a resume with another network or robot is refused)."""

from __future__ import annotations

from typing import Callable

import jax
import numpy as np

from rhaml_jax.errors import RhamlError


def network_task(kind: str, cfg, tc, model, *, init_params: Callable, config_to_dict: Callable,
                 config_from_dict: Callable, loss: Callable, n_fields: int, check_batch: Callable,
                 val_source=None, num_devices=None):
    """(Task, (replicated, batch-sharded) shardings). `loss(params, *batch) -> (loss, dict of
    scalars)` over a batch of `n_fields` arrays; `model`: the RobotModel whose fingerprint the
    checkpoints store; `check_batch(batch, where)` raises naming the field at fault."""
    from rhaml_jax.amlnet.steps import make_optimizer, make_schedule
    from rhaml_jax.refine.train import check_robot
    from rhaml_jax.robots import fingerprint
    from rhaml_jax.training import Task, devices, mesh_shardings

    devs = devices(num_devices)
    if tc.batch % len(devs):
        raise RhamlError(f"--batch {tc.batch}: must be a multiple of the {len(devs)} devices")
    rep, bat = mesh_shardings(devs)
    tx = make_optimizer(tc.lr, tc.steps, tc.weight_decay, tc.warmup, tc.clip)

    def grad_step(params, stats, *rest):
        b = rest[:n_fields]  # rest[n_fields]: the step's PRNG key (unused: examples come drawn)
        (value, parts), grads = jax.value_and_grad(lambda p: loss(p, *b), has_aux=True)(params)
        return value, parts, stats, grads

    def update(params, opt_state, grads):
        import optax

        upd, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, upd), opt_state

    gs = jax.jit(grad_step, in_shardings=(rep, rep) + (bat,) * n_fields + (rep,), out_shardings=rep)
    up = jax.jit(update, donate_argnums=(0, 1), in_shardings=(rep, rep, rep), out_shardings=rep)
    ev = jax.jit(lambda params, *b: loss(params, *b)[1])

    def validate(params, stats, put):
        rows = [ev(params, *(put(x) for x in val_source(i))) for i in range(tc.val_batches)]
        return {k: float(np.mean([float(r[k]) for r in rows])) for k in rows[0]}

    meta = {"model_config": config_to_dict(cfg), "kind": kind, "robot": fingerprint(model).to_dict()}

    def check_resume(stored, where):
        if stored.get("kind") != kind or config_from_dict(stored["model_config"]) != cfg:
            raise RhamlError(f"{where}: checkpoint holds another model ({stored.get('model_config', {}).get('name')!r}), not {cfg.name!r}")
        check_robot(stored, model, where)

    task = Task(name=cfg.name, params=init_params(cfg, jax.random.key(tc.seed)), batch_stats={}, opt_init=tx.init,
                grad_step=gs, update=up, schedule=make_schedule(tc.lr, tc.steps, tc.warmup), meta=meta,
                check_resume=check_resume, check_batch=lambda b, where: check_batch(b, tc.batch, where),
                validate=None if val_source is None else validate, plot=plot_losses)
    return task, (rep, bat)


def plot_losses(rows: list[dict], path) -> None:
    """metrics.png of a refinement-stage network: every training loss term and, where validated,
    the same terms on the validation split (log scale; the terms are all positive)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = sorted({k for r in rows for k in r if k.startswith("loss")})
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for ax, prefix, style, title in ((axes[0], "", "-", "training loss"), (axes[1], "val_", "o-", "validation loss")):
        for k in keys:
            pts = [(r["step"], r[prefix + k]) for r in rows if prefix + k in r]
            if pts:
                ax.semilogy(*zip(*pts), style, label=k, alpha=0.8)
        ax.set_title(title); ax.set_xlabel("step")
        if ax.lines:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def check_fields(b, shapes: dict, what: str, where: str) -> None:
    """Raises RhamlError naming the first field of batch `b` whose shape is not `shapes[name]`."""
    if not isinstance(b, tuple) or len(b) != len(shapes):
        raise RhamlError(f"{where}: expected a {what}, got {type(b).__name__}")
    for (name, shape), a in zip(shapes.items(), b):
        if np.shape(a) != shape:
            raise RhamlError(f"{where}.{name}: expected shape {shape}, got {np.shape(a)}")
