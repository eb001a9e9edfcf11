"""A copy of a BOP training set in which the robot's dark parts cannot be seen: in every other
image of the set (a pure function of the image's place in it, negatives counted), if it shows the
robot, the robot's pixels of luma under --luma (Rec. 601, 0-1; its tyres) are inpainted from their
surroundings (OpenCV Telea, 5 px, the mask grown by a pixel for the anti-aliased rims); labels, masks and the val / test splits unchanged
(hard links). A probe of issue 18's long range on dark surroundings: does a network trained on
robots at their true range whose lower outline is missing read the range from what is left?
(BENCHMARKS.md, "A log-luminance channel, and a test-time gamma, do not take the long range away
either".)

  python experiments/inpaint_dark.py SRC DST [--luma 0.08]
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

import cv2
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--luma", type=float, default=0.08)
    a = ap.parse_args()
    if a.dst.exists():
        raise SystemExit(f"{a.dst}: exists; inpaint_dark writes a new copy")
    if not (a.src / "train").is_dir():
        raise SystemExit(f"{a.src}: no train/ split")
    n = changed = 0
    for scene in sorted((a.src / "train").iterdir()):
        out = a.dst / "train" / scene.name
        (out / "rgb").mkdir(parents=True)
        for f in scene.iterdir():
            if f.is_file():
                shutil.copy(f, out / f.name)
        masks = scene / "mask_visib"
        if masks.exists():  # a scene of negatives has none
            shutil.copytree(masks, out / "mask_visib", copy_function=os.link)
        for f in sorted((scene / "rgb").iterdir()):
            n += 1
            m = masks / f"{f.stem}_000000.png"
            if n % 2 == 0 and m.exists():
                img = cv2.imread(str(f), cv2.IMREAD_COLOR)
                luma = img.astype(np.float32) @ np.array([0.114, 0.587, 0.299], np.float32) / 255.0  # BGR
                dark = ((cv2.imread(str(m), cv2.IMREAD_GRAYSCALE) > 127) & (luma < a.luma)).astype(np.uint8)
                if dark.any():
                    dark = cv2.dilate(dark, np.ones((3, 3), np.uint8))
                    cv2.imwrite(str(out / "rgb" / f.name), cv2.inpaint(img, dark * 255, 5, cv2.INPAINT_TELEA))
                    changed += 1
                    continue
            os.link(f, out / "rgb" / f.name)
    for sp in ("val", "test", "models"):
        if (a.src / sp).exists():
            shutil.copytree(a.src / sp, a.dst / sp, copy_function=os.link)
    for f in a.src.iterdir():
        if f.is_file():
            shutil.copy(f, a.dst / f.name)
    print(f"{n} training images, {changed} with dark parts inpainted")


if __name__ == "__main__":
    main()
