"""Fig. 5 at our scale: violin plots of the signed per-DoF errors (x, y in cm, psi in deg,
wrapped to (-180, 180]) of the full pipeline (Table I's RHAML row) over the circle + sine
frames, one panel per DoF, one row of panels per set (ours, held-out: each panel its own scale,
since the held-out errors can be 100x ours). Reads table_i.py's .npz; no evaluation.

  python experiments/fig5_violin.py --npz experiments/results/table_i.npz \
      --out experiments/results/fig5_violin.png [--rows rhaml] [--json QUANTILES]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _paper  # noqa: E402
from table_i import ROWS  # noqa: E402

DOFS = (("dx", "x error (cm)"), ("dy", "y error (cm)"), ("dpsi", "psi error (deg)"))


def signed_errors(est: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(N, 3) est, gt (m, rad) -> (N, 3) signed dx, dy (cm), dpsi (deg, wrapped)."""
    from rhaml_jax.planar import wrap_angle

    d = np.asarray(est, np.float64) - np.asarray(gt, np.float64)
    return np.stack([100 * d[:, 0], 100 * d[:, 1], np.degrees(wrap_angle(d[:, 2]))], -1)


def quantiles(err: np.ndarray) -> dict:
    """Per DoF: median, 5th and 95th percentile of (N, 3) signed errors, and n."""
    if not len(err):
        return {"n": 0}
    q = np.percentile(err, [50, 5, 95], axis=0)
    return {"n": len(err), **{name: {"median": float(q[0, k]), "p5": float(q[1, k]), "p95": float(q[2, k])}
                              for k, (name, _) in enumerate(DOFS)}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--npz", required=True, help="table_i.py's per-frame estimates")
    ap.add_argument("--out", required=True, help="PNG")
    ap.add_argument("--json", default=None, help="quantiles (default: beside the PNG)")
    ap.add_argument("--rows", nargs="+", default=["rhaml"], help=f"Table I rows, one violin each ({', '.join(ROWS)})")
    a = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.load(a.npz)
    sets = [s for s in ("ours", "heldout") if f"{a.rows[0]}/{s}/est" in z.files]
    err = {(r, s): signed_errors(z[f"{r}/{s}/est"], z[f"{r}/{s}/gt"]) for r in a.rows for s in sets}
    fig, axes = plt.subplots(len(sets), 3, figsize=(3.6 * 3, 3.4 * len(sets)), squeeze=False)
    for i, s in enumerate(sets):
        for k, (_, label) in enumerate(DOFS):
            ax = axes[i, k]
            data = [(j, err[r, s][:, k]) for j, r in enumerate(a.rows) if len(err[r, s])]
            if data:
                ax.violinplot([d for _, d in data], [j for j, _ in data], showmedians=True, showextrema=False,
                              quantiles=[[0.05, 0.95]] * len(data))
            ax.axhline(0, color="k", lw=0.6)
            ax.set_xticks(range(len(a.rows)), [f"{ROWS[r]}\n(n={len(err[r, s])})" for r in a.rows], fontsize=8)
            ax.set_title(f"{s}: {label}", fontsize=9)
            ax.grid(axis="y", alpha=0.3)
    fig.suptitle("Fig. 5: signed errors over circle + sine (median, 5th and 95th percentile marked)", fontsize=10)
    fig.tight_layout()
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=120)
    plt.close(fig)
    out = {"npz": str(a.npz), "units": "dx, dy cm; dpsi deg; signed est - gt, psi wrapped",
           "quantiles": {r: {s: quantiles(err[r, s]) for s in sets} for r in a.rows}}
    _paper.write_json(Path(a.json) if a.json else Path(a.out).with_suffix(".json"), out)
    return out


if __name__ == "__main__":
    main()
