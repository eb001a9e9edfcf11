"""`tune_allocator`: after it, freeing and reallocating a large buffer reuses the same pages
(no new page faults); without it glibc returns them to the kernel (mmap) and faults again."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = r"""
import resource, sys
import numpy as np
np._core.multiarray._set_madvise_hugepage(False)  # 4 KB pages, so faults count pages
if sys.argv[1] == "tuned":
    from rhaml_jax.allocator import tune_allocator
    assert tune_allocator() and tune_allocator()  # applied, and idempotent
for i in range(3):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(64 << 20, np.uint8)  # 64 MB, touched
    del a
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(faults)
"""


def _faults(mode: str) -> int:
    """Page faults of the last of three 64 MB allocations in a child process; mode "env": the
    system allocator configured by `MALLOC_ENV` (what the benchmark gives PyTorch)."""
    from rhaml_jax.allocator import MALLOC_ENV

    env = {**os.environ, **MALLOC_ENV} if mode == "env" else {k: v for k, v in os.environ.items() if k not in MALLOC_ENV}
    out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True, env=env)
    return int(out.stdout.strip().splitlines()[-1])


def _thp_always() -> bool:
    try:
        return "[always]" in Path("/sys/kernel/mm/transparent_hugepage/enabled").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning is Linux-only")
def test_tuned_allocator_reuses_pages():
    pages = (64 << 20) // 4096
    if not _thp_always():  # with transparent huge pages always on, a fresh mmap faults ~32 times
        assert _faults("system") > pages // 2  # a fresh mmap every time: the test can fail
    assert _faults("tuned") < pages // 20
    assert _faults("env") < pages // 20


def test_opt_out(monkeypatch):
    import rhaml_jax.allocator as alloc

    monkeypatch.setattr(alloc, "_applied", False)
    monkeypatch.setenv("RHAML_JAX_MALLOC", "system")
    assert alloc.tune_allocator() is False
