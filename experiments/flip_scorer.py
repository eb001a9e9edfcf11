"""Would a front/back scorer mend IR's flips? For every frame a stored `evaluate` run refined, the
scorer (`train --stage scorer --config scorer_flip_cpu`) rates the refined pose against it turned
by 180 deg about the model's box centre (`refine.heading_search`, as the IR stage runs it); the
per-frame probability of the other side is stored, and for each threshold the flips the scorer
would fix and make are counted against the run's own IR estimates.

    python experiments/flip_scorer.py --scorer RUN --run EV/ens_native_val_scen_s7_500_sine.json /work/data/val_scen_s7_500/sine \
        [--run ...] --out OUT.json

Offline: the refined pose the scorer reads here is IR's final one (the pipeline's search runs
between the coarse and the fine iterations), so this chooses a threshold and tells whether the
scorer is worth a validation run; the validation run itself decides.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import refine, render
from rhaml_jax.data import load_bop_model, read_bop
from rhaml_jax.metrics import flipped
from rhaml_jax.sequence import group_scenes, load_scene

THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98)


@jax.jit
def _other_side(scorer, mesh, images, K, poses):
    """(B,) the probability of the other side for a batch (the pose kept: threshold 1)."""
    h = refine.RefineConfig.camera_height_m
    return jax.vmap(lambda im, k, x: refine.heading_search(scorer, mesh, im, k, x, h, 1.0)[1])(images, K, poses)


def flip_probs(scorer, mesh, images, K, poses, batch: int = 16) -> np.ndarray:
    """(N,) the scorer's probability that each pose (N, 3) faces the wrong way (one compiled
    function for every sequence: the scorer and mesh are arguments)."""
    out = []
    for i in range(0, len(images), batch):
        sl = slice(i, i + batch)
        out.append(np.asarray(_other_side(scorer, mesh, jnp.asarray(images[sl], jnp.float32) / 255.0,
                                          jnp.asarray(K[sl]), poses[sl])))
    return np.concatenate(out)


def counts(p: np.ndarray, was_flipped: np.ndarray) -> dict:
    """Flips after turning the frames whose p exceeds each threshold: {t: (flips, fixed, made)}."""
    out = {}
    for t in THRESHOLDS:
        turn = p > t
        after = was_flipped ^ turn
        out[str(t)] = (int(after.sum()), int(np.sum(was_flipped & turn)), int(np.sum(~was_flipped & turn)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scorer", type=Path, required=True)
    ap.add_argument("--run", nargs=2, action="append", metavar=("EVAL_JSON", "DATA"), required=True)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    scorer = None
    results, total = {}, {}
    for ev, data in a.run:
        rows = json.loads(Path(ev).read_text())["frames"]
        model = load_bop_model(data)
        scorer = scorer or refine.load_scorer(a.scorer, model)  # refused for another robot
        mesh = render.as_mesh(model)
        scenes = list(group_scenes(read_bop(data)).values())
        if len(scenes) != 1:
            raise SystemExit(f"{data}: one scene expected")
        sc = load_scene(scenes[0])
        keep = np.array([bool(r.get("ir_applied")) and r["observed"] for r in rows])
        if not keep.any():
            raise SystemExit(f"{ev}: no frame was refined (run evaluate with the ir module)")
        poses = jnp.asarray([r["ir_est"] for r in rows], jnp.float32)[keep]
        gt = np.asarray(sc.gt)[keep]
        prob = flip_probs(scorer, mesh, sc.seq.images[keep], sc.seq.K[keep], poses)
        was = np.asarray(flipped(np.asarray(poses[:, 2]), gt[:, 2]))
        c = counts(prob, was)
        results[ev] = {"frames": int(keep.sum()), "ir_flips": int(was.sum()), "counts": c, "prob": prob.tolist(),
                       "ir_flipped": was.tolist()}
        for t, v in c.items():
            total[t] = tuple(x + y for x, y in zip(total.get(t, (0, 0, 0)), v))
        print(f"{ev}: {keep.sum()} frames, IR flips {int(was.sum())}; median p {np.median(prob):.3f} "
              f"(flipped frames: {np.median(prob[was]) if was.any() else float('nan'):.3f})")
        print("  threshold: flips after (fixed, made) " + "; ".join(f"{t}: {v[0]} ({v[1]}, {v[2]})" for t, v in c.items()))
    print("all runs: " + "; ".join(f"{t}: {v[0]} ({v[1]}, {v[2]})" for t, v in total.items()))
    a.out.write_text(json.dumps({"runs": results, "total": total}))


if __name__ == "__main__":
    main()
