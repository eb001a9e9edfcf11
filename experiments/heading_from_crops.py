#!/usr/bin/env python3
"""Is the Pioneer's heading learnable when the robot fills the input? A feasibility check.

The zoom-in stage (`rhaml_jax.zoom`) with its estimates set to the truth (no jitter):
crops around the true position, `--zoom` robot lengths wide, resampled to `--size` px; a small
AMLNet (blocks (1, 1, 3, 1), global average pooling, the `axis` heading head) regresses the
heading relative to the viewing ray. Prints the validation |dpsi| and its modulo-180 part
(daxis) per validation.

    python experiments/heading_from_crops.py --data /work/data/cpu_train --out runs/heading_crops \
        [--steps 800] [--size 64] [--zoom 1.6] [--limit 8000]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.amlnet.config import get_config  # noqa: E402
from rhaml_jax.amlnet.trainer import TrainConfig, train_amlnet  # noqa: E402
from rhaml_jax.zoom import ZoomJitter, ZoomSource  # noqa: E402
from rhaml_jax.data import AugmentConfig, make_batch_fn  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=800)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--zoom", type=float, default=1.6)
    ap.add_argument("--limit", type=int, default=20000)
    a = ap.parse_args()
    cfg = dataclasses.replace(get_config("zoom_cpu"), name="crop_heading", input_hw=(a.size, a.size), pool="gap",
                              zoom_factor=a.zoom)
    tc = dataclasses.replace(TrainConfig(), steps=a.steps, val_every=max(a.steps // 4, 1), val_batches=8, warmup=50)
    exact = ZoomJitter(0.0, 0.0)
    train = ZoomSource(a.data, "train", cfg, tc.seed, exact, draws=1, limit=a.limit)
    val = ZoomSource(a.data, "val", cfg, tc.seed, exact, draws=1, limit=a.limit)
    res = train_amlnet(cfg, tc, a.out, make_batch_fn(train, tc.batch, tc.seed, AugmentConfig(), workers=2),
                       make_batch_fn(val, tc.batch, tc.seed, None), data_label=f"exact crops of {a.data}", progress=False)
    print({k: round(v, 2) for k, v in res["val"].items() if isinstance(v, float)})


if __name__ == "__main__":
    main()
