#!/usr/bin/env python3
"""The matrix-product floor of an AMLNet step: how fast could the step be if everything but
its matrix products were free?

  python experiments/gemm_floor.py [--config paper] [--batch 8] [--rounds 3] [--no-torch] [--json OUT]

Compiles the training step (gradient jit) and inference as `bench_amlnet.py` does, reads every
`dot` out of XLA's optimised HLO (inside fusions included), and times each distinct product
(shapes and contracting dimensions as compiled) on its own: with XLA (`lax.dot_general`) and
with PyTorch's CPU GEMM (`torch.matmul` on transposed views, this process, 2 threads). The
sum over the step's products is its floor with that library's GEMM. Rounds interleave the
JAX step, PyTorch's whole step (../shared/bench/torch_amlnet.py as shipped, a subprocess) and
both sweeps of products; every figure is a median over rounds.

The bound printed last: the best training-step ratio JAX / PyTorch any change to the
non-product work could reach here = PyTorch's step time / JAX's product floor. Layouts are
the default row-major ones (the compiled step may pick others for a product; the sweep is
what XLA does with the plain product of those shapes).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import statistics
import sys
import time
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))
sys.path.insert(0, str(ROOT))

from bench_amlnet import torch_run  # noqa: E402
from rhaml_jax.allocator import tune_allocator  # noqa: E402
from rhaml_jax.amlnet.bench import ModelBench, median_seconds  # noqa: E402
from rhaml_jax.amlnet.config import get_config  # noqa: E402
from rhaml_jax.amlnet.count import count_macs  # noqa: E402


class Dot(NamedTuple):
    lhs: tuple[int, ...]
    rhs: tuple[int, ...]
    lhs_contract: tuple[int, ...]
    rhs_contract: tuple[int, ...]
    lhs_batch: tuple[int, ...]
    rhs_batch: tuple[int, ...]
    dtype: str

    @property
    def macs(self) -> int:
        free_l = [n for i, n in enumerate(self.lhs) if i not in self.lhs_contract + self.lhs_batch]
        free_r = [n for i, n in enumerate(self.rhs) if i not in self.rhs_contract + self.rhs_batch]
        return math.prod(self.lhs[i] for i in self.lhs_batch + self.lhs_contract) * math.prod(free_l) * math.prod(free_r)

    @property
    def role(self) -> str:
        """Weight gradients (x^T g) contract the long pixel axis of both operands; forward and
        input-gradient products contract channels."""
        return "weight grad" if self.lhs_contract == self.rhs_contract == (0,) else "forward / input grad"


_DTYPES = {"f32": "float32", "f64": "float64", "bf16": "bfloat16", "f16": "float16"}
_INSTR = re.compile(r"^\s*(?:ROOT )?%([\w.\-]+) = (\w+)\[([\d,]*)\]")
_DOT = re.compile(r" dot\(%([\w.\-]+), %([\w.\-]+)\)")


def _dims(line: str, key: str) -> tuple[int, ...]:
    m = re.search(key + r"=\{([\d,]*)\}", line)
    return tuple(int(i) for i in m.group(1).split(",") if i) if m else ()


def hlo_dots(hlo: str) -> Counter:
    """Every dot of an optimised HLO module (one per occurrence) as a Counter of `Dot`s."""
    dots: Counter = Counter()
    for comp in re.split(r"\n(?=\S)", hlo):  # computations start at column 0
        shapes = {}
        for line in comp.split("\n"):
            m = _INSTR.match(line)
            if not m:
                continue
            shapes[m.group(1)] = (m.group(2), tuple(int(s) for s in m.group(3).split(",") if s))
            d = _DOT.search(line)
            if d:
                (dt, lhs), (_, rhs) = shapes[d.group(1)], shapes[d.group(2)]
                dots[Dot(lhs, rhs, _dims(line, "lhs_contracting_dims"), _dims(line, "rhs_contracting_dims"),
                         _dims(line, "lhs_batch_dims"), _dims(line, "rhs_batch_dims"), _DTYPES[dt])] += 1
    return dots


def _median_call(f, runs: int) -> float:
    """Median seconds per call; a sample is enough back-to-back calls to fill ~50 ms, so
    that a small product's dispatch latency does not count as its arithmetic."""
    jax.block_until_ready(f())
    t = time.perf_counter()
    jax.block_until_ready(f())
    reps = max(1, min(1000, int(0.05 / max(time.perf_counter() - t, 1e-6))))

    def sample():
        for _ in range(reps - 1):
            f()
        return f()

    return median_seconds(sample, runs)[0] / reps


def time_jax(dot: Dot, runs: int) -> float:
    a = jax.random.normal(jax.random.key(0), dot.lhs, dot.dtype)
    b = jax.random.normal(jax.random.key(1), dot.rhs, dot.dtype)
    dn = ((dot.lhs_contract, dot.rhs_contract), (dot.lhs_batch, dot.rhs_batch))
    f = jax.jit(lambda a, b: jax.lax.dot_general(a, b, dn))
    return _median_call(lambda: f(a, b), runs)


def time_torch(dot: Dot, runs: int) -> float:
    import torch

    if dot.lhs_batch or len(dot.lhs) != 2 or len(dot.rhs) != 2:
        raise ValueError(f"time_torch: only 2-D products without batch dimensions, got {dot}")
    a, b = torch.randn(*dot.lhs), torch.randn(*dot.rhs)
    a = a if dot.lhs_contract == (1,) else a.T  # transposed views: BLAS takes them without copying
    b = b if dot.rhs_contract == (0,) else b.T
    return _median_call(lambda: a @ b, runs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="paper")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--runs", type=int, default=5, help="timed calls per product (and 3 per step) per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--no-torch", action="store_true")
    ap.add_argument("--cache", default="/tmp/rhaml_jax_cache", help="JAX persistent compilation cache ('' = off)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    tune_allocator()
    if args.cache:  # the step is compiled twice (.lower().compile() for its HLO, then by the call)
        jax.config.update("jax_compilation_cache_dir", args.cache)
    use_torch = not args.no_torch
    if use_torch:
        import torch

        torch.set_num_threads(2)
    cfg = get_config(args.config)
    b = ModelBench(cfg, args.batch)
    lowered = {
        "train": b.steps.grad_step.lower(b.params, b.stats, b.images, b.observed, b.pose, b.key),
        "inference": b.steps.predict.lower(b.params, b.stats, b.images),
    }
    dots = {k: hlo_dots(v.compile().as_text()) for k, v in lowered.items()}
    fwd_macs = count_macs(cfg) * args.batch
    res = {"config": cfg.name, "batch": args.batch, "command": "python " + " ".join(sys.argv),
           "model_macs": {"inference": fwd_macs, "train (3x forward)": 3 * fwd_macs}}
    for k, c in dots.items():
        res[f"{k}_dots"] = sum(c.values())
        res[f"{k}_dot_macs"] = sum(d.macs * n for d, n in c.items())
    shapes = sorted(set(dots["train"]) | set(dots["inference"]))
    t = {lib: {d: [] for d in shapes} for lib in ("jax", "torch")}
    step = {"jax_train": [], "jax_inference": [], "torch_train": [], "torch_inference": []}
    for r in range(args.rounds):
        step["jax_inference"] += b.inference_s(3)
        step["jax_train"] += b.train_s(3)
        if use_torch and cfg.name == "paper":  # the PyTorch script builds the paper network only
            step["torch_inference"].append(torch_run(args, False, 3)["s_per_batch"])
            step["torch_train"].append(torch_run(args, True, 3)["s_per_batch"])
        for d in shapes:
            t["jax"][d].append(time_jax(d, args.runs))
            if use_torch:
                t["torch"][d].append(time_torch(d, args.runs))
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)
    med = {lib: {d: statistics.median(v) for d, v in tl.items() if v} for lib, tl in t.items()}
    for name, v in step.items():
        if v:
            res[f"{name}_s"] = statistics.median(v)
    for k, c in dots.items():
        for lib in ("jax", "torch") if use_torch else ("jax",):
            floor = sum(med[lib][d] * n for d, n in c.items())
            res[f"{k}_{lib}_gemm_floor_s"] = floor
            res[f"{k}_{lib}_gemm_gmacs"] = res[f"{k}_dot_macs"] / floor / 1e9
        res[f"{k}_jax_step_over_its_floor"] = res[f"jax_{k}_s"] / res[f"{k}_jax_gemm_floor_s"]
        if step["torch_train"]:
            res[f"{k}_torch_step_over_its_floor"] = res[f"torch_{k}_s"] / res[f"{k}_torch_gemm_floor_s"]
            res[f"{k}_measured_ratio_jax_over_torch"] = res[f"torch_{k}_s"] / res[f"jax_{k}_s"]
            res[f"{k}_best_ratio_with_xla_gemm"] = res[f"torch_{k}_s"] / res[f"{k}_jax_gemm_floor_s"]
    rows = []
    for d, n in dots["train"].items():
        row = {"role": d.role, "lhs": d.lhs, "rhs": d.rhs, "count": n, "gmac": d.macs * n / 1e9,
               "jax_ms": 1e3 * med["jax"][d] * n, "jax_gmacs": d.macs / med["jax"][d] / 1e9}
        if use_torch:
            row |= {"torch_ms": 1e3 * med["torch"][d] * n, "torch_gmacs": d.macs / med["torch"][d] / 1e9}
        rows.append(row)
    res["train_products_by_jax_time"] = sorted(rows, key=lambda r: -r["jax_ms"])
    by_role = {}
    for r in rows:
        a = by_role.setdefault(r["role"], {"gmac": 0.0, "jax_ms": 0.0, "torch_ms": 0.0})
        a["gmac"] += r["gmac"]
        a["jax_ms"] += r["jax_ms"]
        a["torch_ms"] += r.get("torch_ms", np.nan)
    res["train_by_role"] = by_role
    text = json.dumps(res, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)


if __name__ == "__main__":
    main()
