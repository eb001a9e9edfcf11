#!/usr/bin/env bash
# One entry point for a fresh machine with Python 3.11: creates .venv, installs, runs.
#   bash run.sh main    install and run the main job
#   bash run.sh test    install (with the dev extra) and run the test suite
set -euo pipefail
cd "$(dirname "$0")"
PY="${PYTHON:-$(command -v python3.11 || command -v python3)}"
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
what="${1:-main}"
shift || true
case "$what" in
  main)
    .venv/bin/python -m pip install -q --disable-pip-version-check -e .
    # The main job: generate circle + sine, run IML, IML+IR, IML+PGO, IML+IR+PGO with the shipped
    # networks, print the paper's Table III layout and write the Fig. 5 / Fig. 6 plots (out/demo).
    exec .venv/bin/python -m rhaml_jax.demo "$@"
    ;;
  test)
    .venv/bin/python -m pip install -q --disable-pip-version-check -e '.[dev]'
    # XLA compiles dominate the suite; a persistent cache makes reruns on this machine fast.
    export JAX_COMPILATION_CACHE_DIR="${JAX_COMPILATION_CACHE_DIR:-$HOME/.cache/rhaml_jax/xla}"
    export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="${JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS:-1}"
    # Test files spread over RHAML_TEST_WORKERS processes (default 2, this machine's cores; each
    # peaks at a few GB), a file's tests in one process so its module fixtures are built once.
    exec .venv/bin/python -m pytest -q -n "${RHAML_TEST_WORKERS:-2}" --dist loadfile "$@"
    ;;
  *)
    echo "usage: bash run.sh main|test" >&2
    exit 2
    ;;
esac
