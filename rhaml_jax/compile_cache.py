"""Keep compiled programs on disk, so that a command run again does not compile again.

Every `evaluate` run compiles its pipeline before its first frame (30-50 s on the 2-core CPU, more
than the frames of a short run take), `fit` runs 16 of them, and the demo and `train` compile
theirs each time. XLA's persistent compilation cache stores each compiled program under a hash of
the program, its compile options and the JAX version, so a program seen before (the same
networks' shapes, the same modules, the same number of frames) loads in a fraction of the time;
parameters are arguments, not constants, so retrained weights hit the cache too.

`enable_compile_cache()` is what the command-line tools call first, beside `tune_allocator()`.
The cache lives in $RHAML_JAX_CACHE_DIR, or $XDG_CACHE_HOME/rhaml_jax/xla (~/.cache/rhaml_jax/xla),
and is off with RHAML_JAX_CACHE_DIR=off. It is not size-capped (JAX's cap needs the `filelock`
package); programs compiled in under `MIN_COMPILE_S` are not stored, and deleting the directory
is always safe. A cache directory the user gave JAX itself (JAX_COMPILATION_CACHE_DIR or
`jax.config`) is left alone. The cache runs code it reads: keep it where only you can write.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["CACHE_ENV", "cache_dir", "enable_compile_cache"]

CACHE_ENV = "RHAML_JAX_CACHE_DIR"
MIN_COMPILE_S = 1.0  # programs compiled faster than this are not worth a file


def cache_dir() -> Path | None:
    """Where the cache lives (module docstring), or None when it is off."""
    where = os.environ.get(CACHE_ENV, "")
    if where.lower() == "off":
        return None
    if where:
        return Path(where).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rhaml_jax" / "xla"


def enable_compile_cache() -> Path | None:
    """Turns on JAX's persistent compilation cache in `cache_dir()`; returns the directory in use
    (JAX's own if the user set one), or None when off or the directory cannot be made."""
    import jax

    if jax.config.jax_compilation_cache_dir:  # the user's choice
        return Path(jax.config.jax_compilation_cache_dir)
    where = cache_dir()
    if where is None:
        return None
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError:  # a read-only home: compile as before
        return None
    jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    return where
