"""`rhaml COMMAND ...`: the console script; each command is also `python -m rhaml_jax.COMMAND`."""

from __future__ import annotations

import importlib
import sys

COMMANDS = ("demo", "generate", "train", "evaluate", "calibrate_flips", "pgo", "info", "fuse_maps", "explore", "fit")


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print("usage: rhaml {" + ",".join(COMMANDS) + "} [--help] ...", file=sys.stderr)
        sys.exit(0 if len(sys.argv) >= 2 else 2)
    command = sys.argv[1].replace("-", "_")
    if command not in COMMANDS:
        print(f"error: unknown command {sys.argv[1]!r} (expected one of {', '.join(COMMANDS)})", file=sys.stderr)
        sys.exit(2)
    try:
        module = importlib.import_module(f"rhaml_jax.{command}")
    except ModuleNotFoundError as e:
        if e.name == f"rhaml_jax.{command}":
            print(f"error: command {command!r} is not available in this version", file=sys.stderr)
            sys.exit(2)
        raise
    if hasattr(module, "__path__"):  # a package: its command lives in __main__
        module = importlib.import_module(f"rhaml_jax.{command}.__main__")
    sys.argv = [f"rhaml {command}"] + sys.argv[2:]
    from rhaml_jax.errors import run_cli

    run_cli(module.main)


if __name__ == "__main__":
    main()
