"""Would a front/back scorer mend IR's flips? For every frame a stored `evaluate` run refined, the
scorer (`train --stage scorer --config scorer_flip_cpu`) rates the refined pose against it turned
by 180 deg about the model's box centre (`refine.heading_search`, as the IR stage runs it); the
per-frame probability of the other side is stored, and for each threshold the flips the scorer
would fix and make are counted against the run's own IR estimates.

    python experiments/flip_scorer.py --scorer RUN --run EV/ens_native_val_scen_s7_500_sine.json /work/data/val_scen_s7_500/sine \
        [--run ...] [--mirror] --out OUT.json

`--mirror` also reads every crop mirrored left-right (`RefineConfig.scorer_mirror`) and counts three
readings side by side: the plain crop's ("plain"), the mean of the two reads' logits ("mirror"), and
both reads past the threshold ("both").

Offline: the refined pose the scorer reads here is IR's final one (the pipeline's search runs
between the coarse and the fine iterations), so this chooses a threshold and tells whether the
scorer is worth a validation run; the validation run itself decides.
"""

from __future__ import annotations

import argparse
import functools
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


@functools.partial(jax.jit, static_argnames="mirror")
def _other_side(scorer, mesh, images, K, poses, mirror=False):
    """(B,) the probability of the other side for a batch (the pose kept: threshold 1)."""
    h = refine.RefineConfig.camera_height_m
    return jax.vmap(lambda im, k, x: refine.heading_search(scorer, mesh, im, k, x, h, 1.0, mirror)[1])(images, K, poses)


def flip_probs(scorer, mesh, images, K, poses, mirror: bool = False, batch: int = 16) -> np.ndarray:
    """(N,) the scorer's probability that each pose (N, 3) faces the wrong way (one compiled
    function for every sequence: the scorer and mesh are arguments)."""
    out = []
    for i in range(0, len(images), batch):
        sl = slice(i, i + batch)
        out.append(np.asarray(_other_side(scorer, mesh, jnp.asarray(images[sl], jnp.float32) / 255.0,
                                          jnp.asarray(K[sl]), poses[sl], mirror)))
    return np.concatenate(out)


def mirrored_alone(p_plain: np.ndarray, p_mean: np.ndarray) -> np.ndarray:
    """The mirrored read's own probability, from the plain read's and the mean of the two reads'
    logits (two hypotheses: p = sigmoid(logit difference), and the mean's difference is the mean)."""
    def logit(p):
        p = np.clip(p.astype(np.float64), 1e-9, 1 - 1e-9)  # guard: a saturated float32 probability
        return np.log(p / (1 - p))

    return 1 / (1 + np.exp(-(2 * logit(p_mean) - logit(p_plain))))


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
    ap.add_argument("--mirror", action="store_true", help="also the mirrored reads (see the module docstring)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    scorer = None
    results, total = {}, {}
    readings = ("plain", "mirror", "both") if a.mirror else ("plain",)
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
        images, K = sc.seq.images[keep], sc.seq.K[keep]
        prob = {"plain": flip_probs(scorer, mesh, images, K, poses)}
        if a.mirror:
            prob["mirror"] = flip_probs(scorer, mesh, images, K, poses, mirror=True)
            prob["both"] = np.minimum(prob["plain"], mirrored_alone(prob["plain"], prob["mirror"]))
        was = np.asarray(flipped(np.asarray(poses[:, 2]), gt[:, 2]))
        c = {k: counts(p, was) for k, p in prob.items()}
        results[ev] = {"frames": int(keep.sum()), "ir_flips": int(was.sum()), "counts": c,
                       "prob": {k: p.tolist() for k, p in prob.items()}, "ir_flipped": was.tolist()}
        print(f"{ev}: {keep.sum()} frames, IR flips {int(was.sum())}")
        for k in readings:
            for t, v in c[k].items():
                total.setdefault(k, {})[t] = tuple(x + y for x, y in zip(total.get(k, {}).get(t, (0, 0, 0)), v))
            print(f"  {k}: threshold: flips after (fixed, made) " + "; ".join(f"{t}: {v[0]} ({v[1]}, {v[2]})" for t, v in c[k].items()))
    for k in readings:
        print(f"all runs, {k}: " + "; ".join(f"{t}: {v[0]} ({v[1]}, {v[2]})" for t, v in total[k].items()))
    a.out.write_text(json.dumps({"runs": results, "total": total}))


if __name__ == "__main__":
    main()
