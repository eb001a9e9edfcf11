"""`python -m rhaml_jax.demo`: the main job (DESIGN.md section 5).

Generates the paper's circle and sine scenarios (a rerun keeps what is complete), runs the
module combinations IML, IML+IR, IML+PGO and IML+IR+PGO of the jitted pipeline with the shipped
networks, prints the paper's Table III layout with the paper's figures beside ours, and writes
the plots a reader wants: the trajectories of Fig. 6 and the per-DoF error violins of Fig. 5.

  python -m rhaml_jax.demo [--out out/demo] [--frames 200] [--seed 0]

`--frames 500` gives the paper's 1000 evaluation points (BENCHMARKS.md reports those); the
default keeps the demo within 10 minutes on a 2-core CPU, install included.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import tyro

from rhaml_jax.allocator import tune_allocator
from rhaml_jax.errors import RhamlError, run_cli

COMBINATIONS = (("iml",), ("iml", "ir"), ("iml", "pgo"), ("iml", "ir", "pgo"))
# DESIGN.md section 6, Table III: |dx|, |dy| (cm), |dpsi| (deg), ATE, FPS (RTX 3060 Ti)
PAPER_TABLE_III = {"iml": (2.9, 7.3, 6.8, 0.29, 34.5), "iml,ir": (1.3, 4.9, 2.9, 0.30, 7.7),
                   "iml,pgo": (6.1, 13.0, 2.6, 0.17, 2.2), "iml,ir,pgo": (1.6, 0.9, 0.4, 0.03, 1.8)}
SCENARIOS = ("circle", "sine")


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = Path("out/demo")
    """folder for the generated scenarios, results.json and the figures"""
    frames: int = 200
    """frames per scenario (the paper: 500 each)"""
    seed: int = 0
    """scenario seed (odometry noise, rooms)"""
    workers: int = 2
    """rendering processes"""


def _combination_available(mods) -> str | None:
    """None if the combination can run with what is installed, else why not."""
    if "ir" not in mods:
        return None
    try:
        from rhaml_jax.refine import DEFAULT_REFINER
    except ImportError:
        return "this build has no refinement stage (rhaml_jax.refine)"
    from rhaml_jax.amlnet import shipped_checkpoint

    try:
        shipped_checkpoint(DEFAULT_REFINER)
    except RhamlError as e:
        return str(e)
    return None


def run_combination(mods, iml_model, iml_params, scenes: list, data_dir: Path, fusion=None,
                    refiner_dir: Path | None = None, fine_dir: Path | str | list[Path | str] | None = None,
                    segmenter_dir: Path | str | None = None) -> tuple[dict, list]:
    """One module combination over BOP scenes (lists of frames) with the given IML (and for "ir"
    the refiner in `refiner_dir` with the fine refiner `fine_dir` and the segmenter `segmenter_dir`,
    as `refine.load_stage` takes them: by default the shipped cascade and segmenter): (the paper's
    metrics over all scenes + fps, the SceneRuns)."""
    from rhaml_jax import pgo, pipeline
    from rhaml_jax.evaluate import score
    from rhaml_jax.planar import wrap_angle
    from rhaml_jax.sequence import run_scenes

    refiner = refiner_params = None
    if "ir" in mods:
        from rhaml_jax import refine

        refiner, refiner_params = refine.load_stage(refiner_dir, data_dir, fine=fine_dir, segmenter=segmenter_dir)
    cfg = pipeline.PipelineConfig(modules=tuple(mods), fusion=fusion or pgo.FusionConfig())
    model = pipeline.PipelineModel(iml_model, cfg, refiner)
    runs, compile_s, seconds = run_scenes(model, pipeline.PipelineParams(iml_params, refiner_params), scenes)
    cat = lambda f: np.concatenate([f(r) for r in runs])  # noqa: E731
    m = score(cat(lambda r: r.result.xypsi), cat(lambda r: r.result.detected), cat(lambda r: r.data.observed),
              cat(lambda r: r.data.gt))
    dpsi = np.abs(wrap_angle(cat(lambda r: r.result.xypsi[:, 2]) - cat(lambda r: r.data.gt[:, 2])))
    m["flips"] = int((dpsi[cat(lambda r: r.data.observed)] > np.pi / 2).sum())  # front/back confusions
    return m | {"fps": sum(len(r.data.frames) for r in runs) / seconds, "compile_seconds": round(compile_s, 1)}, runs


def _table(rows: dict) -> str:
    head = (f"{'modules':<12} {'abs dx (cm)':>16} {'abs dy (cm)':>16} {'abs dpsi (deg)':>16} {'ATE':>6} {'FPS':>7}"
            f"   | paper: dx / dy / dpsi, ATE, FPS (RTX 3060 Ti)")
    lines = [head, "-" * len(head)]
    for key, paper in PAPER_TABLE_III.items():
        name = key.upper().replace(",", "+")
        p = f"   | {paper[0]} / {paper[1]} / {paper[2]}, {paper[3]}, {paper[4]}"
        r = rows.get(key)
        if r is None or "skipped" in r:
            why = "not run" if r is None else r["skipped"]
            lines.append(f"{name:<12} {'(' + why + ')':<65}{p}")
            continue
        f = lambda v: f"{v[0]:.1f} +- {v[1]:.1f}"  # noqa: E731
        lines.append(f"{name:<12} {f(r['dx_cm']):>16} {f(r['dy_cm']):>16} {f(r['dpsi_deg']):>16} "
                     f"{r['ate']:>6.3f} {r['fps']:>7.1f}{p}")
    return "\n".join(lines)


def _plots(out: Path, runs_by_combo: dict) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, axes = plt.subplots(1, len(SCENARIOS), figsize=(6 * len(SCENARIOS), 5))
    for ax, name in zip(np.atleast_1d(axes), SCENARIOS):
        first = next(iter(runs_by_combo.values()))[name]
        obs = first.data.observed
        ax.plot(first.data.gt[obs, 1], first.data.gt[obs, 0], "k-", lw=2.5, label="ground truth")
        for key, runs in runs_by_combo.items():
            r = runs[name]
            ax.plot(r.result.xypsi[obs, 1], r.result.xypsi[obs, 0], ".", ms=2.5, label=key.upper().replace(",", "+"))
        ax.plot([0], [0], "k^", ms=9, label="observer")
        ax.set(title=f"{name} (observer's frame)", xlabel="y (m)", ylabel="x (m)", aspect="equal")
        ax.invert_xaxis()  # y to the left, as seen from above with x up
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    paths.append(out / "fig6_trajectories.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    key = next(k for k in reversed(list(PAPER_TABLE_III)) if k in runs_by_combo)  # the fullest combination run
    err = []
    for name in SCENARIOS:
        r = runs_by_combo[key][name]
        from rhaml_jax import metrics

        obs = r.data.observed
        err.append(np.asarray(metrics.abs_errors(r.result.xypsi[obs], r.data.gt[obs])))
    e = np.concatenate(err) * np.array([100.0, 100.0, 180.0 / np.pi])
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.violinplot([e[:, 0], e[:, 1], e[:, 2]], showmedians=True)
    ax.set_xticks([1, 2, 3], ["abs dx (cm)", "abs dy (cm)", "abs dpsi (deg)"])
    ax.set_title(f"{key.upper().replace(',', '+')}: per-DoF errors, {len(e)} frames (Fig. 5)")
    fig.tight_layout()
    paths.append(out / "fig5_violin.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def run(args: Args) -> dict:
    from rich.console import Console

    from rhaml_jax import iml
    from rhaml_jax.camera import DEFAULT_CAMERA
    from rhaml_jax.data import bop_model_path, load_bop_model, read_bop, write_scenario
    from rhaml_jax.sequence import group_scenes

    if args.frames < 2:
        raise RhamlError(f"--frames must be at least 2, got {args.frames}")
    console = Console(stderr=True)
    t0 = time.perf_counter()
    scenes = {}
    for name in SCENARIOS:
        folder = args.out / name
        console.print(f"[bold]demo[/]: {name} scenario, {args.frames} frames -> {folder}")
        write_scenario(folder, name, "pioneer3dx", DEFAULT_CAMERA, args.seed, args.frames, args.workers)
        scenes[name] = list(group_scenes(read_bop(folder)).values())
    generate_s = time.perf_counter() - t0
    first = args.out / SCENARIOS[0]
    iml_model, iml_params = iml.load_iml(zoom_mirror=True)  # the built-in robot is left-right symmetric
    iml.check_mirror_symmetric(load_bop_model(first), bop_model_path(first))
    rows, runs_by_combo = {}, {}
    for mods in COMBINATIONS:
        key = ",".join(mods)
        why = _combination_available(mods)
        if why is not None:
            rows[key] = {"skipped": why}
            console.print(f"[yellow]demo[/]: {key.upper().replace(',', '+')} skipped: {why}")
            continue
        console.print(f"[bold]demo[/]: running {key.upper().replace(',', '+')} (compiles once, then both scenarios)")
        rows[key], runs = run_combination(mods, iml_model, iml_params, [s for name in SCENARIOS for s in scenes[name]],
                                          first)
        runs_by_combo[key] = dict(zip(SCENARIOS, runs))
    table = _table(rows)
    print(table)
    figures = _plots(args.out, runs_by_combo)
    res = {"frames_per_scenario": args.frames, "rows": rows, "paper_table_iii": PAPER_TABLE_III,
           "generate_seconds": round(generate_s, 1), "seconds": round(time.perf_counter() - t0, 1),
           "figures": [str(p) for p in figures]}
    (args.out / "results.json").write_text(json.dumps(res, indent=1))
    print(f"\nfigures: {', '.join(str(p) for p in figures)}; numbers: {args.out / 'results.json'} "
          f"({res['seconds']:.0f} s in all)", file=sys.stderr)
    return res


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    tune_allocator()
    return run(args)


if __name__ == "__main__":
    run_cli(main)
