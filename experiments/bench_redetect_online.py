"""Online re-detection in one pass (`pgo.fuse_online_redetect`, the pipeline's default) against
session 35's two passes (online fusion of the confident frames, the gate, online fusion again) and
against no re-detection: time of the pose-graph stage and its answer, on stored evaluate runs.

  python experiments/bench_redetect_online.py --runs EVAL.json DATA [EVAL.json DATA ...] [--repeats 5]

Each EVAL.json is an `evaluate --modules iml,ir,pgo --json` run on the BOP data DATA (its scenes
fused one by one, as evaluate does, and scored together). The pose
graph is fed what the pipeline feeds it: the stored IR estimates, their flip probabilities, the
objectness (confident: o >= 0.5; candidates: o >= 0.2). Times: median over `--repeats` calls after
the compiling one, float32, all three methods in one process side by side; the machine's load
average is printed. Answer: robots found (detected and in view), false positives, and the ATE
of the fused poses over the detected frames with the robot in view (as `evaluate` scores it).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import pipeline
from rhaml_jax.data import read_bop
from rhaml_jax.evaluate import score
from rhaml_jax.iml import Estimate
from rhaml_jax.metrics import DETECTION_THRESHOLD
from rhaml_jax.sequence import group_scenes, load_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import timed  # noqa: E402

CFG = pipeline.PipelineConfig(modules=("iml", "ir", "pgo"), pgo_mode="online")


def two_pass(cfg, est, detected, candidates, odom_a, odom_b, a_observes):
    """Session 35's online re-detection: frame k judged by the online graph of the confident frames
    <= k, then the whole sequence fused online again."""
    fusion, _, trusted, _ = pipeline._fuse(cfg, est, detected, odom_a, odom_b, a_observes)
    detected = detected | (trusted & candidates & pipeline.agrees(est.xypsi, fusion.relative, cfg.redetect_gate))
    fusion, c = pipeline.fuse_estimates(cfg, est, detected, odom_a, odom_b, a_observes)
    return fusion, c, detected


def off(cfg, est, detected, candidates, odom_a, odom_b, a_observes):
    fusion, c = pipeline.fuse_estimates(cfg, est, detected, odom_a, odom_b, a_observes)
    return fusion, c, detected


METHODS = {"no re-detection": jax.jit(off, static_argnums=0), "two passes (session 35)": jax.jit(two_pass, static_argnums=0),
           "one pass": jax.jit(pipeline.redetect, static_argnums=0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="+", required=True, metavar="EVAL.json DATA")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    if len(a.runs) % 2:
        ap.error("--runs: expected pairs EVAL.json DATA")
    print(f"load average {os.getloadavg()[0]:.1f} (2-core machine)\n")
    print("| run | method | pose-graph stage ms (median) | robots found | false positives | ATE |")
    print("| --- | --- | --- | --- | --- | --- |")
    for js, data in zip(a.runs[::2], a.runs[1::2]):
        rows = json.loads(Path(js).read_text())["frames"]
        scenes = []  # per scene (a rendezvous sequence has one per camera, as evaluate runs them)
        for (_, sid), frames in group_scenes(read_bop(Path(data))).items():
            scene, mine = load_scene(frames), [r for r in rows if r["scene_id"] == sid]
            n = len(mine)
            o = jnp.asarray([r["o"] for r in mine], jnp.float32)
            est = Estimate(jnp.asarray([r["ir_est"] for r in mine], jnp.float32), o,
                           jnp.asarray([r["ir_flip_prob"] for r in mine], jnp.float32),
                           jnp.asarray([r["ir_roll_pitch"] for r in mine], jnp.float32).reshape(n, 2))
            scenes.append((scene, est, o >= DETECTION_THRESHOLD, o >= CFG.redetect_threshold))
        for name, fn in METHODS.items():
            rel, det, obs, gt, total = [], [], [], [], 0.0
            for scene, est, confident, candidates in scenes:
                seq = scene.seq
                (fusion, _, d), t = timed(lambda: fn(CFG, est, confident, candidates, seq.odom_a, seq.odom_b,
                                                     seq.a_observes), a.repeats)
                rel.append(np.asarray(fusion.relative)), det.append(np.asarray(d)), obs.append(scene.observed)
                gt.append(scene.gt)
                total += t
            rel, det, obs, gt = map(np.concatenate, (rel, det, obs, gt))
            m = score(rel, det, obs, gt)
            print(f"| {Path(js).stem} | {name} | {1e3 * total:.0f} | {int((det & obs).sum())} | "
                  f"{int((det & ~obs).sum())} | {m['ate']:.3f} |", flush=True)

if __name__ == "__main__":
    main()
