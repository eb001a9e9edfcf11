"""AMLNet (IML) alone on a BOP data set: the paper's metrics for a checkpoint.

Run: python experiments/eval_amlnet.py --ckpt rhaml_jax/checkpoints/amlnet_cpu --data DIR [--split val] [--json OUT]
Each image is resized (area filter) to the network's input, as the pipeline does. Prints mean
+- std of |dx|, |dy| (cm), |dpsi| (deg) and the ATE (eq. 12) over the frames with the robot in
view, and the detection counts (threshold 0.5 on o) over all frames.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import cv2
import jax
import numpy as np
import tyro

from rhaml_jax import metrics
from rhaml_jax.amlnet import decode, load_model
from rhaml_jax.data import load_rgb, read_bop


@dataclasses.dataclass(frozen=True)
class Args:
    ckpt: Path
    data: Path
    split: str | None = None
    batch: int = 32
    json: Path | None = None


def evaluate(args: Args) -> dict:
    net, params, stats = load_model(args.ckpt)
    h, w = net.cfg.input_hw
    angle_head = getattr(net.cfg, "angle_head", "psi")
    predict = jax.jit(lambda p, s, x: decode(net.apply(p, s, x), angle_head))
    frames = read_bop(args.data, args.split)
    est, obs_prob = [], []
    t0 = time.perf_counter()
    for i in range(0, len(frames), args.batch):
        chunk = frames[i : i + args.batch]
        imgs = np.stack([cv2.resize(load_rgb(f.rgb), (w, h), interpolation=cv2.INTER_AREA) for f in chunk]).astype(np.float32) / 255.0
        pad = args.batch - len(chunk)
        if pad:
            imgs = np.concatenate([imgs, np.zeros((pad,) + imgs.shape[1:], np.float32)])
        out = jax.device_get(predict(params, stats, imgs))
        est.append(np.stack([out["x"], out["y"], out["psi"]], 1)[: len(chunk)])
        obs_prob.append(out["o"][: len(chunk)])
    seconds = time.perf_counter() - t0
    est, prob = np.concatenate(est), np.concatenate(obs_prob)
    observed = np.array([f.observed for f in frames])
    gt = np.array([f.xypsi if f.observed else np.zeros(3) for f in frames])
    det = prob >= 0.5
    summary = metrics.summarize(est[observed], gt[observed])
    return {
        "metrics": {k: summary[k] for k in ("dx_cm", "dy_cm", "dpsi_deg", "ate")} | {
            "fps": len(frames) / seconds,
            "detection": {"tp": int((det & observed).sum()), "fp": int((det & ~observed).sum()),
                          "fn": int((~det & observed).sum()), "tn": int((~det & ~observed).sum())},
            "detection_accuracy": float((det == observed).mean()), "frames": len(frames), "observed_frames": int(observed.sum()),
        },
        "frames": [{"scene_id": f.scene_id, "im_id": f.im_id, "observed": bool(f.observed),
                    "est": [float(v) for v in e], "gt": None if not f.observed else [float(v) for v in g]}
                   for f, e, g in zip(frames, est, gt)],
    }


def main(args: Args) -> None:
    res = evaluate(args)
    if args.json is not None:
        args.json.write_text(json.dumps(res))
    print(json.dumps(res["metrics"]))


if __name__ == "__main__":
    main(tyro.cli(Args))
