"""Training-time photometric augmentation (`rhaml_jax.data.augment`): median milliseconds per
batch, and the process's CPU seconds per wall second while it runs.

Run: python experiments/bench_augment.py [--batch 32] [--height 256] [--width 320] [--runs 7]
Prints one JSON line. The trainer augments in a background thread beside the training step, so
on a 2-core machine the augmentation's CPU time is taken from the step's: compare versions side
by side (the same script with PYTHONPATH pointing at each checkout), alternating, in one session.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import time

import jax
import numpy as np
import tyro

from rhaml_jax.data import AugmentConfig, augment


@dataclasses.dataclass(frozen=True)
class Args:
    batch: int = 32
    height: int = 256
    width: int = 320
    runs: int = 7


def main(a: Args) -> dict:
    images = np.random.default_rng(0).random((a.batch, a.height, a.width, 3), np.float32)
    jax.block_until_ready(augment(jax.random.PRNGKey(0), images, AugmentConfig()))  # compile
    ts, cpu = [], 0.0
    for i in range(a.runs):
        c0, t0 = os.times(), time.perf_counter()
        jax.block_until_ready(augment(jax.random.PRNGKey(i + 1), images, AugmentConfig()))
        ts.append(time.perf_counter() - t0)
        c1 = os.times()
        cpu += (c1.user - c0.user) + (c1.system - c0.system)
    return {"batch": a.batch, "hw": [a.height, a.width], "median_ms": round(1e3 * statistics.median(ts), 1),
            "ms": [round(1e3 * t) for t in ts], "cpu_per_wall": round(cpu / sum(ts), 2)}


if __name__ == "__main__":
    print(json.dumps(main(tyro.cli(Args))))
