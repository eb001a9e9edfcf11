"""Timing helpers shared by `describe(..., bench=True)` and experiments/bench_amlnet.py.

All timings: compile and one warm-up call first, then `runs` timed calls, median reported
(the machine is shared; medians and side-by-side ratios are what is comparable)."""

from __future__ import annotations

import statistics
import time

import jax
import jax.numpy as jnp

from rhaml_jax.amlnet.config import ModelConfig
from rhaml_jax.amlnet.functional import build
from rhaml_jax.amlnet.steps import make_optimizer, make_steps

__all__ = ["median_seconds", "matmul_gmacs", "ModelBench"]


def median_seconds(f, runs: int) -> tuple[float, list[float]]:
    ts = []
    for _ in range(runs):
        t = time.perf_counter()
        jax.block_until_ready(f())
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), ts


def matmul_gmacs(n: int = 2048, runs: int = 5) -> float:
    """Measured float32 n x n matmul rate in GMAC/s (the machine's dense ceiling)."""
    a = jax.random.normal(jax.random.key(0), (n, n), jnp.float32)
    b = jax.random.normal(jax.random.key(1), (n, n), jnp.float32)
    f = jax.jit(jnp.matmul)
    jax.block_until_ready(f(a, b))
    med, _ = median_seconds(lambda: f(a, b), runs)
    return n**3 / med / 1e9


class ModelBench:
    """Compiles inference and a training step (grad jit + separate AdamW jit) once; times them."""

    def __init__(self, cfg: ModelConfig, batch: int = 8, seed: int = 0):
        self.cfg, self.batch = cfg, batch
        net = build(cfg, jax.random.key(seed))
        self.net = net
        self.steps = make_steps(net, make_optimizer(1e-3, 1000))
        h, w = cfg.input_hw
        k = jax.random.split(jax.random.key(seed + 1), 4)
        self.images = jax.random.uniform(k[0], (batch, h, w, 3), jnp.float32)
        self.observed = (jax.random.uniform(k[1], (batch,)) > 0.2).astype(jnp.float32)
        self.pose = jax.random.normal(k[2], (batch, 3))
        self.key = k[3]
        self.params, self.stats = net.params, net.batch_stats
        self.opt_state = make_optimizer(1e-3, 1000).init(self.params)
        self.compile_s = {}

    def _infer(self):
        return self.steps.predict(self.params, self.stats, self.images)

    def _train(self):
        loss, _, stats, grads = self.steps.grad_step(self.params, self.stats, self.images, self.observed, self.pose, self.key)
        self.params, self.opt_state = self.steps.update(self.params, self.opt_state, grads)
        self.stats = stats
        return loss, self.params

    def _train_fused(self):
        self.params, self.stats, self.opt_state, loss = self.steps.fused_step(
            self.params, self.stats, self.opt_state, self.images, self.observed, self.pose, self.key)
        return loss, self.params

    def _warm(self, name, f):
        if name not in self.compile_s:
            t = time.perf_counter()
            jax.block_until_ready(f())
            self.compile_s[name] = time.perf_counter() - t

    def inference_s(self, runs: int = 3) -> list[float]:
        self._warm("inference", self._infer)
        return median_seconds(self._infer, runs)[1]

    def train_s(self, runs: int = 3, fused: bool = False) -> list[float]:
        f = self._train_fused if fused else self._train
        self._warm("train_fused" if fused else "train", f)
        return median_seconds(f, runs)[1]
