"""What the paper-result scripts (table_i.py, table_ii.py, e2e_finetune.py, the figures) share:
training through the public `train` command (resumable), the circle + sine sets, and one
evaluation call that returns the metrics with the per-frame errors.

Not a library module: experiments/ scripts import it by path (`sys.path` holds their folder)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def train(stage: str, config: str, data: Path, out: Path, steps: int, seed: int, *extra: str) -> dict:
    """`python -m rhaml_jax.train` in a child process (its memory is returned when it ends),
    resumed when `out` already holds checkpoints (a finished run resumes to nothing):
    {"seconds": wall of this call, "val": the last validation metrics of metrics.jsonl}."""
    cmd = [sys.executable, "-m", "rhaml_jax.train", "--stage", stage, "--config", config, "--data", str(data),
           "--out", str(out), "--steps", str(steps), "--seed", str(seed), "--no-progress", *extra]
    if (out / "checkpoints").is_dir() and any((out / "checkpoints").iterdir()):
        cmd.append("--resume")
    t = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT)
    return {"seconds": round(time.perf_counter() - t, 1), "val": last_validation(out / "metrics.jsonl"),
            "command": " ".join(cmd[1:])}


def last_validation(metrics_jsonl: Path) -> dict:
    """The val_* fields of the last metrics.jsonl line that has them ({} if none)."""
    val = {}
    for line in Path(metrics_jsonl).read_text().splitlines():
        row = json.loads(line)
        if any(k.startswith("val_") for k in row):
            val = {"step": row["step"], **{k[4:]: v for k, v in row.items() if k.startswith("val_")}}
    return val


def scenario_sets(ours: Path, heldout: Path | None, frames: int | None = None) -> dict[str, list]:
    """{"ours": scenes, "heldout": scenes}: the circle and sine BOP scenarios under each root
    (`generate --scenario`, `generate --heldout`), each scene a list of frames (first `frames`)."""
    from rhaml_jax.data import read_bop
    from rhaml_jax.sequence import group_scenes

    roots = {"ours": Path(ours)} | ({"heldout": Path(heldout)} if heldout else {})
    return {name: [s[:frames] for sc in ("circle", "sine") for s in group_scenes(read_bop(root / sc)).values()]
            for name, root in roots.items()}


def data_root(frame) -> Path:
    """The BOP data set folder of a frame (ROOT/SPLIT/SCENE/rgb/IMAGE.png), e.g. .../circle."""
    return Path(frame.rgb).parents[3]


def evaluate(mods: tuple[str, ...], iml_model, iml_params, scenes: list, fusion=None) -> tuple[dict, dict]:
    """One module combination over scenes: (the paper's metrics + flips, fps, median range ratio;
    per-frame arrays {"est", "gt", "scenario"} of the detected frames with the robot in view)."""
    from rhaml_jax.demo import run_combination

    data_dir = data_root(scenes[0][0])
    m, runs = run_combination(mods, iml_model, iml_params, scenes, data_dir, fusion)
    est, gt, scen = [], [], []
    for r in runs:
        keep = r.result.detected & r.data.observed
        est.append(r.result.xypsi[keep])
        gt.append(r.data.gt[keep])
        scen += [data_root(r.data.frames[0]).name] * int(keep.sum())
    est, gt = np.concatenate(est), np.concatenate(gt)
    ratio = np.hypot(est[:, 0], est[:, 1]) / np.maximum(np.hypot(gt[:, 0], gt[:, 1]), 1e-9)
    m["median_range_ratio"] = float(np.median(ratio)) if len(ratio) else float("nan")
    return m, {"est": est, "gt": gt, "scenario": np.array(scen)}


def write_json(path: Path, obj) -> None:
    """Atomically (a killed script leaves the previous file whole)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    tmp.replace(path)


def write_npz(path: Path, arrays: dict) -> None:
    """Arrays by name, atomically like write_json."""
    path = Path(path)
    tmp = path.with_suffix(".tmp.npz")
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    tmp.replace(path)
