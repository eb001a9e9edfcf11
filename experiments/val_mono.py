"""A validation look for paint-invariant heading: our sine (seed 7, our rooms and lights) with the
robot in one paint, three times: all parts purple, all orange, all grey, each part its own
saturation and value (drawn once, seeded). Neither hue is the held-out set's (teal, 165-195 deg)
and the rooms and lights are ours, so nothing here previews the held-out set; it asks whether
the heading survives the loss of the parts' own colours (the tyres' dark, the body's red).

    python experiments/val_mono.py --out /work/data/val_mono [--frames 300] [--scenarios sine circle]

writes OUT/{purple,orange,grey}.ply (the robot in metres, recoloured) and OUT/{scenario}_{look}
(`generate --scenario SCENARIO --seed 7 --robot OUT/{look}.ply`; the sine alone by default, as
session 25 used it; `experiments/validate_networks.sh` scores the circle too).

With --cad-out CAD, also CAD/{scenario}_{look}: the same images (linked) with the robot's own
model, in its own paint, as the set's model: what a user has whose CAD colours are not the robot's
(the held-out set's case: a teal robot, the model file in its own paint). Every stage that renders
the model then renders a paint the image does not show.
"""

from __future__ import annotations

import argparse
import colorsys
import subprocess
import sys
from pathlib import Path

import numpy as np

LOOKS = {"purple": (265.0, 285.0), "orange": (20.0, 40.0), "grey": None}  # hue range (deg); None: grey


def recoloured(look: str, seed: int):
    """The built-in robot (a trimesh in metres) with every part in `look`'s paint."""
    import trimesh

    from rhaml_jax.robots import load_robot

    model = load_robot("pioneer3dx")
    colours = (np.asarray(model.face_colors) * 255).round().astype(np.uint8)  # (F, 3), as the BOP model file stores them
    groups, inv = np.unique(colours, axis=0, return_inverse=True)
    rng = np.random.default_rng(seed)
    hue = None if LOOKS[look] is None else rng.uniform(*LOOKS[look]) / 360.0
    new = []
    for _ in groups:
        s = 0.0 if hue is None else rng.uniform(0.3, 1.0)
        v = rng.uniform(0.2, 0.9)
        new.append([int(255 * c) for c in colorsys.hsv_to_rgb(hue or 0.0, s, v)] + [255])
    # unshared vertices (as the BOP model file has them), so each face keeps its own colour
    v = np.asarray(model.vertices)[np.asarray(model.faces)].reshape(-1, 3)
    m = trimesh.Trimesh(v, np.arange(len(v)).reshape(-1, 3), process=False)
    m.visual.vertex_colors = np.repeat(np.array(new, np.uint8)[inv.ravel()], 3, axis=0)
    return m


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--scenarios", nargs="+", default=["sine"], choices=["circle", "sine"])
    ap.add_argument("--cad-out", type=Path, help="also the sets with the robot's own model (see above)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for k, look in enumerate(LOOKS):
        ply = args.out / f"{look}.ply"
        recoloured(look, 100 + k).export(ply)
        for scenario in args.scenarios:
            out = args.out / f"{scenario}_{look}"
            if not (out / "test" / "000000" / "scene_gt.json").exists():  # a finished set is kept
                subprocess.run([sys.executable, "-m", "rhaml_jax.generate", "--out", str(out), "--scenario", scenario,
                                "--frames", str(args.frames), "--seed", "7", "--robot", str(ply), "--workers", "1"], check=True)
            if args.cad_out:
                own_model(out, args.cad_out / out.name)


def own_model(src: Path, out: Path) -> None:
    """out: src's camera and images (linked), the built-in robot in its own paint as the model."""
    import shutil

    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data._bop import write_dataset_header
    from rhaml_jax.robots import load_robot

    out.mkdir(parents=True, exist_ok=True)
    write_dataset_header(out, load_robot("pioneer3dx"), DEFAULT_CAMERA)
    shutil.copyfile(src / "camera.json", out / "camera.json")
    if not (out / "test").exists():
        (out / "test").symlink_to((src / "test").resolve(), target_is_directory=True)


if __name__ == "__main__":
    main()
