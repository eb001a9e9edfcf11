"""How far apart are a view of the robot and the best view of it turned by 180 deg? A bound on what
any single-frame method can do about front/back flips.

For each frame with the robot in view: the heading turned by 180 deg is aligned to the frame's
ground-truth mask (the oracle silhouette alignment, that hypothesis alone), so that its silhouette
explains the image as well as it can; then both poses are rendered (our shaded RGB, hard masks) and
compared, with each other and with the observed image, inside the union of their masks:

- `sil`: the flipped pose's silhouette disagreement with the true mask (pixels, hard renders);
- `d_render`: mean |RGB difference| between the two renders (0-255 levels);
- `margin`: mean |obs - flipped render| minus mean |obs - true render| (0-255 levels): how much
  worse the best flipped pose explains the pixels; near 0, nothing in the image tells them apart.

Rows by relative heading (the robot's heading minus the bearing: 0 = facing the camera) and range.

  python experiments/flip_ambiguity.py --data /work/data/circle /work/data/sine --stride 5 \
      --iml-json /work/data/iml_circle.json /work/data/iml_sine.json --json flip_ambiguity.json
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from rhaml_jax import allocator, data, frames, render
from rhaml_jax.camera import T_cam_robot
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine import AlignConfig, align


@dataclasses.dataclass(frozen=True)
class Args:
    data: tuple[Path, ...]
    """BOP scenario folders (our circle, sine)"""
    iml_json: tuple[Path, ...] = ()
    """`evaluate --json` of the same folders: the frames the IML flipped are marked"""
    stride: int = 5
    """every stride-th frame, and every frame the IML flipped"""
    camera_height_m: float = 0.30
    json: Path | None = None


def main(args: Args):
    allocator.tune_allocator()
    cfg = AlignConfig(flip=False, mirror=False, coarse_stages=(), camera_height_m=args.camera_height_m)
    h = args.camera_height_m
    rows = []
    for k, root in enumerate(args.data):
        flipped = set()
        if args.iml_json:
            for f in json.loads(Path(args.iml_json[k]).read_text())["frames"]:
                if f.get("observed") and f.get("detected") and abs(wrap_angle(f["est"][2] - f["gt"][2])) > np.pi / 2:
                    flipped.add(f["im_id"])
        mesh = render.as_mesh(data.load_bop_model(root))
        recs = [f for i, f in enumerate(data.read_bop(root, "test")) if f.observed and (i % args.stride == 0 or f.im_id in flipped)]
        W = H = None
        for f in recs:
            rgb = data.load_rgb(f.rgb).astype(np.float32)
            mask = data.load_mask(f.mask).astype(np.float32)
            H, W = mask.shape
            gt = np.asarray(f.xypsi, np.float32)
            start = gt + np.array([0, 0, np.pi], np.float32)
            res = _align(mesh, jnp.asarray(mask), jnp.asarray(f.K, jnp.float32), jnp.asarray(start), cfg)
            poses = np.stack([gt, np.asarray(res.xypsi)])
            T = T_cam_robot(h) @ frames.se3_from_xypsi(jnp.asarray(poses))
            out = _render(mesh, T, jnp.asarray(f.K, jnp.float32), W, H)
            im, m = np.asarray(out.rgb) * 255, np.asarray(out.mask) > 0.5
            union = m[0] | m[1]
            n = max(int(union.sum()), 1)
            d_render = float(np.abs(im[0] - im[1])[union].sum() / (3 * n))
            res_true = float(np.abs(rgb - im[0])[union].sum() / (3 * n))
            res_flip = float(np.abs(rgb - im[1])[union].sum() / (3 * n))
            rel = float(np.degrees(wrap_angle(gt[2] - np.arctan2(gt[1], gt[0]))))
            rows.append({"set": root.name, "im_id": f.im_id, "range_m": float(np.hypot(gt[0], gt[1])), "rel_deg": rel,
                         "mask_px": int(mask.sum()), "sil_px": int((m[1] != (mask > 0.5)).sum()),
                         "sil_true_px": int((m[0] != (mask > 0.5)).sum()), "d_render": d_render,
                         "res_true": res_true, "res_flip": res_flip, "margin": res_flip - res_true,
                         "iml_flipped": f.im_id in flipped, "flip_xypsi": np.asarray(res.xypsi).tolist()})
            print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in rows[-1].items() if k != "flip_xypsi"}),
                  flush=True)
    summary = summarize(rows)
    for s in summary:
        print(json.dumps(s))
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in dataclasses.asdict(args).items()}, "summary": summary,
                                         "frames": rows}, indent=1))


def summarize(rows):
    """Medians per (view, range band): view "end-on" within 20 deg of head-on or tail-on."""
    out = []
    end_on = lambda r: min(abs(r["rel_deg"]), 180 - abs(r["rel_deg"])) <= 20  # noqa: E731
    for view in ("end-on", "other"):
        for lo, hi in ((0, 4), (4, 5.5), (5.5, 8)):
            sel = [r for r in rows if (end_on(r) == (view == "end-on")) and lo <= r["range_m"] < hi]
            if not sel:
                continue
            med = lambda k: float(np.median([r[k] for r in sel]))  # noqa: E731
            out.append({"view": view, "range_m": [lo, hi], "frames": len(sel), "iml_flipped": sum(r["iml_flipped"] for r in sel),
                        "median_mask_px": med("mask_px"), "median_sil_px": med("sil_px"), "median_d_render": med("d_render"),
                        "median_margin": med("margin"), "min_margin": float(min(r["margin"] for r in sel))})
    flipped = [r for r in rows if r["iml_flipped"]]
    if flipped:
        out.append({"view": "the IML's flipped frames", "frames": len(flipped),
                    "median_sil_px": float(np.median([r["sil_px"] for r in flipped])),
                    "median_margin": float(np.median([r["margin"] for r in flipped])),
                    "median_d_render": float(np.median([r["d_render"] for r in flipped]))})
    return out


_align = jax.jit(align, static_argnames=("cfg",))
_render = jax.jit(render.render, static_argnames=("width", "height"))

if __name__ == "__main__":
    main(tyro.cli(Args))
