"""Data generation speed and size on disk at 640 x 480 (issue: synthetic data).

Run: python experiments/bench_generate.py [--images 100] [--workers 2]
Prints one JSON line: steady-state images/s of one process (after the renderer compiled),
wall-clock images/s of the whole `generate` run with N worker processes (start-up and
compilation included), and megabytes on disk per 1,000 images (rgb + masks + JSON).
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import tyro

from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import training_sample
from rhaml_jax.data._bop import write_image
from rhaml_jax.data import write_training_set
from rhaml_jax.render import as_mesh
from rhaml_jax.robots import load_robot


@dataclasses.dataclass(frozen=True)
class Args:
    images: int = 100
    workers: int = 2
    robot: str = "pioneer3dx"


def main(args: Args) -> None:
    mesh = as_mesh(load_robot(args.robot))
    training_sample(mesh, DEFAULT_CAMERA, 0, 0)  # compile
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(1, 21):
            t = time.perf_counter()
            s = training_sample(mesh, DEFAULT_CAMERA, 0, i)
            write_image(Path(tmp) / f"{i}.png", s.rgb)
            times.append(time.perf_counter() - t)
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        write_training_set(Path(tmp) / "set", args.robot, DEFAULT_CAMERA, 0, int(args.images * 0.875), args.images - int(args.images * 0.875), args.workers)
        wall = time.perf_counter() - t
        size = sum(p.stat().st_size for p in (Path(tmp) / "set").rglob("*") if p.is_file() and "models" not in p.parts)
    print(json.dumps({
        "width": DEFAULT_CAMERA.width, "height": DEFAULT_CAMERA.height,
        "steady_images_per_s_one_process": round(1.0 / float(np.median(times)), 2),
        "median_ms_per_image": round(1000 * float(np.median(times)), 1),
        "images": args.images, "workers": args.workers,
        "wall_images_per_s_with_startup": round(args.images / wall, 2),
        "mb_per_1000_images": round(size / args.images * 1000 / 1e6, 1),
    }))


if __name__ == "__main__":
    main(tyro.cli(Args))
