"""The shipped IML networks (amlnet_cpu + zoom_cpu, --zoom-mirror) on the held-out appearance
benchmark and on our own scenarios: the BENCHMARKS.md section "Held-out appearance set".

  python -m rhaml_jax.generate --out /work/data/heldout --heldout --workers 1     # outside the repo
  python -m rhaml_jax.generate --out /work/data/ours/circle --scenario circle
  python -m rhaml_jax.generate --out /work/data/ours/sine --scenario sine
  python experiments/heldout_iml.py --heldout /work/data/heldout --ours /work/data/ours --out /work/data/heldout_results \
      [--val /work/data/v2_train] [--repainted /work/data/val_repaint] [--evaluate-args="--amlnet CKPT --zoom CKPT"]

For each data set it runs `python -m rhaml_jax.evaluate --data D --modules iml --zoom-mirror --json J`
(the shipped checkpoints) and, from J, over the frames with the robot in view that were detected:
|dx|, |dy| (cm), |dpsi| (deg) as mean, std and median, the ATE (`rhaml_jax.metrics`), flips
(|dpsi| > 90 deg), the median of estimated / true range; and the detection counts over all frames.
Prints a Markdown table and writes it with the raw numbers to OUT/summary.json.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path


def evaluate(data: Path, out_json: Path, extra: list[str]) -> dict:
    if not out_json.exists():
        cmd = [sys.executable, "-m", "rhaml_jax.evaluate", "--data", str(data), "--modules", "iml", "--zoom-mirror",
               "--json", str(out_json), *extra]
        print("+", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)
    return json.loads(out_json.read_text())


def summary(res: dict) -> dict:
    from rhaml_jax.metrics import frame_summary

    return frame_summary(res["frames"]) | {"detection_accuracy": res["metrics"]["detection_accuracy"]}


def table(rows: dict) -> str:
    head = ("| data | abs dx (cm) mean / std / median | abs dy (cm) | abs dpsi (deg) | ATE | flips (> 90 deg) "
            "| median est/true range | detection (tp / fp / fn / tn) |\n| --- | --- | --- | --- | --- | --- | --- | --- |\n")
    out = []
    for name, r in rows.items():
        d = r["detection"]
        dets = f"{d['tp']} / {d['fp']} / {d['fn']} / {d['tn']}"
        if "dx_cm" not in r:
            out.append(f"| {name} | | | | | | | {dets} |")
            continue
        f3 = lambda v: f"{v[0]:.1f} / {v[1]:.1f} / {v[2]:.1f}"  # noqa: E731
        out.append(f"| {name} | {f3(r['dx_cm'])} | {f3(r['dy_cm'])} | {f3(r['dpsi_deg'])} | {r['ate']:.2f} | "
                   f"{r['flips']} / {r['n']} | {r['median_range_ratio']:.3f} | {dets} |")
    return head + "\n".join(out) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--heldout", type=Path, default=Path("/work/data/heldout"))
    p.add_argument("--ours", type=Path, default=Path("/work/data/ours"), help="folder holding our circle/ and sine/")
    p.add_argument("--out", type=Path, default=Path("/work/data/heldout_results"))
    p.add_argument("--val", type=Path, default=None, help="a BOP training set whose val split is also evaluated")
    p.add_argument("--repainted", type=Path, default=None,
                   help="folder of experiments/repainted_validation.py's scenes (blue_body/, grey_wheels/), also evaluated")
    p.add_argument("--evaluate-args", default="", help='extra evaluate flags as one string (e.g. "--amlnet CKPT --zoom CKPT")')
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    sets = {f"ours: {n}": a.ours / n for n in ("circle", "sine")}
    if a.val is not None:
        sets["ours: validation split"] = a.val
    if a.repainted is not None:
        sets |= {f"validation: {n.replace('_', ' ')}": a.repainted / n for n in ("blue_body", "grey_wheels")}
    sets |= {f"held-out: {n}": a.heldout / n for n in ("circle", "sine", "background", "random")}
    rows = {}
    for name, d in sets.items():
        if not (d / "camera.json").exists():
            print(f"skipping {name}: {d} not found", file=sys.stderr)
            continue
        extra = shlex.split(a.evaluate_args) + (["--split", "val"] if d == a.val else [])
        rows[name] = summary(evaluate(d, a.out / (name.replace(": ", "_").replace(" ", "_") + ".json"), extra))
    md = table(rows)
    print(md)
    (a.out / "summary.json").write_text(json.dumps(rows, indent=1))
    (a.out / "summary.md").write_text(md)


if __name__ == "__main__":
    main()
