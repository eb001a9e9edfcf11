"""IML's two stages measured apart: AMLNet alone (what its estimate gives the zoom crop), and the
zoom stage with an oracle first stage (crops around the true pose, jittered as in its training,
`zoom.ZoomJitter`), so that each stage's errors on the held-out set are told from the other's.

  python experiments/stage_diagnostics.py --amlnet rhaml_jax/checkpoints/amlnet_cpu /work/runs/heat \
      --zoom rhaml_jax/checkpoints/zoom_cpu /work/runs/zoom_luma \
      --data /work/data/ours/circle /work/data/heldout/circle /work/data/heldout/sine --frames 200 --out OUT.json

Over the first `--frames` frames with the robot in view of each data set:
- AMLNet alone: the median bearing error (deg), the fraction within 5 deg, the median estimated /
  true range and the fraction within 12 % (the zoom crop's tolerance, its training jitter),
  the fraction detected;
- the zoom stage (one jitter draw per frame, seed 7): mean |dx|, |dy| (cm), median |dpsi| (deg),
  the fraction of flips (|dpsi| > 90 deg), the median estimated / true range.
Prints Markdown tables; writes OUT.json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import _paper  # noqa: E402


def oracle_errors(zoom_dir: Path, root: Path, frames: int, batch: int = 50) -> dict:
    import jax
    import jax.numpy as jnp

    from rhaml_jax.amlnet import load_model
    from rhaml_jax.planar import wrap_angle
    from rhaml_jax.crop import min_range_m
    from rhaml_jax.zoom import apply_correction, decode_correction
    from rhaml_jax.zoom._source import ZoomSource

    net, p, s = load_model(zoom_dir)
    split = "test" if (root / "test").is_dir() else "val"
    src = ZoomSource(root, split, net.cfg, seed=7, draws=1, limit=frames)
    predict = jax.jit(lambda x: decode_correction(net.apply(p, s, x), net.cfg.angle_head).as_array())
    est, gt = [], []
    for i0 in range(0, src.size, batch):
        idx = range(i0, min(src.size, i0 + batch))
        crops = jnp.asarray(np.stack([src.example(i)[0] for i in idx]), jnp.float32) / 255.0
        guess = np.stack([src.guess(i) for i in idx])
        est.append(np.asarray(apply_correction(guess, np.asarray(predict(crops), np.float64), min_range_m(net.cfg.zoom_length_m))))
        gt.append(np.stack([src.frames[i].xypsi for i in idx]))
    est, gt = np.concatenate(est), np.concatenate(gt)
    dpsi = np.abs(wrap_angle(est[:, 2] - gt[:, 2]))
    return {"n": len(gt), "dx_cm": float(100 * np.mean(np.abs(est[:, 0] - gt[:, 0]))),
            "dy_cm": float(100 * np.mean(np.abs(est[:, 1] - gt[:, 1]))),
            "median_dpsi_deg": float(np.degrees(np.median(dpsi))), "flips": float(np.mean(dpsi > np.pi / 2)),
            "median_range_ratio": float(np.median(np.hypot(est[:, 0], est[:, 1]) / np.hypot(gt[:, 0], gt[:, 1])))}


def first_stage(amlnet_dir: Path, root: Path, frames: int, batch: int = 25) -> dict:
    import jax.numpy as jnp

    from rhaml_jax.amlnet import load_model
    from rhaml_jax.data import load_rgb, read_bop
    from rhaml_jax.iml import IMLModel, IMLParams, localize_jit
    from rhaml_jax.metrics import DETECTION_THRESHOLD
    from rhaml_jax.planar import range_bearing, wrap_angle

    net, p, s = load_model(amlnet_dir)
    split = "test" if (root / "test").is_dir() else "val"
    fr = [f for f in read_bop(root, split) if f.observed][:frames]
    est, o = [], []
    for i in range(0, len(fr), batch):
        e = localize_jit(IMLModel(net), IMLParams((p, s), None), jnp.asarray(np.stack([load_rgb(f.rgb) for f in fr[i:i + batch]])),
                         jnp.asarray(np.stack([f.K for f in fr[i:i + batch]]), jnp.float32))
        est.append(np.asarray(e.xypsi))
        o.append(np.asarray(e.o))
    est, o, gt = np.concatenate(est), np.concatenate(o), np.stack([f.xypsi for f in fr])
    (r_est, b_est), (r_gt, b_gt) = range_bearing(est[:, :2]), range_bearing(gt[:, :2])
    db = np.degrees(np.abs(wrap_angle(b_est - b_gt)))
    rr = r_est / r_gt
    return {"n": len(gt), "median_bearing_deg": float(np.median(db)), "bearing_within_5deg": float(np.mean(db <= 5)),
            "median_range_ratio": float(np.median(rr)), "range_within_12pct": float(np.mean(np.abs(np.log(rr)) <= np.log(1.12))),
            "detected": float(np.mean(o >= DETECTION_THRESHOLD))}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--amlnet", type=Path, nargs="*", default=[])
    ap.add_argument("--zoom", type=Path, nargs="*", default=[])
    ap.add_argument("--data", type=Path, nargs="+", required=True)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    first = [{"amlnet": str(m), "data": str(d), **first_stage(m, d, a.frames)} for m in a.amlnet for d in a.data]
    print(markdown(first, FIRST_COLUMNS))
    rows = [{"zoom": str(z), "data": str(d), **oracle_errors(z, d, a.frames)} for z in a.zoom for d in a.data]
    print(markdown(rows, ZOOM_COLUMNS))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    res = {"amlnet_alone": first, "zoom_oracle": rows}
    _paper.write_json(a.out, res)
    return res


pct = lambda v: f"{100 * v:.0f} %"  # noqa: E731
# (header, key, format) of each table's columns
FIRST_COLUMNS = (("AMLNet", "amlnet", str), ("data", "data", str),
                 ("median bearing error (deg)", "median_bearing_deg", "{:.2f}".format), ("within 5 deg", "bearing_within_5deg", pct),
                 ("median est/true range", "median_range_ratio", "{:.3f}".format), ("within 12 %", "range_within_12pct", pct),
                 ("detected", "detected", pct))
ZOOM_COLUMNS = (("zoom stage", "zoom", str), ("data", "data", str),
                ("abs dx (cm)", "dx_cm", "{:.1f}".format), ("abs dy (cm)", "dy_cm", "{:.1f}".format),
                ("median abs dpsi (deg)", "median_dpsi_deg", "{:.1f}".format), ("flips", "flips", pct),
                ("median est/true range", "median_range_ratio", "{:.3f}".format))


def markdown(rows: list[dict], columns) -> str:
    """A Markdown table of `rows`, one column per (header, key, format)."""
    lines = ["| " + " | ".join(c[0] for c in columns) + " |", "| " + " | ".join(["---"] * len(columns)) + " |"]
    lines += ["| " + " | ".join(fmt(r[k]) for _, k, fmt in columns) + " |" for r in rows]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
