"""Validation scenes for appearance robustness, on our own renderer: the issue-18 controls, a
100-frame circle with the built-in robot repainted (its geometry unchanged), to choose designs
and checkpoints on, so that the held-out set stays untouched until the report.

  python experiments/repainted_validation.py --out /work/data/val_repaint [--frames 100]

Variants (no part in the held-out hue band, 155-205 deg):
- `blue_body`: the red body blue (hue 225 deg);
- `grey_wheels`: the black parts (tyres, top plate, caster) and the yellow hubs mid-grey.
Each is `generate --scenario circle --frames N --robot OUT/VARIANT.ply` (the same room, light
and poses as our circle at seed 0), so `evaluate --data OUT/VARIANT` measures it.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

VARIANTS = {
    # (which of the model's colours, as the predicate on RGB in [0, 1]) -> the new colour
    "blue_body": [(lambda c: c[0] > 0.6 and c[1] < 0.1 and c[2] < 0.1, (0.10, 0.25, 0.85))],
    "grey_wheels": [(lambda c: c.max() < 0.2, (0.5, 0.5, 0.5)), (lambda c: c[0] > 0.9 and c[1] > 0.7 and c[2] < 0.3, (0.5, 0.5, 0.5))],
}


def write_variant_model(out: Path, variant: str) -> Path:
    """OUT/VARIANT.ply: the built-in robot (as `generate` writes it) with the variant's colours."""
    from rhaml_jax.data._bop import _write_ply
    from rhaml_jax.robots import load_robot

    m = load_robot("pioneer3dx")
    faces = np.asarray(m.faces)
    colours = np.asarray(m.face_colors, np.float64).copy()
    for match, new in VARIANTS[variant]:
        hit = np.array([match(c) for c in colours])
        if not hit.any():
            raise SystemExit(f"repainted_validation: variant {variant}: no part of the built-in robot matched")
        colours[hit] = new
    v = np.asarray(m.vertices, np.float64)[faces].reshape(-1, 3)  # one vertex per face corner, metres (what --robot reads)
    rgb = np.repeat(np.round(255 * colours).astype(np.uint8), 3, axis=0)
    path = out / f"{variant}.ply"
    out.mkdir(parents=True, exist_ok=True)
    _write_ply(path, v.astype(np.float32), rgb, np.arange(len(v), dtype=np.int32).reshape(-1, 3))
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=100)
    a = ap.parse_args(argv)
    for variant in VARIANTS:
        if (a.out / variant / "test").is_dir():
            continue
        ply = write_variant_model(a.out, variant)
        subprocess.run([sys.executable, "-m", "rhaml_jax.generate", "--out", str(a.out / variant), "--scenario", "circle",
                        "--frames", str(a.frames), "--robot", str(ply), "--workers", "1"], check=True)


if __name__ == "__main__":
    main()
