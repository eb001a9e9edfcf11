"""Timing shared by the benchmarks: the median wall time of a JAX call after the compiling one."""

from __future__ import annotations

import statistics
import time

import jax


def timed(fn, repeats: int):
    """(fn's output, median seconds of `repeats` calls of fn after a first, compiling one); each
    call waits for its device arrays."""
    out = jax.block_until_ready(fn())
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t)
    return out, statistics.median(ts)


def interleaved(calls: dict, repeats: int) -> dict:
    """{name: median seconds} of `repeats` rounds in which every zero-argument call of `calls` (already
    compiled) runs once in turn, each waiting for its device arrays: side by side, so that the ratios
    hold on a busy machine."""
    ts = {name: [] for name in calls}
    for _ in range(repeats):
        for name, fn in calls.items():
            t = time.perf_counter()
            jax.block_until_ready(fn())
            ts[name].append(time.perf_counter() - t)
    return {name: statistics.median(v) for name, v in ts.items()}
