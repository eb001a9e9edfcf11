"""The IML chain jitted end to end (rhaml_jax.iml.localize) against the host chain that
`evaluate` ran before the pipeline (commit 817e372: AMLNet on OpenCV-resized images, the OpenCV
zoom crop, the zoom network, mirror averaging and the correction on the host, a device_get
between each), on the same frames, interleaved: metrics and frames per second side by side.

  python experiments/bench_iml.py --data /work/data/circle [--frames 500] [--repeats 3] [--out iml.json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def host_chain(frames, images, net, params, stats, zoom, batch=32):
    """evaluate_iml of commit 817e372 (with --zoom-mirror), images already decoded."""
    import jax

    from rhaml_jax.amlnet import decode
    from rhaml_jax.crop import min_range_m
    from rhaml_jax.zoom import apply_correction, mirror_average, zoom_crop
    from rhaml_jax.data import network_image

    h, w = net.cfg.input_hw
    predict = jax.jit(lambda p, s, x: decode(net.apply(p, s, x), net.cfg.angle_head))
    znet, zparams, zstats = zoom
    zpredict = jax.jit(lambda p, s, x: decode(znet.apply(p, s, x), znet.cfg.angle_head))
    pad = lambda x: np.concatenate([x, np.zeros((batch - len(x),) + x.shape[1:], x.dtype)])  # noqa: E731
    est, seconds = [], 0.0
    for i in range(0, len(frames), batch):
        chunk, full = frames[i:i + batch], images[i:i + batch]
        t = time.perf_counter()
        x = np.stack([network_image(im, f.K, (h, w)) for im, f in zip(full, chunk)]).astype(np.float32) / 255.0
        out = jax.device_get(predict(params, stats, pad(x)))
        e = np.stack([out["x"], out["y"], out["psi"]], 1)[:len(chunk)]
        crops = np.stack([zoom_crop(im, f.K, g[:2], znet.cfg) for im, f, g in zip(full, chunk, e)]).astype(np.float32) / 255

        def correct(c):
            z = jax.device_get(zpredict(zparams, zstats, pad(c)))
            return np.stack([z["x"], z["y"], z["psi"]], 1)[:len(chunk)]

        e = apply_correction(e[:, :2], mirror_average(correct(crops), correct(np.ascontiguousarray(crops[:, :, ::-1]))),
                             min_range_m(znet.cfg.zoom_length_m))
        if i:
            seconds += time.perf_counter() - t
        est.append(e)
    return np.concatenate(est), (len(frames) - batch) / seconds


def jit_chain(frames, images, model, params, batch=32):
    import jax

    from rhaml_jax import iml

    K = np.stack([f.K for f in frames]).astype(np.float32)
    est, seconds = [], 0.0
    for i in range(0, len(frames), batch):
        b, k = np.stack(images[i:i + batch]), K[i:i + batch]
        m = len(b)
        if m < batch:
            b = np.concatenate([b, np.zeros((batch - m,) + b.shape[1:], b.dtype)])
            k = np.concatenate([k, np.repeat(k[:1], batch - m, 0)])
        t = time.perf_counter()
        e = jax.device_get(iml.localize_jit(model, params, b, k))
        if i:
            seconds += time.perf_counter() - t
        est.append(e.xypsi[:m])
    return np.concatenate(est), (len(frames) - batch) / seconds


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out")
    a = ap.parse_args()
    from rhaml_jax import iml, metrics, tune_allocator

    tune_allocator()
    from rhaml_jax.amlnet import load_model, shipped_checkpoint
    from rhaml_jax.data import load_rgb, read_bop

    frames = read_bop(a.data)[:a.frames]
    images = [load_rgb(f.rgb) for f in frames]
    net, p, s = load_model(shipped_checkpoint("amlnet_cpu"))
    zoom = load_model(shipped_checkpoint("zoom_cpu"))
    model, params = iml.load_iml(zoom_mirror=True)
    fps = {"host": [], "jit": []}
    for _ in range(a.repeats):  # interleaved: both see the same machine load
        e_host, f = host_chain(frames, images, net, p, s, zoom)
        fps["host"].append(f)
        e_jit, f = jit_chain(frames, images, model, params)
        fps["jit"].append(f)
    obs = np.array([f.observed for f in frames])
    gt = np.array([f.xypsi for f in frames if f.observed])
    res = {"frames": len(frames), "repeats": a.repeats,
           "host": metrics.summarize(e_host[obs], gt), "jit": metrics.summarize(e_jit[obs], gt),
           "fps_host_median": float(np.median(fps["host"])), "fps_jit_median": float(np.median(fps["jit"])),
           "fps_host": fps["host"], "fps_jit": fps["jit"],
           "max_abs_diff": np.abs(e_host - e_jit).max(0).tolist()}
    print(json.dumps(res))
    if a.out:
        open(a.out, "w").write(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
