"""What the robot frames IML misses have in common: detected against missed, per evaluated scene.

  python experiments/detection_misses.py EVAL.json DATA [EVAL.json DATA ...]

Each EVAL.json is an `evaluate --json` run on the BOP scene DATA (split `test`). Per group (detected,
missed), medians over its observed frames of: the range (m), bearing (deg) and relative heading
|psi - bearing| (deg, 0 = seen from behind, 180 = from the front) from the ground truth; IML's
score o; the robot's mean luma (Rec. 601, in [0, 1]) in its visible mask, its surroundings' (its
box grown by half its size each side, the robot left out), their absolute difference (the contrast a
detector sees), and its width (px).
"""

from __future__ import annotations

import argparse
import glob
import json

import cv2
import numpy as np

from rhaml_jax.data._appearance import surroundings

LUMA = np.array([0.299, 0.587, 0.114], np.float32)


def frame_row(data: str, f: dict) -> list[float] | None:
    """[detected, range, bearing, |relative heading|, o, robot luma, around luma, |diff|, width] or None."""
    scene = f"{data}/test/{f['scene_id']:06d}"
    masks = glob.glob(f"{scene}/mask_visib/{f['im_id']:06d}_*.png")
    if not masks:
        return None
    mask = cv2.imread(masks[0], cv2.IMREAD_GRAYSCALE) > 0
    if not mask.any():
        return None
    luma = cv2.imread(f"{scene}/rgb/{f['im_id']:06d}.png")[..., ::-1].astype(np.float32) @ LUMA / 255.0
    box, outside = surroundings(mask)
    robot, around = float(luma[mask].mean()), float(luma[box][outside].mean())
    x, y, psi = f["gt"]
    bearing = np.arctan2(y, x)
    rel = abs((psi - bearing + np.pi) % (2 * np.pi) - np.pi)
    return [float(f["detected"]), float(np.hypot(x, y)), float(np.degrees(bearing)), float(np.degrees(rel)), float(f["o"]),
            robot, around, abs(robot - around), float(np.ptp(np.nonzero(mask)[1]) + 1)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs", nargs="+", help="EVAL.json DATA pairs")
    a = ap.parse_args()
    if len(a.pairs) % 2:
        ap.error("expected EVAL.json DATA pairs")
    print("| run | group | frames | range (m) | bearing (deg) | rel. heading (deg) | o | robot luma | around | contrast | width (px) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for ev, data in zip(a.pairs[::2], a.pairs[1::2]):
        rows = [r for f in json.load(open(ev))["frames"] if f["observed"] and (r := frame_row(data, f)) is not None]
        r = np.array(rows)
        for name, sel in (("detected", r[:, 0] > 0), ("missed", r[:, 0] == 0)):
            if sel.any():
                m = np.median(r[sel, 1:], 0)
                print(f"| {ev.split('/')[-1]} | {name} | {sel.sum()} | {m[0]:.1f} | {m[1]:.0f} | {m[2]:.0f} | {m[3]:.2f} | "
                      f"{m[4]:.3f} | {m[5]:.3f} | {m[6]:.3f} | {m[7]:.0f} |")


if __name__ == "__main__":
    main()
