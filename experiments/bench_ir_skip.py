"""IR's cost per frame as the pipeline runs it, side by side: the default stage (`refine.load_stage`)
on frames vmapped together (session 48's pipeline), one at a time, and one at a time with the
alignment skipped where its start already fits the segmenter's mask (`AlignConfig.skip_iou`, the
default now). Medians of interleaved rounds in one process, so their ratios hold on a busy machine.

    python experiments/bench_ir_skip.py --data DIR --iml-json RUN.json [--data DIR --iml-json RUN.json ...]
        [--frames 32] [--repeats 3] [--json out.json]

Frames: `--frames` of each set's frames that the stored pipeline run (`evaluate --json`) detected,
spread evenly over the set, each started from its IML estimate (`iml_est`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import data, refine

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import interleaved  # noqa: E402


def load(root: Path, run: Path, n: int):
    """(images (n, H, W, 3) uint8, K (n, 3, 3), IML estimates (n, 3)): n detected frames spread over the set."""
    rows = {(r["scene_id"], r["im_id"]): r for r in json.loads(run.read_text())["frames"]}
    fr = [f for f in data.read_bop(root) if f.observed and rows[(f.scene_id, f.im_id)]["detected"]]
    fr = fr[:: max(len(fr) // n, 1)][:n]
    return (np.stack([data.load_rgb(f.rgb) for f in fr]), np.stack([f.K for f in fr]).astype(np.float32),
            np.asarray([rows[(f.scene_id, f.im_id)]["iml_est"] for f in fr], np.float32))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, action="append", required=True)
    p.add_argument("--iml-json", type=Path, action="append", required=True)
    p.add_argument("--frames", type=int, default=32)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args()
    if len(a.data) != len(a.iml_json):
        raise SystemExit("give one --iml-json per --data")
    cfg, sp = refine.load_stage()
    no_skip = dataclasses.replace(cfg, align=dataclasses.replace(cfg.align, skip_iou=None))
    variants = {"vmapped, no skip": (no_skip, a.frames), "one at a time, no skip": (no_skip, 1), "one at a time, skip": (cfg, 1)}

    def compiled(c, batch):
        def one(x):
            image, K, init = x
            r = refine.refine_stage(c, sp, image, K, init)
            return r.xypsi, r.align_skipped
        return jax.jit(lambda *x: jax.lax.map(one, x, batch_size=None if batch == 1 else batch))  # 1: unbatched, cond branches

    fns = {k: compiled(*v) for k, v in variants.items()}
    out = {}
    for root, run in zip(a.data, a.iml_json):
        x = tuple(jnp.asarray(v) for v in load(root, run, a.frames))
        res = {k: jax.block_until_ready(f(*x)) for k, f in fns.items()}  # compiles each
        sec = interleaved({k: (lambda f=f: f(*x)) for k, f in fns.items()}, a.repeats)
        (plain, _), (skip, skipped) = res["one at a time, no skip"], res["one at a time, skip"]
        out[str(root)] = {"frames": len(x[0]), "skipped": int(np.sum(skipped)),
                          "ms_per_frame": {k: round(1e3 * v / len(x[0]), 1) for k, v in sec.items()},
                          "max_position_change_m": float(jnp.abs(skip[:, :2] - plain[:, :2]).max())}
        print(root, json.dumps(out[str(root)]), flush=True)
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
