"""The compiled-program cache of the command-line tools: where it lives, that it is off when asked,
that a second process loads what the first compiled, and that a directory the user gave JAX wins."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from rhaml_jax.compile_cache import CACHE_ENV, cache_dir

ROOT = Path(__file__).resolve().parents[1]

# one process: the cache on (as run_cli turns it on), one program compiled, the cache's hits and
# misses counted from JAX's monitoring events; every program stored, however quick its compile
_PROBE = """
import json, jax, jax.numpy as jnp
from jax import monitoring
from rhaml_jax.compile_cache import enable_compile_cache
events = []
monitoring.register_event_listener(lambda name, **kw: events.append(name))
where = enable_compile_cache()
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.jit(lambda x: jnp.tanh(x @ x.T).sum())(jnp.ones((8, 8)))
print(json.dumps({"dir": str(where) if where else None, "hits": events.count("/jax/compilation_cache/cache_hits"),
                  "misses": events.count("/jax/compilation_cache/cache_misses")}))
"""


def _probe(env: dict) -> dict:
    full = {k: v for k, v in os.environ.items() if k not in (CACHE_ENV, "JAX_COMPILATION_CACHE_DIR")} | env
    full["PYTHONPATH"] = str(ROOT) + os.pathsep + full.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=full, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, "off")
    assert cache_dir() is None
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine"
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "rhaml_jax" / "xla"


def test_a_second_process_loads_what_the_first_compiled(tmp_path):
    env = {CACHE_ENV: str(tmp_path / "xla")}
    first, second = _probe(env), _probe(env)
    assert first["dir"] == str(tmp_path / "xla") and first["hits"] == 0 and first["misses"] >= 1
    assert second["hits"] >= 1 and second["misses"] == 0
    assert any((tmp_path / "xla").iterdir())


def test_off_and_the_users_own_directory(tmp_path):
    off = _probe({CACHE_ENV: "off", "XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert off == {"dir": None, "hits": 0, "misses": 0} and not (tmp_path / "xdg").exists()
    own = _probe({"JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax_own"), CACHE_ENV: str(tmp_path / "ours")})
    assert own["dir"] == str(tmp_path / "jax_own") and not (tmp_path / "ours").exists()


def test_every_command_runs_with_the_cache_on(tmp_path):
    """run_cli, which every `python -m rhaml_jax.X` goes through, turns it on before the command."""
    code = "import jax; from rhaml_jax.errors import run_cli; run_cli(lambda: print(jax.config.jax_compilation_cache_dir))"
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"} | {
        CACHE_ENV: str(tmp_path / "xla"), "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.strip() == str(tmp_path / "xla")
