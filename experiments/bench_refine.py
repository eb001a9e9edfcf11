"""Refinement benchmark: silhouette alignment (and, with --refiner, the learned iterations; with
--scorer too, the heading search) on BOP scenarios, from (a) ground truth + the paper's noise and
(b) the shipped IML's estimates.

  python experiments/bench_refine.py --data /work/data/circle /work/data/sine \
      --iml-json /work/data/iml_circle.json /work/data/iml_sine.json --stride 5 --json out.json

Masks: the scenes' ground-truth masks (BOP mask_visib): the oracle row, which separates the
alignment's own error from a mask predictor's; with --segmenter CKPT also the segmenter's masks
of the images (the deployable row; `python experiments/bench_refine.py ... --segmenter
runs/segmenter_cpu`), with its mask IoU against the ground truth in the alignment's final crop. Prints one JSON line per
(start, stage) with mean +- std |dx|, |dy| (cm), |dpsi| (deg), ATE, flips (|dpsi| > 90 deg),
range bias (%) and ms per frame (median over frames, one frame at a time, compiled).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from rhaml_jax import allocator, data, metrics, render
from rhaml_jax import crop as _crop
from rhaml_jax.refine import AlignConfig, RefineConfig, align, check_ensemble, load_refiner, load_scorer, load_segmenter, refine
from rhaml_jax.refine.segmenter import alignment_target
from rhaml_jax.refine.alignment import align_to, crop_box


@dataclasses.dataclass(frozen=True)
class Args:
    data: tuple[Path, ...]
    """BOP scenario folders"""
    iml_json: tuple[Path, ...] = ()
    """`evaluate --json` outputs (one per --data, same order) for start (b); then only the frames
    the IML detected are used (for both starts), as `evaluate` scores them"""
    stride: int = 1
    """every stride-th frame (the alignment costs about a second per frame on this CPU)"""
    seed: int = 0
    """seed of the paper's noise for start (a)"""
    starts: tuple[str, ...] = ("noise", "iml")
    """(a) noise: gt + N(0, 0.15 m) x, y and N(0, 20 deg) psi; (b) iml: the IML's estimates;
    truth: the ground truth itself (where a refiner's reading moves a perfect estimate)"""
    crop: int = 64
    debias_stages: int = 2
    coarse: bool = True
    """run the alignment's coarse position pass (`AlignConfig.coarse_stages`; --no-coarse: none)"""
    coarse_margin: float = AlignConfig.coarse_margin
    """`AlignConfig.coarse_margin`: the width of the coarse position pass's crop"""
    stages: str | None = None
    """`AlignConfig.stages` as "sharpness:iterations[:xy],..." (e.g. "2:4,4:4,8:3,8:3"; None: the default)"""
    mirror_hypotheses: bool = AlignConfig.mirror
    """`AlignConfig.mirror`: also align from the heading mirrored about the line of sight (and its flip)"""
    min_turn_deg: float = 0.0
    """`AlignConfig.min_turn` in degrees: keep the start unless the alignment turns its heading by more"""
    max_shift: float | None = None
    """`AlignConfig.max_shift`: keep the start where the alignment moves the position by more than this fraction of the range"""
    fd: str = AlignConfig.fd
    """`AlignConfig.fd`: the alignment's finite differences ("central" or "forward")"""
    max_score: float | None = None
    """`AlignConfig.max_score`: keep the start where the aligned silhouette explains the mask worse than this"""
    mask_threshold: float = RefineConfig.mask_threshold
    """the segmenter's mask is thresholded here (`RefineConfig.mask_threshold`)"""
    split: str | None = None
    """only this BOP split (e.g. val of a training set: where thresholds are chosen)"""
    refiner: Path | None = None
    """a refiner checkpoint: also run the learned iterations, then the alignment to its predicted mask"""
    align_predicted: bool = False
    """with --refiner: also run the alignment to the refiner's predicted mask (measured worse: BENCHMARKS.md)"""
    fine_refiner: tuple[Path, ...] | None = None
    """with --refiner: a cascade's fine refiner checkpoint (`--config refiner_fine_cpu`): its iterations after the
    others (several: an ensemble, their updates averaged)"""
    fine_iter: int = 1
    """with --fine-refiner: `RefineConfig.fine_iter`"""
    n_iter: int | None = None
    """with --refiner: `RefineConfig.n_iter`, its learned iterations (None: the refiner's config, 4)"""
    oracle_from_learned: bool = False
    """with --refiner: also align to the ground-truth masks from the learned iterations' last pose
    (what a perfect mask would add after them)"""
    fine_after_align: tuple[int, ...] = ()
    """with --refiner, --fine-refiner and --segmenter: a row per count N, the whole IR stage as `evaluate`
    runs it (`refine` with the alignment to the segmenter's masks and `RefineConfig.fine_after_align` N)"""
    segmenter_from_learned: bool = False
    """with --refiner and --segmenter: also align to the segmenter's masks from the learned iterations'
    last pose (the deployable row of the same)"""
    mirror: str = RefineConfig.mirror
    """`RefineConfig.mirror`: none, fine or all (the learned iterations also read mirrored crops)"""
    fine_views: int = RefineConfig.fine_views
    """with --fine-refiner: `RefineConfig.fine_views` (starts averaged)"""
    max_final_step: float | None = RefineConfig.max_final_step
    """`RefineConfig.max_final_step` (a row after the learned ones: the start kept where the refiner did not converge)"""
    fine_spread_scale: float = 1.0
    """with --fine-views > 1: `RefineConfig.fine_spread` times this"""
    scorer: Path | None = None
    """with --refiner: a heading scorer checkpoint (`train --stage scorer`): the heading search after the learned iterations"""
    flip_threshold: float = RefineConfig.flip_threshold
    """with --scorer: `RefineConfig.flip_threshold` (the scorer's mass on the other side needed to turn the heading)"""
    post_iter: int = RefineConfig.post_iter
    """with --scorer: `RefineConfig.post_iter` (learned iterations after the heading search)"""
    segmenter: Path | None = None
    """a segmenter checkpoint (`train --stage segmenter`): also run the alignment to its masks of the images"""
    oracle: bool = True
    """run the alignment to the ground-truth masks (the oracle row)"""
    from_start: bool = True
    """run the alignments (to gt masks, to the segmenter's) from the start too (--no-from-start: only
    the rows after the learned iterations)"""
    json: Path | None = None


def summary(est, gt, ms=None) -> dict:
    s = metrics.summarize(est, gt)
    d = np.asarray(metrics.abs_errors(jnp.asarray(est, jnp.float32), jnp.asarray(gt, jnp.float32)))
    rr = np.hypot(est[:, 0], est[:, 1]) / np.hypot(gt[:, 0], gt[:, 1]) - 1
    s.update(flips=int((d[:, 2] > np.pi / 2).sum()), range_bias_pct=float(100 * rr.mean()),
             median_dpsi_deg=float(np.rad2deg(np.median(d[:, 2]))))
    if ms is not None:
        s["ms_per_frame"] = float(np.median(ms))
    return s


def learned(a: Args, ref, mesh, cfg, frames, init, gt, name, per_frame, sc=None, fine=None) -> list[dict]:
    """Rows after each learned iteration (with a scorer: then after the heading search and the
    post iterations; with a fine refiner: then after each of its iterations) and, with
    --align-predicted, after the alignment to the predicted mask."""
    rc = RefineConfig(align=None, n_iter=a.n_iter, flip_threshold=a.flip_threshold, post_iter=a.post_iter, fine_iter=a.fine_iter,
                      fine_views=a.fine_views, max_final_step=a.max_final_step, mirror=a.mirror, fine_spread=tuple(a.fine_spread_scale * x for x in RefineConfig.fine_spread))
    f_it = jax.jit(lambda im, i, K: refine(ref, mesh, im, K, i, rc, scorer=sc, fine=fine))
    f_all = jax.jit(lambda im, i, K: refine(ref, mesh, im, K, i, RefineConfig(align=cfg)))
    its, est, ms_it, ms_all, flip_prob, conv = [], [], [], [], [], []
    for j, fr in enumerate(frames):
        im = jnp.asarray(data.load_rgb(fr.rgb), jnp.float32) / 255
        args = (im, jnp.asarray(init[j]), jnp.asarray(fr.K, jnp.float32))
        if j == 0:
            jax.block_until_ready(f_it(*args))
        t = time.perf_counter()
        r1 = jax.block_until_ready(f_it(*args))
        ms_it.append(1e3 * (time.perf_counter() - t))
        its.append(np.asarray(r1.iterates)); flip_prob.append(float(r1.flip_prob)); conv.append(bool(r1.converged))
        if a.align_predicted:
            if j == 0:
                jax.block_until_ready(f_all(*args))
            t = time.perf_counter()
            est.append(np.asarray(jax.block_until_ready(f_all(*args)).xypsi))
            ms_all.append(1e3 * (time.perf_counter() - t))
    its = np.stack(its)
    per_frame.append({"start": name, "gt": gt.tolist(), "learned_iterates": its.tolist(), "flip_prob": flip_prob, "converged": conv,
                      **({"learned_aligned": np.stack(est).tolist()} if est else {})})
    n_iter = ref.cfg.n_iter if a.n_iter is None else a.n_iter
    names = ["start"] + [f"learned iteration {k}" for k in range(1, n_iter + 1)]
    if sc is not None:
        names += ["heading search (scorer)"] + [f"post iteration {k}" for k in range(1, a.post_iter + 1)]
    if fine is not None:
        names += [f"fine iteration {k}" for k in range(1, a.fine_iter + 1)]
    rows = []
    for k, stage in enumerate(names):
        rows.append({"start": name, "stage": stage, "frames": len(gt), "stride": a.stride,
                     **summary(its[:, k], gt, ms_it if k == its.shape[1] - 1 else None)})
    if rc.max_final_step is not None:  # what refine() answers: the start where the iterations did not settle
        kept = np.asarray(conv)[:, None]
        rows.append({"start": name, "stage": f"+ convergence check ({int((~kept).sum())} kept the start)", "frames": len(gt),
                     "stride": a.stride, **summary(np.where(kept, its[:, -1], its[:, 0]), gt)})
    if est:
        rows.append({"start": name, "stage": "learned + alignment (predicted mask)", "frames": len(gt), "stride": a.stride,
                     **summary(np.stack(est), gt, ms_all)})
    for r in rows:
        print(json.dumps(r), flush=True)
    return rows


def whole_stage(a: Args, ref, mesh, cfg: AlignConfig, frames, init, sc, fine, seg, n: int):
    """`refine` as the pipeline runs it with a segmenter (the learned iterations, the alignment to its
    masks, n fine iterations after it; declined or unconverged frames keep the start): (estimates (F, 3),
    ms per frame)."""
    rc = RefineConfig(align=cfg, n_iter=a.n_iter, flip_threshold=a.flip_threshold, post_iter=a.post_iter, fine_iter=a.fine_iter,
                      max_final_step=a.max_final_step, mirror=a.mirror, fine_views=a.fine_views, fine_after_align=n,
                      mask_threshold=a.mask_threshold)
    f = jax.jit(lambda im, i, K: refine(ref, mesh, im, K, i, rc, segmenter=seg, scorer=sc, fine=fine).xypsi)
    est, ms = [], []
    for j, fr in enumerate(frames):
        args = (jnp.asarray(data.load_rgb(fr.rgb), jnp.float32) / 255, jnp.asarray(init[j]), jnp.asarray(fr.K, jnp.float32))
        if j == 0:
            jax.block_until_ready(f(*args))
        t = time.perf_counter()
        est.append(np.asarray(jax.block_until_ready(f(*args))))
        ms.append(1e3 * (time.perf_counter() - t))
    return np.stack(est), ms


def aligned(mesh, cfg: AlignConfig, seg, frames, init, threshold: float = RefineConfig.mask_threshold):
    """The alignment of every frame from `init` (F, 3), to its ground-truth mask (seg None) or to
    the segmenter's mask of its image: (estimates (F, 3), ms per frame, flip confidences, mask
    IoU of the segmenter in the final crop (empty for gt masks))."""
    S = cfg.crop

    def one(image, mask, i, K):
        H, W = mask.shape
        if seg is None:
            return align(mesh, mask, K, i, cfg), jnp.float32(1.0)
        target = lambda b: alignment_target(seg, image, b, S, threshold)  # noqa: E731
        r = align_to(mesh, target, K, i, W, H, cfg)
        box = crop_box(mesh, K, r.xypsi, cfg)
        pred, true = target(box) > 0.5, _crop.crop_image(mask[..., None], box, S, S)[..., 0] > 0.5
        return r, jnp.sum(pred & true) / jnp.maximum(jnp.sum(pred | true), 1)

    f = jax.jit(one)
    est, ms, conf, iou, score, acc = [], [], [], [], [], []
    for j, fr in enumerate(frames):
        args = (jnp.asarray(data.load_rgb(fr.rgb), jnp.float32) / 255, jnp.asarray(data.load_mask(fr.mask), jnp.float32),
                jnp.asarray(init[j]), jnp.asarray(fr.K, jnp.float32))
        if j == 0:
            jax.block_until_ready(f(*args))
        t = time.perf_counter()
        r, q = jax.block_until_ready(f(*args))
        ms.append(1e3 * (time.perf_counter() - t))
        est.append(np.asarray(r.xypsi)); conf.append(float(r.flip_confidence)); iou.append(float(q))
        score.append(float(r.score)); acc.append(bool(r.accepted))
    return np.stack(est), ms, conf, (iou if seg is not None else []), score, acc


def parse_stages(text: str) -> tuple[tuple, ...]:
    """"2:4,4:4:xy" -> ((2.0, 4), (4.0, 4, "xy")): `AlignConfig.stages` from the command line."""
    stages = []
    for part in text.split(","):
        f = part.split(":")
        if len(f) not in (2, 3) or (len(f) == 3 and f[2] != "xy"):
            raise SystemExit(f"--stages: {part!r} is not sharpness:iterations[:xy]")
        stages.append((float(f[0]), int(f[1]), *f[2:]))
    return tuple(stages)


def _iml_estimate(row: dict):
    """IML's estimate of a frame of `evaluate --json`: `est` of an IML-only run, `iml_est` of a
    pipeline run (None where the IML did not detect the robot)."""
    if "iml_est" in row:
        return row["iml_est"] if row["detected"] else None
    return row["est"]


def main(a: Args) -> list[dict]:
    allocator.tune_allocator()
    frames, inits_iml = [], []
    for i, root in enumerate(a.data):
        fr = [f for f in data.read_bop(root, a.split) if f.observed]
        if a.iml_json:  # the frames the IML detected (est is None for the others), as evaluate scores them
            est = {(r["scene_id"], r["im_id"]): _iml_estimate(r) for r in json.loads(Path(a.iml_json[i]).read_text())["frames"]}
            fr = [f for f in fr if est[(f.scene_id, f.im_id)] is not None]
            inits_iml += [est[(f.scene_id, f.im_id)] for f in fr][:: a.stride]
        frames += fr[:: a.stride]
    gt = np.stack([f.xypsi for f in frames]).astype(np.float32)
    rng = np.random.default_rng(a.seed)
    noise = np.stack([rng.normal(0, 0.15, len(gt)), rng.normal(0, 0.15, len(gt)),
                      rng.normal(0, np.deg2rad(20), len(gt))], 1).astype(np.float32)
    starts = {"noise": gt + noise, "truth": gt.copy()}
    if inits_iml:
        starts["iml"] = np.asarray(inits_iml, np.float32)
    mesh = render.as_mesh(data.load_bop_model(a.data[0]))
    cfg = AlignConfig(crop=a.crop, debias_stages=a.debias_stages, max_score=a.max_score, coarse_margin=a.coarse_margin,
                      mirror=a.mirror_hypotheses, min_turn=float(np.deg2rad(a.min_turn_deg)), max_shift=a.max_shift, fd=a.fd,
                      **({} if a.coarse else {"coarse_stages": ()}),
                      **({} if a.stages is None else {"stages": parse_stages(a.stages)}))
    rows, per_frame = [], []
    ref = None if a.refiner is None else load_refiner(a.refiner, data.load_bop_model(a.data[0]))
    seg = None if a.segmenter is None else load_segmenter(a.segmenter, data.load_bop_model(a.data[0]))
    sc = None if a.scorer is None else load_scorer(a.scorer, data.load_bop_model(a.data[0]))
    fine = None if a.fine_refiner is None else check_ensemble(
        tuple(load_refiner(f, data.load_bop_model(a.data[0])) for f in a.fine_refiner))
    for name in [n for n in a.starts if n in starts]:  # iml only with --iml-json
        init = starts[name]
        if ref is not None:
            rows += learned(a, ref, mesh, cfg, frames, init, gt, name, per_frame, sc, fine)
            last = np.asarray(per_frame[-1]["learned_iterates"])[:, -1]
            for key, kind, on in (("oracle", "gt masks", a.oracle_from_learned),
                                  ("segmenter", "segmenter masks", a.segmenter_from_learned and seg is not None)):
                if not on:
                    continue
                est, ms, conf, iou, score, acc = aligned(mesh, cfg, seg if key == "segmenter" else None, frames, last,
                                                         a.mask_threshold)
                per_frame[-1][f"learned_then_{key}"] = est.tolist()
                per_frame[-1][f"learned_then_{key}_score"] = score
                per_frame[-1][f"learned_then_{key}_flip_confidence"] = conf
                per_frame[-1][f"learned_then_{key}_mask_iou"] = iou
                rows.append({"start": name, "stage": f"learned + alignment ({kind})", "frames": len(gt), "stride": a.stride,
                             **summary(est, gt, ms), "accepted": int(np.sum(acc)),
                             **({"median_mask_iou": float(np.median(iou))} if iou else {})})
                print(json.dumps(rows[-1]), flush=True)
            for n in a.fine_after_align if seg is not None and fine is not None else ():
                est, ms = whole_stage(a, ref, mesh, cfg, frames, init, sc, fine, seg, n)
                per_frame.append({"start": name, "stage": f"fine_after_align {n}", "est": est.tolist()})
                rows.append({"start": name, "stage": f"IR with the alignment (segmenter masks) + {n} fine", "frames": len(gt),
                             "stride": a.stride, **summary(est, gt, ms)})
                print(json.dumps(rows[-1]), flush=True)
        kinds = ((["gt masks"] if a.oracle else []) + (["segmenter masks"] if seg is not None else [])) if a.from_start else []
        for kind in kinds:
            est, ms, conf, iou, score, acc = aligned(mesh, cfg, seg if kind == "segmenter masks" else None, frames, init,
                                                     a.mask_threshold)
            per_frame.append({"start": name, "masks": kind, "gt": gt.tolist(), "init": init.tolist(), "est": est.tolist(),
                              "flip_confidence": conf, "mask_iou": iou, "score": score, "accepted": acc})
            for stage, e, t in (("start", init, None), (f"alignment ({kind})", est, ms)):
                if t is None and kind != kinds[0]:
                    continue
                row = {"start": name, "stage": stage, "frames": len(gt), "stride": a.stride, **summary(e, gt, t)}
                if t is not None:
                    row["median_flip_confidence"] = float(np.median(conf))
                    row["accepted"] = int(np.sum(acc))
                    if kind == "segmenter masks":
                        row["median_mask_iou"] = float(np.median(iou))
                print(json.dumps(row), flush=True)
                rows.append(row)
    if a.json:
        a.json.write_text(json.dumps({"args": {k: str(v) for k, v in dataclasses.asdict(a).items()}, "rows": rows, "per_frame": per_frame}))
    return rows


if __name__ == "__main__":
    main(tyro.cli(Args))


def rows_from_json(path: Path) -> list[dict]:
    """The rows of a saved run recomputed from its per-frame dump (e.g. the start rows of a
    --refiner --no-oracle run: column 0 of the learned iterates)."""
    d = json.loads(Path(path).read_text())
    gt = {}
    rows = []
    for pf in d["per_frame"]:
        if "gt" in pf:
            gt[pf["start"]] = np.asarray(pf["gt"])
    for pf in d["per_frame"]:
        its = np.asarray(pf.get("learned_iterates", []))
        if its.size and pf["start"] in gt:
            rows.append({"start": pf["start"], "stage": "start", **summary(its[:, 0], gt[pf["start"]])})
    return rows
