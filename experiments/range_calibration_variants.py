"""How well the pose graph's range calibration (`pgo.range_model`) finds a localiser's range bias,
from the per-frame estimates `evaluate --modules iml,ir,pgo --json` stores (no network runs here).

  python experiments/range_calibration_variants.py --runs EVAL.json DATA [EVAL.json DATA ...] --out OUT.json

For each run, and for the refined (`ir_est`) and the IML's (`iml_est`) estimates: the pipeline's
batch fusion (`pgo.fuse_calibrated`: fuse, calibrate, rescale, fuse again, as
`pipeline.fuse_estimates`) with the range model varied: `off` (no calibration), `absolute`
(every observation's x, y error alike: the pipeline's model until session 18), `relative` (the
error a percentage of the range: the pipeline's default since), `unguarded` (relative without
the support guard: the pipeline until session 19), `slope` (relative, c_1 fitted too), `window100`
and `window200` (relative, a transform between the odometry frames per 100 or 200 consecutive rows:
the odometry's drift kept out of the scale, session 40). Prints abs dx, dy (cm) and ATE of each, the estimates'
true range bias (mean log est/true range over the fusion's inliers), the fitted c_0 and the rows the
fusion kept (`off`: the uncalibrated fusion's, which the fits start from).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import metrics, pgo
from rhaml_jax.data import read_bop
from rhaml_jax.sequence import group_scenes, load_scene


def fused(rows: list[dict], scene, key: str, variants: list[str]) -> tuple[dict, np.ndarray]:
    """Every range-model variant's fused estimates (N, 3), c (2,) and number of rows kept, and the
    uncalibrated fusion's kept rows (N,) bool (those the fits start from)."""
    seq = scene.seq
    xypsi = jnp.asarray([r[key] for r in rows], jnp.float32)
    flip = jnp.asarray([r["ir_flip_prob" if key == "ir_est" else "iml_flip_prob"] for r in rows], jnp.float32)
    det = jnp.asarray([r["detected"] for r in rows])
    cfg = pgo.FusionConfig()
    rv = pgo.rendezvous_from_frames(seq.odom_a, seq.odom_b, pgo.observation_from_xy_yaw_rp(xypsi, None), seq.a_observes)
    first = pgo.fuse_jit(rv, cfg, valid=det, flip_prob=flip)
    kept = np.asarray(first.inlier & det)
    out = {"off": (np.asarray(first.relative), np.zeros(2), int(kept.sum()))}
    for v in variants:
        kw = dict(VARIANTS[v])
        c = jnp.zeros(2)
        if kw.pop("search", False):  # start from the grid scale whose fusion keeps the most rows (ties: the smallest)
            kept_at = [int(jnp.sum(FUSE(pgo.rescale_observations(rv, jnp.array([g, 0.0])), cfg, valid=det, flip_prob=flip).inlier & det))
                       for g in SCALE_GRID]
            c = jnp.array([SCALE_GRID[int(np.argmax(np.asarray(kept_at) - 1e-3 * np.abs(SCALE_GRID)))], 0.0])
        for _ in range(kw.pop("rounds", 1)):  # each round fits what the last one's rescaling left (c_1 = 0)
            fusion, dc = FUSE_CALIBRATED(pgo.rescale_observations(rv, c), cfg, det, flip, **kw)
            c = c + dc
        out[v] = (np.asarray(fusion.relative), np.asarray(c), int(np.sum(np.asarray(fusion.inlier & det))))
    return out, kept


# the pipeline runs "relative"; all but "unguarded" keep a calibration only with the support guard
VARIANTS = {"absolute": dict(relative=False), "relative": dict(), "unguarded": dict(min_support=0.0),
            "slope": dict(slope=True), "window100": dict(window=100), "window200": dict(window=200)}
# session 41: consecutive windows tied by a random walk of the odometry's drift (m, m, rad per window)
DRIFT = {"s": (0.02, 0.02, 0.005), "m": (0.05, 0.05, 0.01), "l": (0.15, 0.15, 0.03)}
VARIANTS |= {f"walk{w}{k}": dict(window=w, drift_sigma=d) for w in (50, 100, 200) for k, d in DRIFT.items()}
VARIANTS |= {f"{v}_r{n}": VARIANTS[v] | dict(rounds=n) for v in ("relative", "window200", "walk200s") for n in (2, 3)}
VARIANTS |= {f"hybrid{t}": dict(window=200, window_max_scale=t / 100) for t in (2, 5, 10)}
# scale search: the log scales tried before the fit (whole range the guard allows, 5 % apart)
SCALE_GRID = np.round(np.arange(-0.3, 0.301, 0.05), 3)
VARIANTS |= {"search": dict(search=True), "search_hybrid2": dict(search=True, window=200, window_max_scale=0.02)}
FUSE = jax.jit(pgo.fuse, static_argnames=("cfg",))
FUSE_CALIBRATED = jax.jit(pgo.fuse_calibrated, static_argnames=("cfg", "relative", "slope", "window", "drift_sigma", "window_max_scale"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="+", help="pairs: evaluate --json output, its BOP data folder")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), help="the fits to run (default: all)")
    ap.add_argument("--summary", action="store_true",
                    help="only print the summary of an earlier --out (with --variants: also their ATE per run)")
    a = ap.parse_args()
    if a.summary:
        return summary(json.loads(a.out.read_text()), a.variants if "--variants" in sys.argv else None)
    if unknown := set(a.variants) - set(VARIANTS):
        ap.error(f"--variants: unknown {sorted(unknown)}; expected some of {list(VARIANTS)}")
    if not a.runs or len(a.runs) % 2:
        ap.error("--runs takes pairs EVAL.json DATA")
    out = []
    for js, data in zip(a.runs[::2], a.runs[1::2]):
        rows = json.loads(Path(js).read_text())["frames"]
        if "ir_est" not in rows[0]:
            ap.error(f"{js}: no ir_est rows (run evaluate --modules iml,ir,pgo)")
        scene = load_scene(list(group_scenes(read_bop(Path(data))).values())[0])
        gt, seen = scene.gt, scene.observed
        for key in ("ir_est", "iml_est"):
            est0 = np.array([r[key] for r in rows])
            variants, kept = fused(rows, scene, key, a.variants)
            k = kept & seen
            bias = float(np.mean(np.log(np.hypot(*est0[k, :2].T) / np.hypot(*gt[k, :2].T))))
            for v, (est, c, n_kept) in variants.items():
                m = metrics.summarize(est[seen], gt[seen])
                out.append({"run": js, "estimates": key, "variant": v, "dx_cm": m["dx_cm"][0], "dy_cm": m["dy_cm"][0],
                            "ate": m["ate"], "c": c.tolist(), "bias": bias,
                            "kept": n_kept, "detected": int(np.sum([r["detected"] for r in rows]))})
                print(f"{Path(js).name:36s} {key:7s} {v:8s} dx {m['dx_cm'][0]:5.2f} dy {m['dy_cm'][0]:5.2f} "
                      f"ATE {m['ate']:.4f}  bias {100 * bias:+.2f} %  c0 {100 * c[0]:+.2f} %  kept {n_kept}", flush=True)
    a.out.write_text(json.dumps(out, indent=1))
    summary(out)


def summary(out: list[dict], variants: list[str] | None = None) -> None:
    """Each fit's geometric-mean ATE over the runs, per kind of estimates; with `variants`, also
    those fits' ATE per run."""
    for key in ("ir_est", "iml_est") if variants else ():
        print(f"{key} ATE per run: " + " / ".join(variants))
        for run in dict.fromkeys(r["run"] for r in out):
            ate = {r["variant"]: r["ate"] for r in out if r["run"] == run and r["estimates"] == key}
            print(f"  {Path(run).name:44s} " + " / ".join(f"{ate[v]:.4f}" for v in variants))
    print("geometric mean over the runs of each fit's ATE:")
    for key in ("ir_est", "iml_est"):
        ate = {}
        for r in out:
            if r["estimates"] == key:
                ate.setdefault(r["variant"], []).append(r["ate"])
        print(f"  {key}: " + ", ".join(f"{v} {np.exp(np.mean(np.log(x))):.4f}" for v, x in ate.items()))


if __name__ == "__main__":
    main()
