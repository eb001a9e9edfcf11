"""Two moving robots, as Algorithm 2 is written: a `generate --scenario rendezvous` sequence
(both robots drive, each camera sees the other at times, both odometries noisy) through the
pipeline, batch and online: error of A_0 T B_0 and of the per-frame relative poses.

  python experiments/two_robots.py --data /work/data/rendezvous --out two_robots.json [--combos iml,pgo]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--combos", nargs="+", default=["iml", "iml,pgo"])
    a = ap.parse_args()
    import jax

    from rhaml_jax import iml, pipeline, planar, tune_allocator
    from rhaml_jax.data import read_bop, read_tum
    from rhaml_jax.evaluate import score
    from rhaml_jax.sequence import group_scenes, interleave, load_scene

    tune_allocator()
    scenes = list(group_scenes(read_bop(a.data)).values())
    if len(scenes) != 2:
        raise SystemExit(f"{a.data}: expected the two scenes of a rendezvous sequence, found {len(scenes)}")
    data = interleave(load_scene(scenes[0]), load_scene(scenes[1]))
    folder = scenes[0][0].rgb.parent.parent
    _, truth_a = read_tum(folder / "observer_groundtruth.txt")
    _, truth_b = read_tum(folder / "observed_groundtruth.txt")
    true_a0_T_b0 = planar.between(truth_a[0], truth_b[0])
    iml_model, iml_params = iml.load_iml(zoom_mirror=True)
    rows = []
    for combo in a.combos:
        mods = tuple(combo.split(","))
        for mode in (["batch", "online"] if "pgo" in mods else ["-"]):
            cfg = pipeline.PipelineConfig(modules=mods, pgo_mode="batch" if mode == "-" else mode)
            refiner = refiner_params = None
            if "ir" in mods:
                from rhaml_jax import refine

                refiner, refiner_params = refine.load_stage(None, a.data)
            model = pipeline.PipelineModel(iml_model, cfg, refiner)
            params = pipeline.PipelineParams(iml_params, refiner_params)
            f = pipeline.run_jit.lower(model, params, data.seq).compile()
            t = time.perf_counter()
            res = jax.device_get(f(params, data.seq))
            seconds = time.perf_counter() - t
            m = score(np.asarray(res.xypsi), np.asarray(res.detected), data.observed, data.gt)
            row = {"modules": combo, "pgo_mode": mode, **m, "fps": len(data.frames) / seconds}
            if res.fusion is not None:
                a0 = np.asarray(res.fusion.a0_T_b0)
                a0 = a0[-1] if a0.ndim == 2 else a0  # online: after the last frame
                d = planar.between(true_a0_T_b0, a0.astype(np.float64))
                row |= {"a0_T_b0_error_cm": float(100 * np.hypot(d[0], d[1])), "a0_T_b0_error_deg": float(np.degrees(abs(d[2]))),
                        "rejected": int((np.asarray(res.detected) & ~np.asarray(res.fusion.inlier)).sum()),
                        "false_positives_rejected": int((np.asarray(res.detected) & ~data.observed
                                                         & ~np.asarray(res.fusion.inlier)).sum())}
            print(json.dumps(row), flush=True)
            rows.append(row)
    json.dump({"frames": len(data.frames), "observed": int(data.observed.sum()), "rows": rows}, open(a.out, "w"), indent=1)
    print(table(rows))


def table(rows: list[dict]) -> str:
    """The rows as BENCHMARKS.md's Markdown table."""
    pm = lambda v: f"{v[0]:.1f} +- {v[1]:.1f}"  # noqa: E731
    out = ["| modules | PGO | abs dx (cm) | abs dy (cm) | abs dpsi (deg) | ATE | A_0 T B_0 error | detection tp / fp / fn / tn |",
           "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        d = r["detection"]
        a0 = f"{r['a0_T_b0_error_cm']:.1f} cm, {r['a0_T_b0_error_deg']:.2f} deg" if "a0_T_b0_error_cm" in r else ""
        out.append(f"| {r['modules'].upper().replace(',', '+')} | {'' if r['pgo_mode'] == '-' else r['pgo_mode']} | "
                   f"{pm(r['dx_cm'])} | {pm(r['dy_cm'])} | {pm(r['dpsi_deg'])} | {r['ate']:.3f} | {a0} | "
                   f"{d['tp']} / {d['fp']} / {d['fn']} / {d['tn']} |")
    return "\n".join(out)


if __name__ == "__main__":
    main()
