"""The observed-mask segmenter's masks against the ground truth, in the alignment's 1.4x crop
around the true pose (BENCHMARKS.md, "Refinement": the segmenter rows).

  python experiments/segmenter_iou.py --segmenter RUN --data SET [SET ...]        # median IoU per set
  python experiments/segmenter_iou.py --segmenter RUN --data TRAINING_SET --areas  # threshold vs area, val split
  python experiments/segmenter_iou.py --segmenter RUN --data VAL_SET --areas --split test --margins 1.4

Per set: every 25th frame with the robot in view (the first 20 whose mask has at least 300 px),
the median IoU of the mask thresholded at 0.5. With --areas, on the val split (every 4th frame)
at margins 1.4 and 2.5: the predicted / true area and the median IoU per threshold, where
`RefineConfig.mask_threshold` was chosen.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import crop as _crop
from rhaml_jax import data
from rhaml_jax.refine import load_segmenter, observed_mask
from rhaml_jax.refine.train import _corners


def crops(seg, root: Path, frames, margins):
    """(predicted masks, true masks) (N, S, S) at each frame's true pose, for each margin in turn."""
    S = seg.cfg.crop
    corners = _corners(data.load_bop_model(root).vertices)
    f_mask = jax.jit(lambda im, b: observed_mask(seg, im, b))
    pred, true = [], []
    for f in frames:
        m = data.load_mask(f.mask)
        if m.sum() < 300:  # the robot mostly out of view or tiny
            continue
        pc = corners @ f.T_m2c[:3, :3].T + f.T_m2c[:3, 3]
        im = jnp.asarray(data.load_rgb(f.rgb), jnp.float32) / 255
        for margin in margins:
            box = jnp.asarray(_crop.object_box(f.K, pc, margin=margin), jnp.float32)
            pred.append(np.asarray(f_mask(im, box)))
            true.append(np.asarray(_crop.crop_image(jnp.asarray(m, jnp.float32)[..., None], box, S, S))[..., 0])
    return np.array(pred), np.array(true)


def iou(pred, true):
    return np.array([(a & b).sum() / max((a | b).sum(), 1) for a, b in zip(pred, true)])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--segmenter", type=Path, required=True)
    p.add_argument("--data", type=Path, nargs="+", required=True)
    p.add_argument("--areas", action="store_true", help="threshold vs area on the val split (margins 1.4, 2.5)")
    p.add_argument("--split", default="val", help="with --areas: the split (e.g. test: a validation look's scenes)")
    p.add_argument("--margins", type=float, nargs="+", default=[1.4, 2.5], help="with --areas: the crop margins")
    a = p.parse_args()
    seg = load_segmenter(a.segmenter)
    for root in a.data:
        if a.areas:
            frames = [f for f in data.read_bop(root, a.split) if f.observed][::4]
            P, T = crops(seg, root, frames, a.margins)
            n = len(a.margins)
            for k, margin in enumerate(a.margins):
                pk, tk = P[k::n], T[k::n] > 0.5
                for thr in (0.2, 0.3, 0.4, 0.5):
                    h = pk > thr
                    print(f"{root} margin {margin} threshold {thr}: area ratio {h.sum() / tk.sum():.3f}, "
                          f"median IoU {np.median(iou(h, tk)):.3f}")
        else:
            frames = [f for f in data.read_bop(root) if f.observed][::25][:20]
            P, T = crops(seg, root, frames, (1.4,))
            print(f"{root}: median IoU {np.median(iou(P > 0.5, T > 0.5)):.3f} over {len(P)} crops")


if __name__ == "__main__":
    main()
