"""A validation run constructed from two stored ones: `AlignConfig.min_turn` and `max_shift` applied offline.

    python experiments/merge_gate.py BASE ALIGNED OUT --min-turn-deg 4 [--max-shift 0.03] [--ev /work/runs/validation]

BASE and ALIGNED are labels of `experiments/validate_networks.sh` runs with the same networks, ALIGNED
with the alignment after the cascade (`evaluate --segmenter`) and no gate. Per frame, OUT's IR estimate
(and the IR flip probability) is ALIGNED's where both runs refined the frame and the alignment turned
the cascade's heading by more than the gate (and, with --max-shift, moved its position by at most that
fraction of its range), else BASE's; every other field is BASE's. This is what the
gate does within a frame. What it leaves out: the pipeline's re-detection refines doubtful frames and
keeps those its pose graph agrees with, so a real run with the gate can call a few frames detected
differently (BASE and ALIGNED differ so on 4 of 1,933 OOD robots). Writes EV/OUT_SET.json for every set
of both runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rhaml_jax.planar import wrap_angle


def merge(base: dict, aligned: dict, min_turn: float, max_shift: float | None = None) -> tuple[dict, int]:
    """(the constructed run, how many frames took ALIGNED's estimate)."""
    frames, taken = [], 0
    by_id = {(r["scene_id"], r["im_id"]): r for r in aligned["frames"]}
    for r in base["frames"]:
        a = by_id[(r["scene_id"], r["im_id"])]
        out = dict(r)
        if r.get("ir_applied") and a.get("ir_applied"):
            turn = abs(wrap_angle(a["ir_est"][2] - r["ir_est"][2]))
            b, e = np.asarray(r["ir_est"][:2]), np.asarray(a["ir_est"][:2])
            near = max_shift is None or np.hypot(*(e - b)) <= max_shift * np.hypot(*b)
            if turn > min_turn and near:
                out["ir_est"], out["ir_flip_prob"] = a["ir_est"], a["ir_flip_prob"]
                taken += 1
        frames.append(out)
    return {"metrics": base["metrics"], "frames": frames}, taken


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("base")
    p.add_argument("aligned")
    p.add_argument("out")
    p.add_argument("--min-turn-deg", type=float, required=True)
    p.add_argument("--max-shift", type=float, default=None)
    p.add_argument("--ev", type=Path, default=Path("/work/runs/validation"))
    a = p.parse_args()
    for path in sorted(a.ev.glob(f"{a.aligned}_*.json")):
        s = path.name[len(a.aligned) + 1:]
        base = a.ev / f"{a.base}_{s}"
        if s == "summary.json" or not base.exists():
            continue
        run, taken = merge(json.loads(base.read_text()), json.loads(path.read_text()), np.deg2rad(a.min_turn_deg), a.max_shift)
        (a.ev / f"{a.out}_{s}").write_text(json.dumps(run))
        print(f"{s}: {taken} of {len(run['frames'])} frames take the alignment", flush=True)


if __name__ == "__main__":
    main()
