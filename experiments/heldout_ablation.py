"""Which held-out factor breaks the shipped IML networks: a 100-frame circle rendered with ONE
group of held-out settings at a time (the held-out circle's own draw), evaluated like the
held-out set (evaluate --modules iml --zoom-mirror).

  python experiments/heldout_ablation.py --out /work/data/heldout_ablation --frames 100

Variants: `teal_parts` (the v1 circle's room and Lambertian light, robot parts in the held-out
teal), `scene_only` (held-out hemisphere light, Voronoi / photograph room and camera, robot in its
own colours), `both` (all held-out settings: the held-out circle at `--frames`), `neither` (the v1
circle at `--frames`). Not a benchmark to tune on: a diagnosis of the old networks.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from heldout_iml import evaluate, summary, table  # noqa: E402


def render_variant(out: Path, variant: str, frames: int, seed: int = 0) -> None:
    import jax.numpy as jnp

    from rhaml_jax.camera import DEFAULT_CAMERA, T_cam_robot
    from rhaml_jax.data import HeldoutConfig
    from rhaml_jax.data._appearance import color_groups, rgb_to_hsv
    from rhaml_jax.data._bop import write_dataset_header, write_frame, write_scene_json
    from rhaml_jax.data._synth import scenario_frame, scenario_frame_v2
    from rhaml_jax.data._writer import ScenarioJob, _heldout_scene_look, _scene_look, scenario_poses
    from rhaml_jax.frames import se3_from_xypsi
    from rhaml_jax.render import Mesh, as_mesh
    from rhaml_jax.robots import load_robot

    if (out / "test" / "000000" / "scene_gt.json").exists():
        return
    model = load_robot("pioneer3dx")
    mesh, cam = as_mesh(model), DEFAULT_CAMERA
    write_dataset_header(out, model, cam)
    scenes, bounds = scenario_poses("circle", frames, seed)
    _, observer, observed, _, _ = scenes[0]
    room_v1, light = _scene_look(seed, bounds)
    room_h, look = _heldout_scene_look(mesh, ScenarioJob("pioneer3dx", None, cam, seed, bounds, (), HeldoutConfig(), 0))
    groups, group_of_face = color_groups(np.asarray(mesh.face_colors))
    teal = Mesh(mesh.vertices, mesh.faces, jnp.asarray(look.part_rgb[group_of_face], jnp.float32))
    own = dataclasses.replace(look, part_hsv=rgb_to_hsv(groups))
    folder = out / "test" / "000000"
    recs = {}
    for i in range(frames):
        if variant == "teal_parts":
            rgb, visib, rel, seen = scenario_frame(teal, cam, room_v1, light, observer[i], observed[i])
        elif variant == "neither":
            rgb, visib, rel, seen = scenario_frame(mesh, cam, room_v1, light, observer[i], observed[i])
        else:
            rgb, visib, rel, seen = scenario_frame_v2(mesh, cam, room_h, own if variant == "scene_only" else look,
                                                      observer[i], observed[i], frame_seed=i)
        T_w2c = np.asarray(T_cam_robot(0.30).as_matrix(), np.float64)
        T_m2c = T_w2c @ np.asarray(se3_from_xypsi(rel).as_matrix(), np.float64) if seen else None
        recs[i] = write_frame(folder, cam, i, rgb, T_w2c, T_m2c, visib, visib)
    write_scene_json(folder, recs)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("/work/data/heldout_ablation"))
    p.add_argument("--frames", type=int, default=100)
    a = p.parse_args()
    rows = {}
    for v in ("neither", "teal_parts", "scene_only", "both"):
        render_variant(a.out / v, v, a.frames)
        rows[v] = summary(evaluate(a.out / v, a.out / f"{v}.json", []))
    md = table(rows)
    print(md)
    (a.out / "summary.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
