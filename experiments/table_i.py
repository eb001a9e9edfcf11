"""Table I (the paper's method comparison) at our scale: FrontNet retrained on our data, the
shipped AMLNet alone (the whole image, FrontNet's setting) and under its zoom-in stage (the
pipeline's IML), and RHAML (IML + IR + PGO), on circle + sine (ours and the held-out set).

  python experiments/table_i.py --data /work/data/v1_train --ours /work/data/ours \
      --heldout /work/data/heldout --runs /work/runs/table_i --out experiments/results/table_i.json \
      [--amlnet CKPT --zoom CKPT]   (other networks, e.g. the paper's scale trained elsewhere)

Resumable: a finished FrontNet training is reused, an interrupted one resumes from its
checkpoint; the JSON and the .npz beside it are rewritten after every row. The .npz holds the
per-frame estimates of every row and set (keys ROW/SET/est, ROW/SET/gt: (N, 3) x, y (m), psi
(rad); ROW/SET/scenario: (N,) "circle" | "sine"; the detected frames with the robot in view;
truth/SET/SCENARIO: every in-view frame's true pose), which fig5_violin.py and
fig6_trajectories.py plot without evaluating again.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _paper  # noqa: E402

ROWS = {"frontnet": "FrontNet", "amlnet": "AMLNet (whole image)", "iml": "AMLNet (IML)", "rhaml": "RHAML"}
MODULES = {"frontnet": ("iml",), "amlnet": ("iml",), "iml": ("iml",), "rhaml": ("iml", "ir", "pgo")}
# DESIGN.md section 6: (dx, dy (cm), dpsi (deg): mean, std), ATE, params (M), MACs (G); both AMLNet rows
# stand beside the paper's AMLNet (the paper's IML is AMLNet on the whole 224 x 224 image).
_AML = ((2.9, 2.3), (7.3, 6.6), (6.8, 12.9), 0.29, 49.8, 8.8)
PAPER = {"frontnet": ((30.3, 36.7), (50.9, 75.8), (64.9, 53.2), 2.21, 0.33, 0.07), "amlnet": _AML, "iml": _AML,
         "rhaml": ((1.6, 1.5), (0.9, 1.1), (0.4, 0.4), 0.03, 109, 50.7)}


def refiner_size() -> dict:
    """The default IR cascade as the pipeline loads it (`refine.load_stage()`: the refiner for
    `RefineConfig` n_iter iterations, the front/back scorer once per hypothesis, then each fine
    refiner of the ensemble for fine_iter; a mirrored iteration reads its crop twice): parameters (leaves of every params pytree) and MACs
    per frame at batch 1, counted as amlnet/count.py counts (the jaxpr's convolutions and matrix
    products)."""
    import functools
    import math

    import jax
    import jax.numpy as jnp

    from rhaml_jax.amlnet.count import jaxpr_macs
    from rhaml_jax.refine import load_stage, net, scorer, segmenter

    cfg, stage = load_stage()
    out = {"params": 0, "macs": 0, "networks": []}
    fines = stage.fine if isinstance(stage.fine, tuple) else (stage.fine,)  # an ensemble: each member every iteration
    reads = {"none": (1, 1), "fine": (1, 2), "all": (2, 2)}[cfg.mirror]  # a mirrored iteration reads its crop twice
    coarse = (stage.refiner.cfg.n_iter if cfg.n_iter is None else cfg.n_iter) * reads[0]
    # (name, network, its params, its input, passes per frame)
    nets = [(r.cfg.name, functools.partial(net.apply, r.cfg), r.params, (1, r.cfg.crop, r.cfg.crop, 7), n)  # crop + render + mask
            for r, n in ((stage.refiner, coarse), *((f, cfg.fine_iter * reads[1]) for f in fines))]
    if stage.scorer is not None:  # a pass per heading searched (coarse grid, then the fine one), twice if mirrored
        sc = stage.scorer.cfg
        n = (sc.grid + (sc.fine if sc.fine > 1 else 0)) * (2 if cfg.scorer_mirror else 1)
        nets.append((sc.name, functools.partial(scorer.apply, sc), stage.scorer.params, (1, sc.crop, sc.crop, 3), n))
    if stage.segmenter is not None:  # one pass per frame: the alignment's observed mask
        sg = stage.segmenter.cfg
        nets.append((sg.name, functools.partial(segmenter.apply, sg), stage.segmenter.params, (1, sg.crop, sg.crop, 3), 1))
    for name, apply, p, shape, n in nets:
        x = jax.ShapeDtypeStruct(shape, jnp.float32)
        macs = int(jaxpr_macs(jax.make_jaxpr(apply)(p, x).jaxpr))
        params = int(sum(math.prod(v.shape) for v in jax.tree.leaves(p)))
        out["params"] += params
        out["macs"] += n * macs
        out["networks"].append(f"{name} x {n} ({params} params, {macs} MACs each)")
    return out


def sizes(frontnet_config, amlnet_config, zoom_config) -> dict:
    """Params and MACs per frame of each row (batch 1, each network at its input size); configs
    are names or the loaded networks' `ModelConfig`s."""
    from rhaml_jax.amlnet import describe

    fn, aml, zoom = (describe(c) for c in (frontnet_config, amlnet_config, zoom_config))
    ref = refiner_size()
    iml = {"params": aml["params"] + zoom["params"], "macs": aml["macs"] + 2 * zoom["macs"]}
    return {"frontnet": {"params": fn["params"], "macs": fn["macs"], "size_note": f"{fn['config']}, {fn['input_shape']}"},
            "amlnet": {"params": aml["params"], "macs": aml["macs"], "size_note": f"{aml['config']}, {aml['input_shape']}"},
            "iml": iml | {"size_note": f"AMLNet + {zoom['config']} x 2 (the crop and its mirror image)"},
            "rhaml": {"params": iml["params"] + ref["params"], "macs": iml["macs"] + ref["macs"],
                      "size_note": f"IML + the IR cascade: {', '.join(ref['networks'])}; rendering and the pose "
                                   "graph not counted"}}


def validation_curve(metrics_jsonl: Path) -> list[dict]:
    """Every validation of a training run: step, detection accuracy, |dx|, |dy| (cm), |dpsi| (deg)."""
    keys = ("detection_acc", "dx_cm", "dy_cm", "dpsi_deg")
    rows = [json.loads(line) for line in Path(metrics_jsonl).read_text().splitlines()]
    return [{"step": r["step"], "loss": r.get("loss"), **{k: r[f"val_{k}"] for k in keys}} for r in rows if "val_dx_cm" in r]


def run(a) -> dict:
    from rhaml_jax import iml, tune_allocator

    tune_allocator()
    out_path = Path(a.out)
    npz_path = out_path.with_suffix(".npz")
    sets = _paper.scenario_sets(a.ours, a.heldout, a.frames)
    run_dir = Path(a.runs) / f"{a.frontnet_config}_s{a.seed}"
    ck = run_dir / "checkpoints"
    step0 = max((int(p.name) for p in ck.iterdir() if p.name.isdigit()), default=0) if ck.is_dir() else 0
    tr = _paper.train("amlnet", a.frontnet_config, Path(a.data), run_dir, a.steps, a.seed, "--batch", str(a.batch),
                      "--val-every", str(max(a.steps // 8, 1)), *a.train_args)
    prev = json.loads(out_path.read_text()).get("frontnet_training", {}) if step0 and out_path.exists() else {}
    if "seconds" in prev:  # wall time of the earlier calls: all of it when the run had finished, else added
        tr["seconds"] = prev["seconds"] if step0 >= a.steps else tr["seconds"] + prev["seconds"]
    out = {"protocol": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(a).items()},
           "frontnet_training": tr | {"run": str(run_dir), "curve": validation_curve(run_dir / "metrics.jsonl")},
           "rows": {}}
    if a.amlnet and not a.zoom:
        raise SystemExit("--amlnet: give its zoom-in stage too (--zoom): the IML and RHAML rows need one")
    nets = dict(amlnet=a.amlnet, zoom=a.zoom)  # None: the shipped pair
    loads = {"frontnet": dict(amlnet=run_dir, no_zoom=True), "amlnet": dict(amlnet=a.amlnet, no_zoom=True),
             "iml": dict(nets, zoom_mirror=True), "rhaml": dict(nets, zoom_mirror=True)}
    iml_model, _ = iml.load_iml(**loads["iml"])
    size, frames = sizes(a.frontnet_config, iml_model.amlnet.cfg, iml_model.zoom.cfg), {}
    for set_name, scenes in sets.items():  # the whole true paths, detected or not: truth/SET/SCENARIO (N, 3)
        for scene in scenes:
            frames[f"truth/{set_name}/{_paper.data_root(scene[0]).name}"] = np.array([f.xypsi for f in scene if f.observed])
    for key, kw in loads.items():
        model, params = iml.load_iml(**kw)
        row = {"label": ROWS[key], "modules": list(MODULES[key]), **size[key]}
        for set_name, scenes in sets.items():
            m, f = _paper.evaluate(MODULES[key], model, params, scenes)
            row[set_name] = m
            frames |= {f"{key}/{set_name}/{k}": v for k, v in f.items()}
            print(f"{ROWS[key]:22s} {set_name:8s} {cells(m)}", flush=True)
        out["rows"][key] = row
        _paper.write_json(out_path, out)
        _paper.write_npz(npz_path, frames)
    print(markdown(out))
    return out


def cells(m: dict) -> str:
    """One metrics dict as markdown cells: |dx| | |dy| | |dpsi| | ATE | flips | detected / in view | FPS."""
    pm = lambda v: "n/a" if v is None else f"{v[0]:.1f} +- {v[1]:.1f}"  # noqa: E731
    d = m["detection"]
    ate = "n/a" if m["ate"] is None else f"{m['ate']:.3f}"
    return (f"{pm(m['dx_cm'])} | {pm(m['dy_cm'])} | {pm(m['dpsi_deg'])} | {ate} | {m['flips']} | "
            f"{d['tp']} / {d['tp'] + d['fn']} | {m['fps']:.1f}")


def markdown(out: dict) -> str:
    """Table I, one block per set, the paper's figures beside (ours only: the paper has no held-out set)."""
    head = ("| method | abs dx (cm) | abs dy (cm) | abs dpsi (deg) | ATE | flips | detected / in view | FPS "
            "| Params (M) | MACs (G) | paper: dx / dy / dpsi, ATE, Params, MACs |")
    lines = []
    sets = [s for s in ("ours", "heldout") if any(s in r for r in out["rows"].values())]
    for s in sets:
        lines += [f"\n{s}:\n", head, "|" + " --- |" * (head.count("|") - 1)]
        for key, r in out["rows"].items():
            p = PAPER[key]
            paper = (f"{p[0][0]} +- {p[0][1]} / {p[1][0]} +- {p[1][1]} / {p[2][0]} +- {p[2][1]}, {p[3]}, {p[4]} M, {p[5]} G"
                     if s == "ours" else "")
            lines.append(f"| {r['label']} | {cells(r[s])} | {r['params'] / 1e6:.2f} | {r['macs'] / 1e9:.3f} | {paper} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="BOP training set for FrontNet (train and val splits)")
    ap.add_argument("--ours", required=True, help="root with circle/ and sine/ (our renderer)")
    ap.add_argument("--heldout", default=None, help="root with the held-out circle/ and sine/")
    ap.add_argument("--runs", required=True, help="folder for FrontNet's training run")
    ap.add_argument("--out", required=True, help="results JSON (the per-frame .npz goes beside it)")
    ap.add_argument("--steps", type=int, default=4000, help="FrontNet's steps (the shipped AMLNet's 4000)")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=None, help="first N frames of each scenario")
    ap.add_argument("--frontnet-config", default="frontnet", help="e.g. tiny_frontnet for tests")
    ap.add_argument("--amlnet", default=None, help="AMLNet checkpoint of the AMLNet, IML and RHAML rows (default: the "
                                                    "shipped default, iml.DEFAULT_AMLNET; the paper's scale: a `paper`-config run)")
    ap.add_argument("--zoom", default=None, help="its zoom-in stage (default: the shipped iml.DEFAULT_ZOOM)")
    ap.add_argument("--train-args", nargs=argparse.REMAINDER, default=[], help="more train flags (last)")
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    main()
