"""Jitted training and inference steps as plain functions of (params, batch_stats, inputs).

On XLA's CPU backend, fusing the optimizer update into the backward computation (one jit for
value_and_grad + optax update) was measured ~6x slower than two separate jits (DESIGN.md
section 8; `experiments/bench_amlnet.py --fused` measures it again).  So a training step is
  grads = grad_step(params, batch_stats, images, observed, pose, key)   # jit 1
  params, opt_state = update(params, opt_state, grads)                 # jit 2 (donated)
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import optax

from rhaml_jax.amlnet.functional import Net
from rhaml_jax.amlnet.heatmap import heatmap_loss
from rhaml_jax.amlnet.loss import amlnet_loss

__all__ = ["Steps", "make_steps", "make_optimizer", "make_schedule"]


class Steps(NamedTuple):
    grad_step: Callable  # (params, stats, images, observed, pose, key) -> (loss, parts, new_stats, grads)
    update: Callable  # (params, opt_state, grads) -> (params, opt_state)
    predict: Callable  # (params, stats, images) -> raw head
    fused_step: Callable  # (params, stats, opt_state, images, observed, pose, key) -> (params, stats, opt_state, loss)


def make_schedule(lr: float = 1e-3, steps: int = 1000, warmup: int = 0):
    """Cosine annealing from `lr` to 0 over `steps` (optional linear warm-up)."""
    if warmup > 0:
        return optax.warmup_cosine_decay_schedule(0.0, lr, warmup, max(steps, warmup + 1))
    return optax.cosine_decay_schedule(lr, max(steps, 1))


def make_optimizer(lr: float = 1e-3, steps: int = 1000, weight_decay: float = 0.05, warmup: int = 0,
                   clip: float | None = None):
    """AdamW with `make_schedule`, after clipping the gradient's global norm to `clip`
    (None: no clipping).  Clipping keeps the rare huge gradient of an outlier batch from
    inflating Adam's second-moment estimate for hundreds of steps."""
    adamw = optax.adamw(make_schedule(lr, steps, warmup), weight_decay=weight_decay)
    return adamw if clip is None else optax.chain(optax.clip_by_global_norm(clip), adamw)


def make_steps(net: Net, tx: optax.GradientTransformation, w_psi: float = 3.0, w_p: float = 2.0,
               shardings: tuple | None = None, w_xy: tuple[float, float] = (1.0, 1.0)) -> Steps:
    """`shardings` = (replicated, batch-sharded) NamedShardings for data parallelism."""
    head = net.cfg.angle_head
    dense = getattr(net.cfg, "head", "global") == "heatmap"

    def loss_fn(params, stats, images, observed, pose, key):
        out, new_stats = net.train_apply(params, stats, images, key)
        if dense:
            loss, parts = heatmap_loss(out, observed, pose, net.cfg.zoom_centre_z_m, w_psi, w_p)
        else:
            loss, parts = amlnet_loss(out, observed, pose, head, w_psi, w_p, w_xy)
        return loss, (parts, new_stats)

    def grad_step(params, stats, images, observed, pose, key):
        (loss, (parts, new_stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, stats, images, observed, pose, key)
        return loss, parts, new_stats, grads

    def update(params, opt_state, grads):
        upd, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, upd), opt_state

    def fused(params, stats, opt_state, images, observed, pose, key):
        loss, _, new_stats, grads = grad_step(params, stats, images, observed, pose, key)
        params, opt_state = update(params, opt_state, grads)
        return params, new_stats, opt_state, loss

    predict = lambda params, stats, images: net.apply(params, stats, images)
    if shardings is None:
        return Steps(jax.jit(grad_step), jax.jit(update, donate_argnums=(0, 1)), jax.jit(predict), jax.jit(fused, donate_argnums=(0, 1, 2)))
    rep, bat = shardings
    return Steps(
        jax.jit(grad_step, in_shardings=(rep, rep, bat, bat, bat, rep), out_shardings=rep),
        jax.jit(update, donate_argnums=(0, 1), in_shardings=(rep, rep, rep), out_shardings=rep),
        jax.jit(predict, in_shardings=(rep, rep, bat), out_shardings=bat),
        jax.jit(fused, donate_argnums=(0, 1, 2), in_shardings=(rep, rep, rep, bat, bat, bat, rep), out_shardings=rep),
    )
