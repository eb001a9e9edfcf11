"""User-facing errors and the command-line wrapper that turns them into one line + exit 2.

Every check at an API boundary raises :class:`RhamlError` (or a subclass) with a message that
names the file, field, shape or value at fault. Commands run through :func:`run_cli`, which
prints that message on one line to stderr and exits with status 2, never a traceback.
"""

from __future__ import annotations

import sys
from typing import Callable, NoReturn

import numpy as np

__all__ = ["RhamlError", "run_cli", "check_finite", "check_shape"]


class RhamlError(ValueError):
    """Bad input from a user: a file, field, shape or value that cannot be used."""


def fail(message: str) -> NoReturn:
    raise RhamlError(message)


def check_shape(name: str, array, shape: tuple[int | None, ...]) -> np.ndarray | object:
    """Checks that `array` has `shape` (None matches any size); returns it unchanged."""
    actual = tuple(np.shape(array))
    if len(actual) != len(shape) or any(s is not None and s != a for s, a in zip(shape, actual)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        fail(f"{name}: expected shape {want}, got {actual}")
    return array


def check_finite(name: str, array) -> None:
    """Raises when a host-side array holds NaN or Inf (call outside jit only)."""
    a = np.asarray(array)
    if a.size and not np.all(np.isfinite(a)):
        bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
        fail(f"{name}: {bad} non-finite value(s) (NaN or Inf)")


def run_cli(main: Callable[[], object]) -> None:
    """Runs a command's `main`, with compiled programs kept on disk (`rhaml_jax.compile_cache`);
    user errors print one line and exit 2."""
    from rhaml_jax.compile_cache import enable_compile_cache

    enable_compile_cache()
    try:
        main()
    except RhamlError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    except FileNotFoundError as e:
        print(f"error: file not found: {e.filename or e}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
