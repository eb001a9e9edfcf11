"""The silhouette alignment's cost, side by side: `refine.SEGMENTER_ALIGN` (the alignment from a
refiner cascade's end) with central and with forward finite differences (`AlignConfig.fd`),
without the mirrored hypotheses, and with its soft silhouettes culled (`AlignConfig.cull`; the
others not), on one frame and on a vmapped batch. Medians of interleaved
rounds in one process (so their ratios hold on a busy machine), and each variant's error from
starts a few centimetres and degrees off the truth (targets: our hard masks at the true poses).

    python experiments/bench_align_speed.py [--repeats 7] [--batch 8] [--json out.json]
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

from rhaml_jax import render
from rhaml_jax.camera import DEFAULT_CAMERA as CAM
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine import SEGMENTER_ALIGN
from rhaml_jax.refine.alignment import align_crop, crop_box, params_from_xypsi, pose_from_params
from rhaml_jax.robots import load_robot

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import interleaved  # noqa: E402


def frames(n: int, seed: int = 0):
    """n true planar poses 2-6 m away in view, starts off by the cascade's typical residual
    (range 1-3 %, bearing 0.5 deg, heading 3-25 deg: the headings the alignment is kept for)."""
    rng = np.random.default_rng(seed)
    r, b, psi = rng.uniform(2.0, 6.0, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-np.pi, np.pi, n)
    gt = np.stack([r * np.cos(b), r * np.sin(b), psi], 1).astype(np.float32)
    dr = rng.choice([-1, 1], n) * rng.uniform(0.01, 0.03, n)
    db, dpsi = rng.normal(0, np.deg2rad(0.5), n), rng.choice([-1, 1], n) * np.deg2rad(rng.uniform(3, 25, n))
    rs, bs = r * (1 + dr), b + db
    init = np.stack([rs * np.cos(bs), rs * np.sin(bs), psi + dpsi], 1).astype(np.float32)
    return gt, init


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--json", default=None)
    a = p.parse_args()
    mesh = render.as_mesh(load_robot("pioneer3dx"))
    K = jnp.asarray(CAM.K, jnp.float32)
    gt, init = frames(a.batch)
    S = SEGMENTER_ALIGN.crop

    # the targets: hard masks at the true poses in the crop every variant uses (they share crop, margin, camera)
    boxes = jax.vmap(lambda x: crop_box(mesh, K, x, SEGMENTER_ALIGN))(jnp.asarray(gt))
    T = pose_from_params(params_from_xypsi(jnp.asarray(gt)), SEGMENTER_ALIGN.camera_height_m)
    masks = jax.vmap(lambda t, b: render.render(mesh, t, K, S, S, box=b).mask)(T, boxes).astype(jnp.float32)
    variants = {f"fd {fd}": dataclasses.replace(SEGMENTER_ALIGN, fd=fd, min_turn=0.0, max_shift=None, cull=False)
                for fd in ("central", "forward")}
    variants["fd forward, no mirrored hypotheses"] = dataclasses.replace(variants["fd forward"], mirror=False)
    variants["fd forward, culled soft silhouettes"] = dataclasses.replace(variants["fd forward"], cull=True)
    calls = {}
    for name, cfg in variants.items():
        fn = jax.jit(jax.vmap(lambda m, b, i, cfg=cfg: align_crop(mesh, m, b, K, i, CAM.width, CAM.height, cfg).xypsi))
        one = (masks[:1], boxes[:1], jnp.asarray(init[:1]))
        many = (masks, boxes, jnp.asarray(init))
        calls[name] = (fn, one, many)
        jax.block_until_ready(fn(*one)), jax.block_until_ready(fn(*many))  # compile both shapes
    # interleaved: each round times every variant once, on one frame and on the batch
    sec = interleaved({(name, key): (lambda fn=fn, args=args: fn(*args)) for name, (fn, one, many) in calls.items()
                       for key, args in (("one", one), ("batch", many))}, a.repeats)
    rows = []
    for name, (fn, _, many) in calls.items():
        d = np.asarray(fn(*many)) - gt
        rows.append({"variant": name, "ms_one_frame": 1e3 * sec[(name, "one")],
                     "ms_per_frame_batched": 1e3 * sec[(name, "batch")] / a.batch,
                     "dxy_cm_mean": float(100 * np.hypot(d[:, 0], d[:, 1]).mean()),
                     "dpsi_deg_mean": float(np.rad2deg(np.abs(wrap_angle(d[:, 2]))).mean())})
        print(json.dumps(rows[-1]), flush=True)
    base = rows[0]["ms_one_frame"]
    for r in rows:
        r["speedup_one_frame"] = base / r["ms_one_frame"]
    out = {"batch": a.batch, "repeats": a.repeats, "rows": rows, "devices": str(jax.devices())}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
