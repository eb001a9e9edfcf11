"""Does a refiner read each part of the pose update? Per component of DeepIM's update (v_x, v_y,
v_z, rotation vector), the correlation and the slope of the predicted against the true update
on validation draws (the training's own: `refine.train.RefinerSource`, flips left out). A part
the network cannot read has slope ~0 (session 17: the heading, r_y, before the disentangled loss).

  python experiments/refiner_update_corr.py --refiner RUN_OR_EXPORT --data BOP_SET [--split val] [--batches 8]
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jaxlie
import numpy as np
import tyro

from rhaml_jax import render
from rhaml_jax.data import load_bop_model
from rhaml_jax.refine import load_refiner
from rhaml_jax.refine import net as N
from rhaml_jax.refine.train import RefinerSource, render_input


@dataclasses.dataclass(frozen=True)
class Args:
    refiner: Path
    data: Path
    split: str = "val"
    batches: int = 8
    """batches of 32 draws"""
    seed: int = 10_000
    """the training's validation seed"""


def main() -> None:
    a = tyro.cli(Args, description=__doc__.split("\n\n")[0])
    model = load_bop_model(a.data)
    ref = load_refiner(a.refiner, model)
    rc = ref.cfg
    src = RefinerSource(a.data, a.split, rc, 32, seed=a.seed)
    mesh = render.as_mesh(model)

    @jax.jit
    def pred_and_true(obs, box, K, T_init, T_gt):
        T0 = jaxlie.SE3(T_init)
        out = N.apply(rc, ref.params, render_input(mesh, rc, obs, T0, K, box))
        return out.update, N.target_update(T0, jaxlie.SE3(T_gt), K, box)

    P, T = [], []
    for s in range(a.batches):
        b = src(s)
        p, t = pred_and_true(b.obs, b.box, b.K, b.T_init, b.T_gt)
        P.append(np.asarray(p))
        T.append(np.asarray(t))
    P, T = np.concatenate(P), np.concatenate(T)
    keep = np.linalg.norm(T[:, 3:], axis=1) < 1.0  # the flips (a turn near 180 deg) are not a refiner's to undo
    P, T = P[keep], T[keep]
    for k, name in enumerate(["v_x", "v_y", "v_z", "r_x", "r_y", "r_z"]):
        if T[:, k].std() < 1e-6:  # the data never varies this part (level cameras: r_x, r_z)
            row = {"part": name, "true_std": float(T[:, k].std()), "pred_std": float(P[:, k].std())}
        else:
            row = {"part": name, "corr": float(np.corrcoef(P[:, k], T[:, k])[0, 1]),
                   "slope": float(np.polyfit(T[:, k], P[:, k], 1)[0]), "true_std": float(T[:, k].std()),
                   "pred_std": float(P[:, k].std())}
        print(json.dumps(row))


if __name__ == "__main__":
    main()
