"""`fit`'s report: DIR/report.md with the robot, the plan, the stages' wall time, the training
curves, the evaluation tables (our scenarios and the held-out appearance set) and plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rhaml_jax.fitting._plan import Plan, stage_counts, stage_seconds


def _fmt(v) -> str:
    return "" if v is None else f"{v[0]:.1f} / {v[1]:.1f} / {v[2]:.1f}"


def _results(out: Path, plan: Plan) -> dict[tuple[str, str], dict]:
    """(evaluation set, modules) -> evaluate's JSON, for every result written."""
    from rhaml_jax.fitting._plan import eval_modules

    found = {}
    for name in plan.eval_sets:
        for modules in eval_modules(name):
            path = out / "eval" / "results" / f"{name.replace('/', '_')}_{modules.replace(',', '+')}.json"
            if path.exists():
                found[name, modules] = json.loads(path.read_text())
    return found


def evaluation_rows(results: dict) -> list[tuple[str, str, dict]]:
    """(evaluation set, modules, `metrics.frame_summary` + evaluate's FPS) for every result."""
    from rhaml_jax.metrics import frame_summary

    return [(name, modules, frame_summary(res["frames"]) | {"fps": res["metrics"].get("fps")})
            for (name, modules), res in results.items()]


def _seen(res: dict) -> list[dict]:
    return [f for f in res["frames"] if f["observed"] and f["est"] is not None]


def _plots(out: Path, results: dict) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rhaml_jax.metrics import abs_errors

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, name in zip(axes, ("circle", "sine")):
        for modules, style in (("iml", "."), ("iml,ir,pgo", "-")):
            seen = _seen(results[name, modules]) if (name, modules) in results else []
            if seen:  # a set where nothing was detected has no trajectory to draw
                est = np.array([f["est"] for f in seen])
                ax.plot(est[:, 0], est[:, 1], style, ms=2, lw=1, label=modules.upper().replace(",", "+"))
        if (name, "iml") in results:
            gt = np.array([f["gt"] for f in results[name, "iml"]["frames"] if f["observed"]])
            ax.plot(gt[:, 0], gt[:, 1], "k--", lw=1, label="ground truth")
        ax.set_title(f"{name} (observer's frame)"), ax.set_xlabel("x (m)"), ax.set_ylabel("y (m)"), ax.axis("equal")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "report_trajectories.png", dpi=80)
    plt.close(fig)

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for name in ("circle", "sine", "heldout/circle", "heldout/sine"):
        fr = _seen(results[name, "iml,ir"]) if (name, "iml,ir") in results else []
        if fr:
            e = np.asarray(abs_errors(np.array([f["est"] for f in fr]), np.array([f["gt"] for f in fr])))
            for ax, col in zip(axes, (100 * e[:, 0], 100 * e[:, 1], np.degrees(e[:, 2]))):
                ax.hist(col, bins=30, histtype="step", label=name)
    for ax, lab in zip(axes, ("abs dx (cm)", "abs dy (cm)", "abs dpsi (deg)")):
        ax.set_xlabel(lab), ax.set_yscale("log")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.suptitle("IML+IR errors per frame")
    fig.tight_layout()
    fig.savefig(out / "report_errors.png", dpi=80)
    plt.close(fig)
    return ["report_trajectories.png", "report_errors.png"]


def _flip_lines(out: Path, results: dict) -> list[str]:
    """How well IML's flip probability predicts its flips on each set (`zoom.calibration_metrics`)."""
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta

    cal = checkpoint_meta(out / "networks" / "zoom").get("flip_calibration") if (out / "networks" / "zoom").is_dir() else None
    lines = ["", "## Flip probability", "",
             (f"IML's flip probability: sigmoid({cal['a']:.3f} + {cal['b']:.3f} r) of the zoom stage's front/back ranking r, "
              f"fitted on {cal['frames']} detected frames ({cal['flips']} flipped) of {cal['source']}."
              if cal else "IML's flip probability is the zoom stage's raw front/back ranking (not calibrated)."),
             "Flips by the robot's view (`metrics.flips_by_view`; back: its back faces the camera): a network that reads "
             "the front from the paint flips the back views of a paint it never saw.",
             "", "| data | flips | back / side / front views | mean probability | Brier | ECE | ROC area |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    f = lambda v: "" if v is None else f"{v:.3f}"  # noqa: E731
    for (name, modules), res in results.items():
        m, views = res["metrics"].get("iml_flip"), res["metrics"].get("iml_flips_by_view", {})
        by_view = " / ".join(f"{k} {n} of {t}" for k, (n, t) in views.items())
        if modules == "iml" and m and m["frames"]:
            lines.append(f"| {name} | {m['flips']} / {m['frames']} | {by_view} | {f(m['mean_prob'])} | {f(m['brier'])} "
                         f"| {f(m['ece'])} | {f(m['auroc'])} |")
    return lines


def write_report(out: Path, model, plan: Plan) -> Path:
    """Writes DIR/report.md (and its plots); returns its path."""
    out = Path(out)
    state = json.loads((out / "fit.json").read_text())
    results = _results(out, plan)
    rows = evaluation_rows(results)
    from rhaml_jax.data import SynthConfig
    from rhaml_jax.robots import RobotFingerprint

    fp = RobotFingerprint.from_dict(state["robot"])
    depths = SynthConfig().scaled(plan.scale).depth_m
    lines = [f"# fit report: {fp.name}", "",
             f"Robot: {fp.describe()}; {len(model.faces)} faces. Networks: `{out / 'networks'}` "
             f"(`evaluate --amlnet {out / 'networks/amlnet'} --zoom {out / 'networks/zoom'} --refiner {out / 'networks/refiner'} --fine-refiner {out / 'networks/fine'}`).",
             "", "## Plan and wall time", "",
             f"Budget {plan.budget_minutes:g} min, size {plan.size}: {plan.images} training images with the robot and "
             f"{plan.negatives} without at {plan.width} x {plan.height}; AMLNet `{plan.amlnet_config}` {plan.amlnet_steps} "
             f"steps of {plan.amlnet_batch}, then {plan.amlnet_nocart_steps} on {plan.nocart_images} + {plan.nocart_negatives} "
             f"images without robot-like carts, zoom `{plan.zoom_config}` {plan.zoom_steps} steps, refiner `{plan.refiner_config}` "
             f"{plan.refiner_steps} steps, the first {plan.refiner_v1_steps} on {plan.refine_v1_images} plain-look (v1) images "
             f"at {plan.eval_width} x {plan.eval_height}, the rest on those and {plan.refine_images} v3 ones together, then the fine "
             f"refiner `{plan.fine_config}` {plan.refiner_fine_steps} steps on those from the refiner's weights; "
             f"{plan.frames} frames per evaluation scenario at {plan.eval_width} x {plan.eval_height}. "
             f"Distances x {plan.scale:g} of the Pioneer's (training depths {depths[0]:.2f}-{depths[1]:.2f} m, "
             f"circle radius {2.0 * plan.scale:.2f} m about {4.5 * plan.scale:.2f} m ahead); AMLNet and zoom "
             + ("fine-tuned from the shipped Pioneer networks." if plan.warm_start else
                f"trained from random weights, the zoom stage's first {plan.zoom_v1_steps} steps on {plan.v1_images} "
                "plain-look (v1) images."),
             "", "| stage | seconds | planned at the rule's rates |", "| --- | --- | --- |"]
    planned = stage_seconds(plan, len(model.faces))
    lines += [f"| {k} | {v:.0f} | {planned[k]:.0f} |" for k, v in state["done"].items()]
    made = stage_counts(Plan.from_dict(state.get("planned", state["plan"])))
    paced = [f"{k} {made[k]} -> {n}" for k, n in stage_counts(plan).items() if n != made[k]]
    if paced:
        lines += ["", f"Paced (behind the budget, the counts of stages not yet begun were scaled down): {', '.join(paced)}."]
    if state.get("lost"):
        lines += ["", "Killed and resumed; the seconds above include each killed attempt's, up to its last file: "
                  + ", ".join(f"{k} {v:.0f} s" for k, v in state["lost"].items()) + "."]
    lines += ["", f"Total so far: {sum(state['done'].values()) / 60:.1f} min.", "", "## Training curves", ""]
    lines += [f"![{k}](runs/{k}/metrics.png)" for k in ("amlnet", "amlnet_nocart", "zoom_v1", "zoom", "refiner_v1", "refiner", "refiner_fine") if (out / "runs" / k / "metrics.png").exists()]
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
    lines += _flip_lines(out, results)
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in _plots(out, results)]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    (out / "report.json").write_text(json.dumps({"state": state, "rows": rows}, indent=1))
    return path
