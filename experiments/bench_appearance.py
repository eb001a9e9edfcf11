"""Cost of the v2 appearance randomisation: training images per second, v1 against v2, measured
side by side (interleaved in one process, renderer compiled first), median over the images.

  python experiments/bench_appearance.py --images 20 [--width 640 --height 480]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from rhaml_jax.camera import DEFAULT_CAMERA
from rhaml_jax.data import SynthConfig, training_sample
from rhaml_jax.render import as_mesh
from rhaml_jax.robots import load_robot


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--images", type=int, default=20)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    a = p.parse_args()
    mesh = as_mesh(load_robot("pioneer3dx"))
    cam = DEFAULT_CAMERA.resized(a.width, a.height)
    cfgs = {"v1": SynthConfig(appearance=None), "v2": SynthConfig()}
    for cfg in cfgs.values():  # compile every shape first (robot, distractors, shadows)
        for i in range(3):
            training_sample(mesh, cam, 1, i, cfg=cfg)
    times = {k: [] for k in cfgs}
    for i in range(a.images):
        for k, cfg in cfgs.items():
            t = time.perf_counter()
            training_sample(mesh, cam, 0, i, cfg=cfg)
            times[k].append(time.perf_counter() - t)
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(json.dumps({"images": a.images, "size": [a.width, a.height], "median_s": med, "v2_over_v1": med["v2"] / med["v1"]}))


if __name__ == "__main__":
    main()
