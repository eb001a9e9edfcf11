"""Fig. 6 at our scale: the circle and sine trajectories in the observer's x-y plane, ground
truth against the FrontNet, AMLNet (IML) and RHAML estimates (the detected frames), one panel
per scenario, a second row for the held-out set when the .npz has it. Reads table_i.py's .npz.

  python experiments/fig6_trajectories.py --npz experiments/results/table_i.npz \
      --out experiments/results/fig6_trajectories.png [--rows frontnet iml rhaml]

Axes as seen from above with the observer's x up and y to the left (the demo's plots); the view
is the truth's extent plus a margin, estimates outside it are counted in the legend.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from table_i import ROWS  # noqa: E402

STYLE = {"frontnet": dict(color="C3", ms=3), "amlnet": dict(color="C1", ms=3), "iml": dict(color="C0", ms=3),
         "rhaml": dict(color="C2", ms=3)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--npz", required=True, help="table_i.py's per-frame estimates")
    ap.add_argument("--out", required=True, help="PNG")
    ap.add_argument("--rows", nargs="+", default=["frontnet", "iml", "rhaml"], help=f"Table I rows ({', '.join(ROWS)})")
    ap.add_argument("--margin", type=float, default=1.0, help="view = the truth's extent plus this (m)")
    a = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.load(a.npz)
    rows = [r for r in a.rows if any(k.startswith(f"{r}/") for k in z.files)]
    sets = [s for s in ("ours", "heldout") if any(f"{r}/{s}/est" in z.files for r in rows)]
    scenarios = ("circle", "sine")
    fig, axes = plt.subplots(len(sets), len(scenarios), figsize=(4.8 * len(scenarios), 5.4 * len(sets)), squeeze=False)
    for i, s in enumerate(sets):
        for j, sc in enumerate(scenarios):
            ax = axes[i, j]
            pick = {r: z[f"{r}/{s}/scenario"] == sc for r in rows}
            gt = z[f"truth/{s}/{sc}"]  # (N, 3) every in-view frame, detected or not
            if len(gt):
                ax.plot(gt[:, 1], gt[:, 0], "k-", lw=2.5, label="ground truth", zorder=1)
                lo, hi = gt[:, :2].min(0) - a.margin, gt[:, :2].max(0) + a.margin
                lo, hi = np.minimum(lo, [-0.3, -0.3]), np.maximum(hi, [0.3, 0.3])  # keep the observer in view
                ax.set(xlim=(hi[1], lo[1]), ylim=(lo[0], hi[0]))  # y to the left
            for r in rows:
                est = z[f"{r}/{s}/est"][pick[r]]
                out = int((~((est[:, :2] >= lo) & (est[:, :2] <= hi)).all(1)).sum()) if len(gt) else 0
                label = f"{ROWS[r]} (n={len(est)}" + (f", {out} outside)" if out else ")")
                ax.plot(est[:, 1], est[:, 0], ".", label=label, zorder=2, **STYLE.get(r, {}))
            ax.plot([0], [0], "k^", ms=7, label="observer")
            ax.set_aspect("equal", adjustable="box")
            ax.set(title=f"{s}: {sc} (observer's frame)", xlabel="y (m)", ylabel="x (m)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="best")
    fig.suptitle("Fig. 6: trajectories, ground truth and estimates (detected frames)", fontsize=10)
    fig.tight_layout()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=120)
    plt.close(fig)
    return Path(a.out)


if __name__ == "__main__":
    main()
