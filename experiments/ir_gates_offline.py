"""Offline trials of a gate on IR's output: where the gate fires, the stored IR estimate is replaced
by IML's (its heading only, or the whole estimate), and the validation label is written anew for
`compare_validation.py` (which refits the pose graph from the stored estimates).

    # the cascade's iterates per validation sequence (for the convergence gate), once:
    for s in val_scen_s7_500/circle ... val_mono/sine_grey; do t=$(echo $s | tr / _)
      python experiments/bench_refine.py --data /work/data/$s --iml-json EV/fine_$t.json --starts iml --no-oracle \\
          --refiner rhaml_jax/checkpoints/refiner_cpu --fine-refiner rhaml_jax/checkpoints/refiner_fine_cpu --json BENCH/$t.json
    done
    python experiments/ir_gates_offline.py --base fine --gate convergence --threshold 1.0 --keep whole --bench BENCH --out OUT
    python experiments/ir_gates_offline.py --base fine --gate heading --threshold 10 --keep heading --out OUT
    python experiments/compare_validation.py fine LABEL --ev OUT          # OUT also needs links to EV/fine_*

Gates: `heading` fires where IR's and IML's headings differ by more than THRESHOLD deg;
`convergence` where the cascade's last coarse iteration moved the range by more than THRESHOLD %
(`RefineConfig.max_final_step`, which `refine` now applies itself; BENCHMARKS.md, "A convergence
check for the refiner"). The label written is BASE + gate + keep + threshold, printed.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from rhaml_jax.planar import wrap_angle


def last_coarse_steps(bench_json: Path, n_iter: int = 4) -> np.ndarray:
    """|log(r_n / r_(n-1))| in % per frame of `bench_refine.py`'s start-iml iterates."""
    pf = [p for p in json.loads(bench_json.read_text())["per_frame"] if p["start"] == "iml"][0]
    it = np.asarray(pf["learned_iterates"])
    r = np.hypot(it[:, :, 0], it[:, :, 1])
    return 100 * np.abs(np.log(r[:, n_iter] / r[:, n_iter - 1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="fine", help="the validation label whose stored estimates are gated")
    ap.add_argument("--ev", type=Path, default=Path("/work/runs/validation"))
    ap.add_argument("--gate", choices=("heading", "convergence"), required=True)
    ap.add_argument("--threshold", type=float, required=True, help="deg (heading) or % of the range (convergence)")
    ap.add_argument("--keep", choices=("whole", "heading"), default="whole", help="what of IML's estimate replaces IR's")
    ap.add_argument("--bench", type=Path, help="bench_refine.py JSONs per sequence (the convergence gate)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    label = f"{a.base}{a.gate}{a.keep}{a.threshold:g}".replace(".", "p")
    a.out.mkdir(parents=True, exist_ok=True)
    for path in sorted(a.ev.glob(f"{a.base}_val_*.json")):
        seq = path.stem[len(a.base) + 1:]
        if seq.endswith("background") or seq.endswith("random"):
            continue
        d = json.loads(path.read_text())
        rows = [x for x in d["frames"] if x["observed"] and x["detected"] and "ir_est" in x]
        if a.gate == "convergence":
            steps = last_coarse_steps(a.bench / f"{seq}.json")
            if len(steps) != len(rows):
                raise SystemExit(f"{a.bench / seq}.json: {len(steps)} frames, {path}: {len(rows)} detected")
            fire = steps > a.threshold
        else:
            fire = [abs(wrap_angle(x["ir_est"][2] - x["iml_est"][2])) > math.radians(a.threshold) for x in rows]
        for x, f in zip(rows, fire):
            if f:
                x["ir_est"] = list(x["iml_est"]) if a.keep == "whole" else [*x["ir_est"][:2], x["iml_est"][2]]
        (a.out / f"{label}_{seq}.json").write_text(json.dumps(d))
        print(f"{label} {seq}: gated {int(np.sum(fire))} of {len(rows)}")


if __name__ == "__main__":
    main()
