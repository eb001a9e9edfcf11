"""How far the robot is by the image row of its reference point, against AMLNet's range head.

  python experiments/row_range.py DATA [DATA ...] [--amlnet CKPT] [--stride 5]

The camera sits at the nominal height with no tilt (DESIGN.md section 2), so the row v at which
AMLNet's heatmap puts the robot's reference point (`zoom_centre_z_m` above the floor) gives its
depth without its size: x = fy (h - z_ref) / (v - cy), in the network camera. This prints, per
BOP set, over the frames with the robot in view where AMLNet finds it (o >= 0.5): the median
est/true range of the range head and of the row, the median abs error of each (%), and how many
frames each puts within 10 %. A diagnostic for issue 18's "range from the geometry": the size cue
reads long on dark surroundings (BENCHMARKS.md, "Dim rooms in training do not take the long range
away"); does the row?
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, nargs="+")
    ap.add_argument("--amlnet", type=Path)
    ap.add_argument("--stride", type=int, default=5, help="every n-th frame")
    a = ap.parse_args()

    from rhaml_jax import crop
    from rhaml_jax.amlnet.heatmap import STRIDE
    from rhaml_jax.camera import DEFAULT_CAMERA, NOMINAL_HEIGHT_M
    from rhaml_jax.data import read_bop
    from rhaml_jax.iml import load_iml

    model, params = load_iml(a.amlnet, no_zoom=True)
    net = model.amlnet
    h, w = net.cfg.input_hw
    net_K = jnp.asarray(DEFAULT_CAMERA.resized(w, h).K, jnp.float32)
    z_ref = float(net.cfg.zoom_centre_z_m)
    Kn = np.asarray(net_K)  # the heatmap's camera (`heatmap.net_intrinsics` of its grid)

    @jax.jit
    def peak(image, K):  # (H, W, 3) uint8 -> (o, range head, u, v) in the network image
        box = crop.network_box(K, (image.shape[1], image.shape[0]), net_K, (w, h))
        x = jnp.round(crop.resample(image.astype(jnp.float32), box, w, h)) / 255.0
        out = net.apply(*params.amlnet, x[None])[0]
        gh, gw, C = out.shape
        flat = out.reshape(gh * gw, C)
        i = jnp.argmax(flat[:, 0])
        at = flat[i]
        return jax.nn.sigmoid(at[0]), jnp.exp(at[3]), STRIDE * (i % gw + at[1]) - 0.5, STRIDE * (i // gw + at[2]) - 0.5

    print("| data | frames | range head: median est/true, median abs error, within 10 % | row: median est/true, median abs error, within 10 % |\n"
          "| --- | --- | --- | --- |")
    for root in a.data:
        head, row = [], []
        frames = [f for f in read_bop(root) if f.mask is not None][:: a.stride]
        for f in frames:
            o, r, u, v = (float(t) for t in peak(np.asarray(Image.open(f.rgb).convert("RGB")), jnp.asarray(f.K, jnp.float32)))
            if o < 0.5:
                continue
            t = np.asarray(f.T_m2c)[:3, 3]  # the observed robot's origin in the camera frame (z: depth)
            true_r = float(np.hypot(t[2], t[0]))
            bearing_x = (u - Kn[0, 2]) / Kn[0, 0]  # optical x / z of the peak's ray
            depth = Kn[1, 1] * (NOMINAL_HEIGHT_M - z_ref) / max(v - Kn[1, 2], 1e-3)  # guard: a row at the horizon
            head.append(r / true_r)
            row.append(depth * np.hypot(1.0, bearing_x) / true_r)
        cells = []
        for q in (np.array(head), np.array(row)):
            e = np.abs(q - 1)
            cells.append(f"{np.median(q):.3f}, {100 * np.median(e):.1f} %, {np.mean(e < 0.1):.0%}")
        print(f"| {root} | {len(head)} | {cells[0]} | {cells[1]} |", flush=True)


if __name__ == "__main__":
    main()
