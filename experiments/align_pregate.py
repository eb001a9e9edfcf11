"""How well the alignment's outcome can be told before it runs: features of the segmenter's mask
against the hypotheses' starts at the cascade's end, per frame of two stored validation runs.

    python experiments/align_pregate.py BASE ALIGNED --out F.json [--ev /work/runs/validation] [--data /work/data]
    python experiments/align_pregate.py BASE ALIGNED --features F.json --skip-iou 0.95 --label OUT

BASE and ALIGNED are labels of `experiments/validate_networks.sh` runs with the same networks, BASE
without the alignment after the cascade, ALIGNED with the gated one (`refine.SEGMENTER_ALIGN`). For
every frame both runs refined, at BASE's IR estimate (the cascade's end) in the alignment's crop: the
segmenter's thresholded mask (`alignment_target`) against the hard silhouette (`start_iou`) of each starting
hypothesis (`alignment.hypotheses`: the estimate, its flip, its mirror, the mirror's flip), as IoU;
and whether ALIGNED took the alignment's result (its estimate differs from BASE's). A cheap test on
these features that skips the alignment where it would not have been taken saves its cost there.

With `--features` (a file the first form wrote) and `--skip-iou T` the script instead constructs the
validation run of that test (`AlignConfig.skip_iou`): per frame, BASE's IR estimate where the start's
IoU is at least T (the alignment skipped, so the cascade's end kept), else ALIGNED's; every other field
is ALIGNED's. Written as EV/OUT_SET.json for `compare_validation.py ALIGNED OUT`. As with
`merge_gate.py`, the pipeline's re-detection, which refines doubtful frames too, is not reproduced.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import data, render
from rhaml_jax.amlnet.checkpoint import shipped_checkpoint
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine import DEFAULT_SEGMENTER, SEGMENTER_ALIGN, RefineConfig, load_segmenter
from rhaml_jax.refine.alignment import crop_box, hypotheses, params_from_xypsi, start_iou, xypsi_from_params
from rhaml_jax.refine.segmenter import alignment_target
from rhaml_jax.robots import load_robot

SETS = ([f"val_scen_s{s}_500/{c}" for s in (7, 8) for c in ("circle", "sine")]
        + [f"val_ood{x}/{c}" for x in ("", "_s2") for c in ("circle", "sine")]
        + [f"{v}/{c}_{p}" for v in ("val_mono", "val_mono_cad") for p in ("purple", "orange", "grey") for c in ("circle", "sine")])


def features(mesh, seg, cfg):
    """jit(image, K, xypsi) -> (`alignment.start_iou` of each starting hypothesis (4,), target area in px)."""
    S = cfg.crop

    def f(image, K, xyp):
        box = crop_box(mesh, K, xyp, cfg)
        target = alignment_target(seg, image, box, S, RefineConfig.mask_threshold)
        starts = xypsi_from_params(hypotheses(params_from_xypsi(xyp), cfg))
        return jax.vmap(lambda x: start_iou(mesh, K, box, target, x, cfg))(starts), jnp.sum(target)

    return jax.jit(f)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("base")
    p.add_argument("aligned")
    p.add_argument("--out", type=Path, default=None, help="the features file to write")
    p.add_argument("--ev", type=Path, default=Path("/work/runs/validation"))
    p.add_argument("--data", type=Path, default=Path("/work/data"))
    p.add_argument("--features", type=Path, default=None)
    p.add_argument("--skip-iou", type=float, default=None)
    p.add_argument("--label", default=None)
    a = p.parse_args()
    if a.features is not None:
        return construct(a)
    if a.out is None:
        raise SystemExit("--out (the features file) or --features is needed")
    robot = load_robot("pioneer3dx")
    mesh = render.as_mesh(robot)
    seg = load_segmenter(shipped_checkpoint(DEFAULT_SEGMENTER), robot)
    f = features(mesh, seg, SEGMENTER_ALIGN)
    rows = []
    for s in SETS:
        name = s.replace("/", "_")
        base = json.loads((a.ev / f"{a.base}_{name}.json").read_text())["frames"]
        al = {(r["scene_id"], r["im_id"]): r for r in json.loads((a.ev / f"{a.aligned}_{name}.json").read_text())["frames"]}
        frames = {(fr.scene_id, fr.im_id): fr for fr in data.read_bop(a.data / s)}
        t0, n = time.perf_counter(), 0
        for r in base:
            q = al[(r["scene_id"], r["im_id"])]
            if not (r.get("ir_applied") and q.get("ir_applied")):
                continue
            fr = frames[(r["scene_id"], r["im_id"])]
            image = jnp.asarray(data.load_rgb(fr.rgb), jnp.float32) / 255
            iou, area = f(image, jnp.asarray(fr.K, jnp.float32), jnp.asarray(r["ir_est"], jnp.float32))
            b, e, gt = np.asarray(r["ir_est"]), np.asarray(q["ir_est"]), np.asarray(r["gt"])
            err = lambda x: (float(np.hypot(*(x[:2] - gt[:2]))), float(abs(wrap_angle(x[2] - gt[2]))))  # noqa: E731
            rows.append({"set": s, "scene_id": r["scene_id"], "im_id": r["im_id"], "iou": [float(v) for v in iou],
                         "area": float(area), "taken": bool(np.abs(b - e).max() > 1e-5),
                         "base_err": err(b), "aligned_err": err(e),
                         "range": float(np.hypot(*gt[:2]))})
            n += 1
        print(f"{s}: {n} frames, {sum(r['taken'] for r in rows if r['set'] == s)} taken, "
              f"{1e3 * (time.perf_counter() - t0) / max(n, 1):.0f} ms per frame", flush=True)
    a.out.write_text(json.dumps(rows))


def construct(a) -> None:
    """The validation run of `AlignConfig.skip_iou` = a.skip_iou, from the stored features."""
    if a.skip_iou is None or a.label is None:
        raise SystemExit("--features needs --skip-iou and --label")
    skip = {(r["set"], r["scene_id"], r["im_id"]) for r in json.loads(a.features.read_text()) if r["iou"][0] >= a.skip_iou}
    for s in SETS:
        name = s.replace("/", "_")
        base = {(r["scene_id"], r["im_id"]): r for r in json.loads((a.ev / f"{a.base}_{name}.json").read_text())["frames"]}
        run = json.loads((a.ev / f"{a.aligned}_{name}.json").read_text())
        n = 0
        for r in run["frames"]:
            if (s, r["scene_id"], r["im_id"]) in skip:
                b = base[(r["scene_id"], r["im_id"])]
                r["ir_est"], r["ir_flip_prob"] = b["ir_est"], b["ir_flip_prob"]
                n += 1
        (a.ev / f"{a.label}_{name}.json").write_text(json.dumps(run))
        print(f"{s}: the alignment skipped on {n} of {len(run['frames'])} frames", flush=True)


if __name__ == "__main__":
    main()
