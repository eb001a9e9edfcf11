"""Mixes BOP training sets of one robot and camera into one, by symlinking their scene folders
(nothing is copied): OUT/<split>/<k * 1000 + scene id> -> SET_k/<split>/<scene id>.

  python experiments/mix_bop.py --out /work/data/mix /work/data/v2_train /work/data/v1_train

The first set's camera.json and models/ are linked; every set must have the same ones.
"""

from __future__ import annotations

import argparse
import filecmp
import os
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("sets", type=Path, nargs="+")
    a = ap.parse_args()
    first = a.sets[0].resolve()
    for s in a.sets[1:]:
        for f in ("camera.json", "models/obj_000001.ply"):
            if not filecmp.cmp(first / f, s / f, shallow=False):
                raise SystemExit(f"error: {s / f} differs from {first / f}: not the same robot and camera")
    a.out.mkdir(parents=True, exist_ok=True)
    for f in ("camera.json", "models"):
        if not (a.out / f).exists():
            os.symlink(first / f, a.out / f)
    for k, s in enumerate(a.sets):
        for split in sorted(p for p in s.resolve().iterdir() if p.is_dir() and p.name != "models"):
            (a.out / split.name).mkdir(exist_ok=True)
            for scene in sorted(p for p in split.iterdir() if p.is_dir()):
                link = a.out / split.name / f"{k * 1000 + int(scene.name):06d}"
                if not link.exists():
                    os.symlink(scene, link)
    print(f"{a.out}: " + ", ".join(f"{sp.name} {len(list(sp.iterdir()))} scenes" for sp in sorted(a.out.iterdir())
                                 if sp.is_dir() and sp.name != "models"))


if __name__ == "__main__":
    main()
