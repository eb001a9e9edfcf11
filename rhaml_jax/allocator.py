"""Keep freed memory in the process instead of handing it back to the kernel (glibc only).

XLA's CPU runtime allocates every execution's buffers with malloc. glibc serves the large ones
with fresh mmap pages, or trims them from its arenas on free, so each training step touches
its working set anew: 565,000 minor page faults (2.3 GB) per training step of the paper-size
AMLNet at batch 8, 0 with these settings (experiments/bench_amlnet.py reports the count; the
step's median time in alternating runs: 6.6 s -> 5.5 s, BENCHMARKS.md). The cost: the process
keeps its peak heap.

`tune_allocator()` is what the command-line tools call first; library users call it
themselves, early (before JAX starts its threads), or set RHAML_JAX_MALLOC=system to opt out.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

__all__ = ["tune_allocator", "MALLOC_ENV"]

# mallopt parameters, glibc's malloc.h
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8
# The same settings as glibc's environment variables, for a child process (a trim threshold
# beyond any heap: never trim, as mallopt's -1).
MALLOC_ENV = {"MALLOC_ARENA_MAX": "1", "MALLOC_MMAP_MAX_": "0", "MALLOC_TRIM_THRESHOLD_": str(2**62)}
_applied = False


def tune_allocator() -> bool:
    """Configures glibc malloc for repeated large allocations (see module docstring).

    Returns whether the settings were applied: False on a non-glibc system, when
    RHAML_JAX_MALLOC=system, or when glibc refused one of them. Idempotent."""
    global _applied
    if _applied:
        return True
    if os.environ.get("RHAML_JAX_MALLOC", "") == "system":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 - glibc only: musl and macOS have no mallopt semantics to rely on
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    ok = all(mallopt(p, v) == 1 for p, v in ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, -1)))
    _applied = ok
    return ok
