"""One BOP training set made of several of one robot and camera, by symlinking their scene
folders (nothing is copied): OUT/<split>/<k * 1000 + scene id> -> SET_k/<split>/<scene id>.
What trains on mixed looks (fit's curriculum, the robust networks' fine-tuning) reads it as
one set."""

from __future__ import annotations

import filecmp
import os
from pathlib import Path

from rhaml_jax.errors import RhamlError


def mix_sets(out: Path, sets: list[Path]) -> dict[str, int]:
    """Links `sets` into `out` (idempotent: links already there are kept, so a killed run is
    simply run again); returns the scene count per split. The first set's camera.json and
    models/ are linked; every set must have the same ones."""
    out, sets = Path(out), [Path(s).resolve() for s in sets]
    if not sets:
        raise RhamlError(f"{out}: no sets to mix")
    first = sets[0]
    for s in sets:
        for f in ("camera.json", "models/obj_000001.ply"):
            if not (s / f).is_file():
                raise RhamlError(f"{s}: not a BOP set ({f} missing)")
            if not filecmp.cmp(first / f, s / f, shallow=False):
                raise RhamlError(f"{s / f} differs from {first / f}: not the same robot and camera")
    out.mkdir(parents=True, exist_ok=True)
    for f in ("camera.json", "models"):
        if not (out / f).exists():
            os.symlink(first / f, out / f)
    for k, s in enumerate(sets):
        for split in sorted(p for p in s.iterdir() if p.is_dir() and p.name != "models"):
            (out / split.name).mkdir(exist_ok=True)
            for scene in sorted(p for p in split.iterdir() if p.is_dir()):
                link = out / split.name / f"{k * 1000 + int(scene.name):06d}"
                if not link.is_symlink():
                    os.symlink(scene, link)
    return {sp.name: len(list(sp.iterdir())) for sp in sorted(out.iterdir()) if sp.is_dir() and sp.name != "models"}
