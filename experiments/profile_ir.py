"""Where IR's time goes, frame by frame as the pipeline runs it: the default stage (`refine.load_stage`)
with its parts removed one at a time, the alignment's building blocks alone, and optionally the
alignment with other step schedules. Medians of interleaved rounds in one process (ratios hold on a
busy machine); frames as `bench_ir_skip.py` picks them.

    python experiments/profile_ir.py --data DIR --iml-json RUN.json [--frames 16] [--repeats 3]
        [--stages 3,3,2,2 ...] [--cull] [--json out.json]

`--stages A,B,C,D`: the default alignment (`refine.SEGMENTER_ALIGN`) with these LM steps in its four
stages, its ms per frame, and how far its estimates move from the default's (largest position
change, frames whose heading moves by more than 1 deg). `--cull`: the default stage with its
alignment's soft silhouettes culled (`AlignConfig.cull`) and not, and with no back faces culled
at all (the model's `Mesh.winding` 0: the hard renders too), moved as the schedules are.
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

from rhaml_jax import refine, render
from rhaml_jax.refine import alignment as A
from rhaml_jax.refine.segmenter import alignment_target

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import interleaved  # noqa: E402
from bench_ir_skip import load  # noqa: E402


def stage_variants(cfg, sp, schedules: list[str], cull: bool = False) -> dict:
    """Name -> (RefineConfig, StageParams): the default, its parts removed, other schedules, culling."""
    R = dataclasses.replace
    bare = sp._replace(segmenter=None)
    fine = sp.fine[0] if isinstance(sp.fine, tuple) else sp.fine
    out = {"default": (cfg, sp), "no alignment": (R(cfg, align=None), bare),
           "no alignment, no scorer": (R(cfg, align=None), bare._replace(scorer=None)),
           "no alignment, no scorer, one fine refiner": (R(cfg, align=None), bare._replace(scorer=None, fine=fine)),
           "no alignment, no scorer, no fine refiner": (R(cfg, align=None), bare._replace(scorer=None, fine=None))}
    for text in schedules:
        steps = [int(v) for v in text.split(",")]
        if len(steps) != len(cfg.align.stages):
            raise SystemExit(f"--stages {text}: give {len(cfg.align.stages)} step counts")
        stages = tuple((st[0], n, *st[2:]) for st, n in zip(cfg.align.stages, steps))
        out[f"alignment steps {text}"] = (R(cfg, align=R(cfg.align, stages=stages)), sp)
    if cull:
        for on in (True, False):
            out[f"alignment cull {on}"] = (R(cfg, align=R(cfg.align, cull=on)), sp)
        out["alignment cull False, no hard culling"] = (R(cfg, align=R(cfg.align, cull=False)),
                                                         sp._replace(mesh=sp.mesh._replace(winding=jnp.float32(0.0))))
    return out


def blocks(cfg, sp) -> dict:
    """Name -> f(image uint8, K, xypsi): the alignment's building blocks at one pose."""
    ac, mesh = cfg.align, sp.mesh

    def box(K, x):
        return A.crop_box(mesh, K, x, ac)

    def hard(K, x, ss):
        return A._hard(mesh, K, box(K, x), A.params_from_xypsi(x)[None], ac.camera_height_m, ac.crop, ss)

    return {"segmenter's mask": lambda i, K, x: alignment_target(sp.segmenter, i.astype(jnp.float32) / 255, box(K, x), ac.crop,
                                                                   cfg.mask_threshold),
            f"hard silhouette {4 * ac.crop} px (the skip test's, 4x4 per crop pixel)": lambda i, K, x: hard(K, x, 4),
            **{f"soft silhouette {ac.crop} px{', culled' if c else ''}": lambda i, K, x, c=c: render.silhouette(
                mesh, A.pose_from_params(A.params_from_xypsi(x)[None], ac.camera_height_m), K, ac.crop, ac.crop, box=box(K, x),
                sharpness=8.0, config=render.RenderConfig(soft_cull=c)) for c in (False, True)}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--iml-json", type=Path, required=True)
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--stages", nargs="*", default=[])
    p.add_argument("--cull", action="store_true")
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args()
    cfg, sp = refine.load_stage()
    x = tuple(jnp.asarray(v) for v in load(a.data, a.iml_json, a.frames))

    def per_frame(f):  # one frame at a time (lax.map without a batch size), as the pipeline runs IR
        return jax.jit(lambda *xs: jax.lax.map(lambda t: f(*t), xs))

    stages = {k: per_frame(lambda i, K, s, c=c, q=q: refine.refine_stage(c, q, i, K, s).xypsi)
              for k, (c, q) in stage_variants(cfg, sp, a.stages, a.cull).items()}
    parts = {k: per_frame(f) for k, f in blocks(cfg, sp).items()}
    fns = stages | parts
    res = {k: jax.block_until_ready(f(*x)) for k, f in fns.items()}  # compiles each
    sec = interleaved({k: (lambda f=f: f(*x)) for k, f in fns.items()}, a.repeats)
    ref = np.asarray(res["default"])
    moved = {k: {"max_position_change_cm": round(100 * float(np.hypot(*(np.asarray(res[k])[:, :2] - ref[:, :2]).T).max()), 2),
                 "frames_heading_moved_over_1deg": int(np.sum(np.degrees(np.abs(np.angle(np.exp(1j * (np.asarray(res[k])[:, 2]
                                                                                                    - ref[:, 2]))))) > 1))}
             for k in stages if k.startswith("alignment ")}
    out = {"data": str(a.data), "frames": len(x[0]), "ms_per_frame": {k: round(1e3 * v / len(x[0]), 2) for k, v in sec.items()},
           "schedules": moved}
    print(json.dumps(out, indent=1))
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
