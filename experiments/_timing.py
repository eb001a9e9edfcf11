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
