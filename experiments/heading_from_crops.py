#!/usr/bin/env python3
"""Is the Pioneer's heading learnable when the robot fills the input? A feasibility check.

Crops a square around the true robot position from each stored training image (at its stored
resolution, side = `--zoom` x the robot's projected length, resampled to `--size` px) and trains
a small AMLNet-style network (the `axis` heading head, x = y = 0 targets) to regress the heading
relative to the viewing ray, psi - atan2(y, x), which is what the robot's look depends on.
Prints the validation |dpsi| and its modulo-180 part (daxis) per validation.

    python experiments/heading_from_crops.py --data /work/data/cpu_train --out runs/heading_crops \
        [--steps 800] [--size 64] [--zoom 1.6]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.amlnet.config import AMLNetConfig  # noqa: E402
from rhaml_jax.amlnet.trainer import TrainConfig, train_amlnet  # noqa: E402
from rhaml_jax.data import AugmentConfig, load_rgb, make_batch_fn, read_bop  # noqa: E402

ROBOT_LENGTH_M, ROBOT_CENTRE_Z_M, CAMERA_H_M = 0.455, 0.12, 0.30


class Crops:
    """Source of (crop (size, size, 3) uint8, 1.0, (0, 0, psi - bearing)) from observed frames."""

    def __init__(self, root: Path, split: str, size: int, zoom: float, limit: int):
        self.frames = [f for f in read_bop(root, split) if f.observed][:limit]
        self.size_px, self.zoom, self.size = size, zoom, len(self.frames)
        self._cache: dict[int, np.ndarray] = {}

    def example(self, index: int):
        f = self.frames[index]
        x, y, psi = f.xypsi
        if index not in self._cache:
            K = f.K
            # robot centre in the optical frame: (-y, h - z, x) (DESIGN.md section 2)
            u = K[0, 2] + K[0, 0] * (-y) / x
            v = K[1, 2] + K[1, 1] * (CAMERA_H_M - ROBOT_CENTRE_Z_M) / x
            side = self.zoom * ROBOT_LENGTH_M * K[0, 0] / x
            s = self.size_px / side
            A = np.array([[s, 0, self.size_px / 2 - s * u], [0, s, self.size_px / 2 - s * v]])
            img = load_rgb(f.rgb)
            self._cache[index] = cv2.warpAffine(img, A, (self.size_px, self.size_px), flags=cv2.INTER_AREA,
                                                borderMode=cv2.BORDER_REPLICATE)
        rel = np.arctan2(np.sin(psi - np.arctan2(y, x)), np.cos(psi - np.arctan2(y, x)))
        return self._cache[index], 1.0, np.array([0.0, 0.0, rel], np.float32)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=800)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--zoom", type=float, default=1.6)
    ap.add_argument("--limit", type=int, default=20000)
    a = ap.parse_args()
    cfg = AMLNetConfig("crop_heading", input_hw=(a.size, a.size), depths=(1, 1, 3, 1), dims=(32, 64, 128, 256),
                       mlp_ratios=(4, 4, 4, 3), neck=(256,), angle_head="axis", pool="gap", layer_scale_init=0.1)
    tc = dataclasses.replace(TrainConfig(), steps=a.steps, val_every=max(a.steps // 4, 1), val_batches=8, warmup=50)
    train = Crops(a.data, "train", a.size, a.zoom, a.limit)
    val = Crops(a.data, "val", a.size, a.zoom, a.limit)
    res = train_amlnet(cfg, tc, a.out, make_batch_fn(train, tc.batch, tc.seed, AugmentConfig()),
                       make_batch_fn(val, tc.batch, tc.seed, None), data_label=f"crops of {a.data}", progress=False)
    print({k: round(v, 2) for k, v in res["val"].items() if isinstance(v, float)})


if __name__ == "__main__":
    main()
