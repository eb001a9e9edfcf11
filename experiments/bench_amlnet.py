#!/usr/bin/env python3
"""AMLNet speed: JAX (this package) vs PyTorch eager (../shared/bench/torch_amlnet.py), side
by side in one run, plus the machine's matmul ceiling and the depthwise-kernel alternatives.

  python experiments/bench_amlnet.py [--config paper] [--batch 8] [--runs 3] [--rounds 2]
      [--fused] [--kernels] [--no-torch] [--system-malloc] [--json OUT]

Rounds interleave JAX inference, torch inference, JAX training step, torch training step, so
that load from other processes hits both alike; every figure is a median over all timed calls
(PyTorch's: medians over rounds of its script's mean over --runs calls). This process calls
rhaml_jax.allocator.tune_allocator (as the package's command-line tools do) unless
--system-malloc; PyTorch runs twice per round, as shipped and with the same glibc settings
through the environment, and both ratios are reported.
Training MACs are counted as 3x the forward MACs (forward + two backward products).
--fused also times the training step as ONE jit (value_and_grad + AdamW), the variant that was
~6x slower on XLA's CPU backend; --kernels times the depthwise / ACN alternatives alone.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TORCH_SCRIPT = ROOT.parent / "shared" / "bench" / "torch_amlnet.py"

from rhaml_jax.allocator import MALLOC_ENV, tune_allocator  # noqa: E402
from rhaml_jax.amlnet import ops  # noqa: E402
from rhaml_jax.amlnet.acn import acn, acn_reference, init_acn_params  # noqa: E402
from rhaml_jax.amlnet.bench import ModelBench, matmul_gmacs, median_seconds  # noqa: E402
from rhaml_jax.amlnet.config import get_config  # noqa: E402
from rhaml_jax.amlnet.count import count_macs  # noqa: E402

TORCH_MATMUL = """
import time, torch, statistics, json
torch.set_num_threads(2)
a = torch.randn(2048, 2048); b = torch.randn(2048, 2048); a @ b
ts = []
for _ in range(5):
    t = time.perf_counter(); a @ b; ts.append(time.perf_counter() - t)
print(json.dumps({"gmacs": 2048**3 / statistics.median(ts) / 1e9}))
"""


def torch_run(args, train: bool, runs: int, tuned_malloc: bool = False) -> dict:
    cmd = [sys.executable, str(TORCH_SCRIPT), "--batch", str(args.batch), "--size", "224", "--runs", str(runs)]
    if train:
        cmd.append("--train")
    # PyTorch's CPU tensors come from malloc too: as shipped, or with our settings
    env = {k: v for k, v in os.environ.items() if k not in MALLOC_ENV}
    r = subprocess.run(cmd, capture_output=True, text=True, check=True, env={**env, **MALLOC_ENV} if tuned_malloc else env)
    return json.loads(r.stdout.strip().splitlines()[-1])


def acn_taps_first(p, x, kernels, dense):
    """The first fast dense ACN (kept for comparison): one matmul for the mixing logits and
    every tap, then shifted-slice sums."""
    from jax import lax
    from rhaml_jax.amlnet.acn import _mix_weights

    n, c = len(kernels), x.shape[-1]
    mats = [p["mix"]] + [p[f"{u}{k}"].transpose(1, 0, 2).reshape(c, k * c) for u in "xy" for k in kernels]
    z = jnp.einsum("bhwc,cd->bhwd", x, jnp.concatenate(mats, axis=1))
    m = _mix_weights(z[..., : 2 * n], n)
    taps, out = sum(kernels), x
    for ui, (u, axis) in enumerate((("x", 2), ("y", 1))):
        zu = lax.slice_in_dim(z, 2 * n + ui * taps * c, 2 * n + (ui + 1) * taps * c, axis=3)
        off = 0
        for v, k in enumerate(kernels):
            out = out + m[..., ui, v, None] * (ops.shifted_tap_sum(zu, k, c, axis, offset=off) + p[f"b{u}{k}"])
            off += k
    return out


def kernels_bench(runs: int) -> list[dict]:
    """Depthwise 1x11 and dense ACN (K = 3, 5, 7) at stage-1 and stage-3 shapes of the paper
    network (batch 8): XLA grouped/dense conv vs the fast formulations, forward only."""
    rows = []
    for name, (hw, c) in {"stage1": (56, 96), "stage3": (14, 384)}.items():
        g = c // 8
        x = jax.random.normal(jax.random.key(0), (8, hw, hw, g))
        w = jax.random.normal(jax.random.key(1), (11, g))
        macs = 8 * hw * hw * g * 11
        for label, f in (("depthwise 1x11: lax grouped conv", ops.depthwise_1d_ref), ("depthwise 1x11: shifted slices", ops.depthwise_1d)):
            jf = jax.jit(lambda x, w, f=f: f(x, w, None, 2))
            jax.block_until_ready(jf(x, w))
            med, _ = median_seconds(lambda: jf(x, w), runs)
            rows.append({"shape": name, "op": label, "ms": 1e3 * med, "gmacs": macs / med / 1e9})
        p = init_acn_params(jax.random.key(2), g, (3, 5, 7), True)
        macs = 8 * hw * hw * (30 * g * g + 6 * g)
        for label, f in (("dense ACN K=3,5,7: 6 lax convs (reference)", acn_reference), ("dense ACN K=3,5,7: im2col matmul (used)", acn),
                         ("dense ACN K=3,5,7: taps-first matmul", acn_taps_first)):
            jf = jax.jit(lambda p, x, f=f: f(p, x, (3, 5, 7), True))
            jax.block_until_ready(jf(p, x))
            med, _ = median_seconds(lambda: jf(p, x), runs)
            rows.append({"shape": name, "op": label, "ms": 1e3 * med, "gmacs": macs / med / 1e9})
        # im2col alternative for one 1x7 dense conv (concatenate the 7 shifted inputs, one matmul)
        wd = jax.random.normal(jax.random.key(3), (7, g, g))

        def im2col(x, wd):
            xp = jnp.pad(x, ((0, 0), (0, 0), (3, 3), (0, 0)))
            cols = jnp.concatenate([xp[:, :, j:j + hw] for j in range(7)], axis=-1)
            return cols @ wd.reshape(7 * g, g)

        macs = 8 * hw * hw * 7 * g * g
        for label, f in (("dense 1x7: lax conv", lambda x, w: ops.dense_1d_ref(x, w, None, 2)),
                         ("dense 1x7: im2col + matmul", im2col),
                         ("dense 1x7: taps-first matmul", lambda x, w: ops.dense_1d(x, w, None, 2))):
            jf = jax.jit(f)
            jax.block_until_ready(jf(x, wd))
            med, _ = median_seconds(lambda: jf(x, wd), runs)
            rows.append({"shape": name, "op": label, "ms": 1e3 * med, "gmacs": macs / med / 1e9})
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="paper")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--runs", type=int, default=3, help="timed calls per round and mode")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--fused", action="store_true")
    ap.add_argument("--kernels", action="store_true")
    ap.add_argument("--no-torch", action="store_true")
    ap.add_argument("--system-malloc", action="store_true", help="do not call rhaml_jax.allocator.tune_allocator")
    ap.add_argument("--cache", default="/tmp/rhaml_jax_cache", help="JAX persistent compilation cache ('' = off)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    malloc_tuned = False if args.system_malloc else tune_allocator()
    if args.cache:
        jax.config.update("jax_compilation_cache_dir", args.cache)
    cfg = get_config(args.config)
    use_torch = not args.no_torch and args.config == "paper" and cfg.input_hw == (224, 224)
    res = {"config": cfg.name, "batch": args.batch, "command": "python " + " ".join(sys.argv), "jax_malloc_tuned": malloc_tuned}
    res["macs_per_image"] = macs = count_macs(cfg)
    res["jax_matmul_gmacs"] = matmul_gmacs()
    if use_torch:
        res["torch_matmul_gmacs"] = json.loads(subprocess.run([sys.executable, "-c", TORCH_MATMUL], capture_output=True, text=True, check=True).stdout)["gmacs"]
    b = ModelBench(cfg, args.batch)
    t0 = time.perf_counter()
    b.inference_s(1)
    b.train_s(1)
    res["jax_compile_and_first_calls_s"] = time.perf_counter() - t0
    res["jax_compile_s"] = dict(b.compile_s)
    ji, jt, ti, tt, jf, tti, ttt, faults = [], [], [], [], [], [], [], []
    for r in range(args.rounds):
        ji += b.inference_s(args.runs)
        if use_torch:
            ti.append(torch_run(args, False, args.runs)["s_per_batch"])
            tti.append(torch_run(args, False, args.runs, tuned_malloc=True)["s_per_batch"])
        flt = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        jt += b.train_s(args.runs)
        faults.append((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - flt) / args.runs)
        if use_torch:
            tt.append(torch_run(args, True, args.runs)["s_per_batch"])
            ttt.append(torch_run(args, True, args.runs, tuned_malloc=True)["s_per_batch"])
        if args.fused:
            jf += b.train_s(args.runs, fused=True)
        print(f"round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)
    med = statistics.median
    res["jax_inference_s"] = ji
    res["jax_train_s"] = jt
    res["jax_train_minor_page_faults_per_step"] = faults  # per round: kernel page faults of this process
    res["jax_inference_images_per_s"] = args.batch / med(ji)
    res["jax_train_images_per_s"] = args.batch / med(jt)
    res["jax_inference_gmacs"] = macs * args.batch / med(ji) / 1e9
    res["jax_train_gmacs"] = 3 * macs * args.batch / med(jt) / 1e9
    res["jax_inference_fraction_of_matmul"] = res["jax_inference_gmacs"] / res["jax_matmul_gmacs"]
    res["jax_train_fraction_of_matmul"] = res["jax_train_gmacs"] / res["jax_matmul_gmacs"]
    if args.fused:
        res["jax_train_fused_s"] = jf
        res["jax_train_fused_images_per_s"] = args.batch / med(jf)
        res["jax_compile_s"] = dict(b.compile_s)
    if use_torch:
        res["torch_inference_s"] = ti
        res["torch_train_s"] = tt
        res["torch_inference_images_per_s"] = args.batch / med(ti)
        res["torch_train_images_per_s"] = args.batch / med(tt)
        res["torch_inference_gmacs"] = macs * args.batch / med(ti) / 1e9
        res["torch_train_gmacs"] = 3 * macs * args.batch / med(tt) / 1e9
        res["inference_ratio_jax_over_torch"] = med(ti) / med(ji)
        res["train_ratio_jax_over_torch"] = med(tt) / med(jt)
        res["torch_tuned_malloc_inference_s"] = tti
        res["torch_tuned_malloc_train_s"] = ttt
        res["inference_ratio_jax_over_torch_tuned_malloc"] = med(tti) / med(ji)
        res["train_ratio_jax_over_torch_tuned_malloc"] = med(ttt) / med(jt)
    if args.kernels:
        res["kernels"] = kernels_bench(args.runs * args.rounds)
    text = json.dumps(res, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)


if __name__ == "__main__":
    main()
