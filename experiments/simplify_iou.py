"""Silhouette IoU of simplified robot models against the full model over random views.

Run: python experiments/simplify_iou.py [--views 50]
Prints a markdown table (model, budget, faces, IoU min / mean, seconds to simplify).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import tyro

from rhaml_jax.robots import load_robot
from rhaml_jax.robots import silhouette_iou

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "robots"


@dataclasses.dataclass(frozen=True)
class Args:
    views: int = 50
    budgets: tuple[int, ...] = (500, 1000, 2000, 5000, 10000)
    quadric: bool = False
    """Also measure whole-mesh quadric decimation (fast-simplification) at the same budgets."""


def main(args: Args) -> None:
    robots = {
        "built-in pioneer3dx": "pioneer3dx",
        "Pioneer-3DX URDF": str(DATA / "pioneer3dx/urdf/pioneer3dx.urdf"),
        "TurtleBot3 Burger URDF": str(DATA / "turtlebot3_burger/urdf/turtlebot3_burger.main.urdf"),
    }
    print("| model | full faces | budget | faces | IoU min | IoU mean | simplify s |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, spec in robots.items():
        full = load_robot(spec)
        for budget in args.budgets:
            if budget >= len(full.faces):
                continue
            t = time.perf_counter()
            simp = full.simplify(budget)
            dt = time.perf_counter() - t
            iou = silhouette_iou(full, simp, args.views)
            print(f"| {label} | {len(full.faces)} | {budget} | {len(simp.faces)} | {iou.min():.4f} | {iou.mean():.4f} | {dt:.2f} |")
            if args.quadric:
                import fast_simplification
                import numpy as np

                from rhaml_jax.robots import RobotModel

                t = time.perf_counter()
                v, f = fast_simplification.simplify(full.vertices.astype(np.float64), full.faces.astype(np.int64),
                                                    target_reduction=1.0 - budget / len(full.faces))
                dt = time.perf_counter() - t
                q = RobotModel.from_parts("quadric", [("all", v, f, (0.5, 0.5, 0.5))])
                iou = silhouette_iou(full, q, args.views)
                print(f"| {label} (quadric) | {len(full.faces)} | {budget} | {len(q.faces)} | {iou.min():.4f} | {iou.mean():.4f} | {dt:.2f} |")


if __name__ == "__main__":
    main(tyro.cli(Args))
