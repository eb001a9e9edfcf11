"""`fit`'s report: DIR/report.md with the robot, the plan, the stages' wall time, the training
curves, the evaluation tables (our scenarios and the held-out appearance set) and plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rhaml_jax.fitting._plan import Plan


def _fmt(v) -> str:
    return "" if v is None else f"{v[0]:.1f} / {v[1]:.1f} / {v[2]:.1f}"


def evaluation_rows(out: Path, plan: Plan) -> list[tuple[str, str, dict]]:
    """(evaluation set, modules, `metrics.frame_summary` + evaluate's FPS) for every result."""
    from rhaml_jax.fitting._run import eval_modules
    from rhaml_jax.metrics import frame_summary

    rows = []
    for name in plan.eval_sets:
        for modules in eval_modules(name):
            path = out / "eval" / "results" / f"{name.replace('/', '_')}_{modules.replace(',', '+')}.json"
            if path.exists():
                res = json.loads(path.read_text())
                rows.append((name, modules, frame_summary(res["frames"]) | {"fps": res["metrics"].get("fps")}))
    return rows


def _plots(out: Path, rows) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    results = out / "eval" / "results"
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, name in zip(axes, ("circle", "sine")):
        for modules, style in (("iml", "."), ("iml,ir,pgo", "-")):
            path = results / f"{name}_{modules.replace(',', '+')}.json"
            if not path.exists():
                continue
            fr = [f for f in json.loads(path.read_text())["frames"] if f["observed"] and f["est"] is not None]
            est = np.array([f["est"] for f in fr])
            ax.plot(est[:, 0], est[:, 1], style, ms=2, lw=1, label=modules.upper().replace(",", "+"))
        gt_path = results / f"{name}_iml.json"
        if gt_path.exists():
            gt = np.array([f["gt"] for f in json.loads(gt_path.read_text())["frames"] if f["observed"]])
            ax.plot(gt[:, 0], gt[:, 1], "k--", lw=1, label="ground truth")
        ax.set_title(f"{name} (observer's frame)"), ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.axis("equal")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "report_trajectories.png", dpi=80)
    plt.close(fig)
    written.append("report_trajectories.png")

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for name in ("circle", "sine", "heldout/circle", "heldout/sine"):
        path = results / f"{name.replace('/', '_')}_iml+ir.json"
        if not path.exists():
            continue
        fr = [f for f in json.loads(path.read_text())["frames"] if f["observed"] and f["est"] is not None]
        if not fr:
            continue
        d = np.array([f["est"] for f in fr]) - np.array([f["gt"] for f in fr])
        errs = (np.abs(d[:, 0]) * 100, np.abs(d[:, 1]) * 100, np.degrees(np.abs(np.arctan2(np.sin(d[:, 2]), np.cos(d[:, 2])))))
        for ax, e in zip(axes, errs):
            ax.hist(e, bins=30, histtype="step", label=name)
    for ax, lab in zip(axes, ("abs dx (cm)", "abs dy (cm)", "abs dpsi (deg)")):
        ax.set_xlabel(lab), ax.set_yscale("log")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.suptitle("IML+IR errors per frame")
    fig.tight_layout()
    fig.savefig(out / "report_errors.png", dpi=80)
    plt.close(fig)
    written.append("report_errors.png")
    return written


def write_report(out: Path, model, plan: Plan) -> Path:
    """Writes DIR/report.md (and its plots); returns its path."""
    out = Path(out)
    state = json.loads((out / "fit.json").read_text())
    rows = evaluation_rows(out, plan)
    from rhaml_jax.robots import RobotFingerprint

    fp = RobotFingerprint.from_dict(state["robot"])
    lines = [f"# fit report: {fp.name}", "",
             f"Robot: {fp.describe()}; {len(model.faces)} faces. Networks: `{out / 'networks'}` "
             f"(`evaluate --amlnet {out / 'networks/amlnet'} --zoom {out / 'networks/zoom'} --refiner {out / 'networks/refiner'}`).",
             "", "## Plan and wall time", "",
             f"Budget {plan.budget_minutes:g} min, size {plan.size}: {plan.images} training images with the robot and "
             f"{plan.negatives} without at {plan.width} x {plan.height}; AMLNet `{plan.amlnet_config}` {plan.amlnet_steps} "
             f"steps of {plan.amlnet_batch}, zoom `{plan.zoom_config}` {plan.zoom_steps} steps, refiner `{plan.refiner_config}` "
             f"{plan.refiner_steps} steps; {plan.frames} frames per evaluation scenario at {plan.eval_width} x {plan.eval_height}.",
             "", "| stage | seconds |", "| --- | --- |"]
    lines += [f"| {k} | {v:.0f} |" for k, v in state["done"].items()]
    lines += ["", f"Total so far: {sum(state['done'].values()) / 60:.1f} min.", "", "## Training curves", ""]
    lines += [f"![{k}](runs/{k}/metrics.png)" for k in ("amlnet", "zoom", "refiner") if (out / "runs" / k / "metrics.png").exists()]
    lines += ["", "## Evaluation", "",
              "Over the frames with the robot in view that were detected: mean / std / median; flips: |dpsi| > 90 deg; "
              "detection over every frame. `heldout/*`: the held-out appearance set (settings outside every training "
              "range; nothing trains or tunes on it).", "",
              "| data | modules | abs dx (cm) | abs dy (cm) | abs dpsi (deg) | ATE | flips | median est/true range | detection (tp / fp / fn / tn) | FPS |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, modules, r in rows:
        d = r["detection"]
        det = f"{d['tp']} / {d['fp']} / {d['fn']} / {d['tn']}"
        fps = "" if r.get("fps") is None else f"{r['fps']:.1f}"
        if "dx_cm" not in r:
            lines.append(f"| {name} | {modules} | | | | | | | {det} | {fps} |")
            continue
        lines.append(f"| {name} | {modules} | {_fmt(r['dx_cm'])} | {_fmt(r['dy_cm'])} | {_fmt(r['dpsi_deg'])} | {r['ate']:.3f} "
                     f"| {r['flips']} / {r['n']} | {r['median_range_ratio']:.3f} | {det} | {fps} |")
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in _plots(out, rows)]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    (out / "report.json").write_text(json.dumps({"state": state, "rows": rows}, indent=1))
    return path
