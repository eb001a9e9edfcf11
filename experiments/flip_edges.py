"""Can the image's edges tell front from back where the networks cannot? A test-time probe, no
training: for each detected frame, the robot's hard silhouette is rendered at IML's estimate and
at it turned by 180 deg; each outline is slid by up to `shift` pixels to where the image's
gradient is strongest along it, and scored by the mean gradient magnitude on it (normalised by
the gradient's median in the box around both). Outlines are paint-independent: if the true
heading's outline sits on the image's edges better than the flipped one's, the score difference
ranks IML's flips.

    python experiments/flip_edges.py --data DIR --iml-json EVAL.json [--stride 1] [--json OUT]

Prints, over the detected frames with the robot in view: the ROC area of (flipped score - kept
score) against IML's flips, and how many flips a rule "turn when the flipped outline scores
higher by `margin`" would undo and make, per margin.
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
from rhaml_jax.metrics import flipped, view_deg


@dataclasses.dataclass(frozen=True)
class Args:
    data: Path
    """a BOP scenario folder"""
    iml_json: Path
    """`evaluate --json` of that folder (IML's estimates)"""
    stride: int = 1
    shift: int = 4
    """pixels each outline may slide (range and bearing errors of a few percent)"""
    camera_height_m: float = 0.30
    margins: tuple[float, ...] = (0.0, 0.05, 0.1, 0.2)
    json: Path | None = None


def outline(mask: np.ndarray) -> np.ndarray:
    """The mask's boundary pixels (inside, with a 4-neighbour outside)."""
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    return mask & ~inner


def gradient(grey: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude."""
    g = np.pad(grey, 1, mode="edge")
    gx = (g[:-2, 2:] + 2 * g[1:-1, 2:] + g[2:, 2:]) - (g[:-2, :-2] + 2 * g[1:-1, :-2] + g[2:, :-2])
    gy = (g[2:, :-2] + 2 * g[2:, 1:-1] + g[2:, 2:]) - (g[:-2, :-2] + 2 * g[:-2, 1:-1] + g[:-2, 2:])
    return np.hypot(gx, gy)


def best_shift(edges: np.ndarray, line: np.ndarray, shift: int) -> tuple[int, int]:
    """The offset within +-shift pixels that puts `line` on the strongest `edges` (mean)."""
    ys, xs = np.nonzero(line)
    H, W = edges.shape
    scores = {(dy, dx): float(edges[np.clip(ys + dy, 0, H - 1), np.clip(xs + dx, 0, W - 1)].mean())
              for dy in range(-shift, shift + 1) for dx in range(-shift, shift + 1)}
    return max(scores, key=scores.get)


def moved(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    return np.roll(np.roll(mask, dy, axis=0), dx, axis=1)


def dilated(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out |= moved(mask, dy, dx)
    return out


def scores(edges: np.ndarray, masks: np.ndarray, shift: int, apart: int = 2) -> tuple[float, float]:
    """Each hypothesis' outline, slid onto the edges, scored on its part more than `apart` pixels
    from the other's (where the two hypotheses differ): mean edge strength there."""
    lines = [outline(m) for m in masks]
    lines = [moved(line, *best_shift(edges, line, shift)) if line.any() else line for line in lines]
    own = [lines[0] & ~dilated(lines[1], apart), lines[1] & ~dilated(lines[0], apart)]
    return tuple(float(edges[o].mean()) if o.any() else 0.0 for o in own)


def main(args: Args):
    allocator.tune_allocator()
    est = {(f["scene_id"], f["im_id"]): f for f in json.loads(args.iml_json.read_text())["frames"]}
    mesh = render.as_mesh(data.load_bop_model(args.data))
    recs = [f for i, f in enumerate(data.read_bop(args.data, "test")) if i % args.stride == 0 and f.observed
            and est[(f.scene_id, f.im_id)]["detected"]]
    rows = []
    for f in recs:
        e = np.asarray(est[(f.scene_id, f.im_id)]["iml_est"], np.float32)
        poses = np.stack([e, e + np.array([0, 0, np.pi], np.float32)])
        rgb = data.load_rgb(f.rgb).astype(np.float32)
        H, W = rgb.shape[:2]
        T = T_cam_robot(args.camera_height_m) @ frames.se3_from_xypsi(jnp.asarray(poses))
        masks = np.asarray(_render(mesh, T, jnp.asarray(f.K, jnp.float32), W, H).mask) > 0.5
        edges = gradient(rgb @ np.array([0.299, 0.587, 0.114], np.float32))
        ys, xs = np.nonzero(masks[0] | masks[1])
        if len(ys) == 0:
            continue
        pad = 3 * args.shift
        box = edges[max(ys.min() - pad, 0):ys.max() + pad + 1, max(xs.min() - pad, 0):xs.max() + pad + 1]
        norm = float(np.median(box)) + 1e-3
        kept, turned = scores(edges / norm, masks, args.shift)
        gt = np.asarray(f.xypsi, float)
        rows.append({"im_id": f.im_id, "range_m": float(np.hypot(gt[0], gt[1])),
                     "view_deg": float(view_deg(gt)[0]),
                     "iml_flipped": bool(flipped([e[2]], [gt[2]])[0]), "kept": kept, "turned": turned,
                     "outline_px": int(outline(masks[0]).sum())})
    summary = summarize(rows, args.margins)
    print(json.dumps(summary, indent=1))
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in dataclasses.asdict(args).items()}, "summary": summary,
                                         "frames": rows}, indent=1))


def summarize(rows: list[dict], margins) -> dict:
    y = np.array([r["iml_flipped"] for r in rows])
    s = np.array([r["turned"] - r["kept"] for r in rows])
    rel = np.array([(r["turned"] - r["kept"]) / max(r["kept"], 1e-6) for r in rows])
    pos, neg = s[y], s[~y]
    auc = float(((pos[:, None] > neg[None]).sum() + 0.5 * (pos[:, None] == neg[None]).sum()) / max(len(pos) * len(neg), 1))
    rules = {f"{m:g}": {"undone": int((y & (rel > m)).sum()), "made": int((~y & (rel > m)).sum())} for m in margins}
    return {"frames": len(rows), "iml_flips": int(y.sum()), "roc_area": auc, "turn_if_relative_gain_above": rules}


_render = jax.jit(render.render, static_argnames=("width", "height"))

if __name__ == "__main__":
    main(tyro.cli(Args))
