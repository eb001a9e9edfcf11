"""A photometric front/back test, measured and not adopted (BENCHMARKS.md, "What a single frame
can tell about front and back"): from each IML estimate, one learned refiner iteration from the
estimate and from its heading turned by 180 deg; both results rendered in the crop around the
first; the hypothesis whose render's luminance correlates better with the observed crop's inside
its mask wins (`margin`: by how much the turned one must be better).

  python experiments/flip_photometric.py --data /work/data/circle /work/data/sine \
      --iml-json /work/data/iml_circle.json /work/data/iml_sine.json --stride 4
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import tyro

from rhaml_jax import crop as _crop
from rhaml_jax import data, render
from rhaml_jax.amlnet.model import LUMA
from rhaml_jax.planar import wrap_angle
from rhaml_jax.refine import RefineConfig, _corners, _T_cam, refine, shipped_refiner


@dataclasses.dataclass(frozen=True)
class Args:
    data: tuple[Path, ...]
    iml_json: tuple[Path, ...]
    """`evaluate --json` of the same folders (the starts)"""
    stride: int = 4
    """every stride-th detected frame, and every frame the IML flipped"""
    crop: int = 96
    margins: tuple[float, ...] = (0.0, 0.02, 0.05)
    camera_height_m: float = 0.30


def ncc(a, b):
    return float(np.corrcoef(a, b)[0, 1]) if a.size > 3 and a.std() > 0 and b.std() > 0 else 0.0


def main(a: Args):
    h, S = a.camera_height_m, a.crop
    diffs, flipped = [], []
    for root, ij in zip(a.data, a.iml_json):
        model = data.load_bop_model(root)
        mesh, ref = render.as_mesh(model), shipped_refiner(model)
        corners = _corners(mesh)
        cfg = RefineConfig(align=None, n_iter=1)

        @jax.jit
        def both(im, init, K):
            inits = jnp.stack([init, init + jnp.array([0.0, 0.0, jnp.pi])])
            xyp = jax.vmap(lambda i: refine(ref, mesh, im, K, i, cfg).xypsi)(inits)
            box = _crop.object_box(K, _T_cam(xyp[0], h) @ corners, margin=1.3)
            T = jax.vmap(lambda p: _T_cam(p, h).wxyz_xyz)(xyp)
            out = render.render(mesh, jaxlie.SE3(T), K, S, S, box=jnp.broadcast_to(box, (2, 4)))
            return xyp, _crop.crop_image(im, box, S, S), out.rgb, out.mask

        est = {f["im_id"]: f for f in json.loads(ij.read_text())["frames"] if f["observed"] and f["detected"]}
        for k, fr in enumerate(f for f in data.read_bop(root, "test") if f.im_id in est):
            e = est[fr.im_id]
            was_flipped = abs(wrap_angle(e["est"][2] - e["gt"][2])) > np.pi / 2
            if k % a.stride and not was_flipped:
                continue
            im = jnp.asarray(data.load_rgb(fr.rgb), jnp.float32) / 255
            xyp, obs, rgb, m = jax.device_get(both(im, jnp.asarray(e["est"], jnp.float32), jnp.asarray(fr.K, jnp.float32)))
            lo, lr = obs @ np.asarray(LUMA), rgb @ np.asarray(LUMA)
            c = [ncc(lr[j][m[j] > 0.5], lo[m[j] > 0.5]) for j in range(2)]
            diffs.append(c[1] - c[0])  # > 0: the turned hypothesis correlates better
            flipped.append(abs(wrap_angle(xyp[0][2] - fr.xypsi[2])) > np.pi / 2)
    d, f = np.array(diffs), np.array(flipped)
    for t in a.margins:
        turn = d > t
        print(json.dumps({"margin": t, "frames": len(d), "flips_before": int(f.sum()), "fixed": int((f & turn).sum()),
                          "made": int((~f & turn).sum()), "flips_after": int((f ^ turn).sum())}))


if __name__ == "__main__":
    main(tyro.cli(Args))
