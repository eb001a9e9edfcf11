"""A refiner on a validation split, iteration by iteration: where a training curriculum is chosen.

  python experiments/refiner_val.py --refiner RUN_OR_EXPORT --data BOP_SET [--split val] [--num 96] [--json out.json]
  python experiments/refiner_val.py ... --iml-json IML.json   # starts: the IML's estimates (evaluate --split val --json)

The examples are the training's own draws on that split (`refine.train.RefinerSource`: the
initial pose as the paper's noise or as our IML errs, half each, a pure function of (seed,
index)), or with `--iml-json` the IML's own estimates of the split's detected robot frames (as
the pipeline starts IR), and the refiner runs as at test time: re-cropped and re-rendered at each new pose, in the
frame's true camera (so the frames' varied camera heights do not enter the error). Prints, after
each learned iteration: the point-matching loss (eq. 8, L1, m; mean and median), the mean depth
and lateral errors (cm), the mean and median |dpsi| (deg, about the camera's vertical axis), the
median range bias (%) and the flips.
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

from rhaml_jax import allocator, frames, render
from rhaml_jax import crop as _crop
from rhaml_jax.data import load_bop_model
from rhaml_jax.refine import load_refiner
from rhaml_jax.refine import net as N
from rhaml_jax.refine.train import RefinerSource, _corners, render_input


@dataclasses.dataclass(frozen=True)
class Args:
    refiner: Path
    """refiner checkpoint folder (a training run or an export)"""
    data: Path
    """BOP set with the split"""
    split: str = "val"
    num: int = 96
    """examples (drawn from the split's frames, cycling)"""
    seed: int = 10_000
    """the training's validation seed (train uses seed + 10,000)"""
    n_iter: int = 4
    iml_json: Path | None = None
    """`evaluate --data DATA --split SPLIT --modules iml --json`: start from its estimates (every
    detected robot frame once; --num is then ignored)"""
    json: Path | None = None


def _errors(T: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> dict:
    """(B, 4, 4) estimates and truths, model to camera -> per-example errors."""
    pe = np.einsum("bij,pj->bpi", T[:, :3, :3], points) + T[:, None, :3, 3]
    pg = np.einsum("bij,pj->bpi", T_gt[:, :3, :3], points) + T_gt[:, None, :3, 3]
    t, tg = T[:, :3, 3], T_gt[:, :3, 3]
    # the model's forward axis in camera coordinates (x right, y down, z ahead): its heading on the floor
    fwd, fwd_g = T[:, :3, 0], T_gt[:, :3, 0]
    dpsi = np.angle(np.exp(1j * (np.arctan2(fwd[:, 0], fwd[:, 2]) - np.arctan2(fwd_g[:, 0], fwd_g[:, 2]))))
    return {"pm": np.abs(pe - pg).sum(-1).mean(-1), "depth": np.abs(t[:, 2] - tg[:, 2]), "lateral": np.abs(t[:, 0] - tg[:, 0]),
            "dpsi": np.abs(dpsi), "range": np.linalg.norm(t, axis=-1) / np.linalg.norm(tg, axis=-1) - 1}


def run(a: Args) -> list[dict]:
    model = load_bop_model(a.data)
    ref = load_refiner(a.refiner, model)
    rc = ref.cfg
    src = RefinerSource(a.data, a.split, rc, 1, seed=a.seed)
    mesh = render.as_mesh(model)
    corners = jnp.asarray(_corners(model.vertices), jnp.float32)
    points = model.sample_surface(512, seed=1)

    @jax.jit
    def step(image, K, wxyz_xyz):
        T = jaxlie.SE3(wxyz_xyz)
        bx = _crop.object_box(K, T @ corners, margin=rc.margin)
        obs = _crop.crop_image(image, bx, rc.crop, rc.crop)
        out = N.apply(rc, ref.params, render_input(mesh, rc, obs[None], jaxlie.SE3(wxyz_xyz[None]), K, bx))
        return N.apply_update(jaxlie.SE3(wxyz_xyz[None]), out.update, K, bx).wxyz_xyz[0]

    if a.iml_json is None:
        starts = [(i % len(src.frames), src.drawn(i)[1]) for i in range(a.num)]
    else:  # the IML's planar estimate, in the frame's own camera (as CropSource.drawn places a drawn one)
        est = {(r["scene_id"], r["im_id"]): r["est"] for r in json.loads(a.iml_json.read_text())["frames"] if r["detected"]}
        starts = [(i, f.T_w2c @ np.asarray(frames.se3_from_xypsi(jnp.asarray(est[(f.scene_id, f.im_id)])).as_matrix())) for i, f in enumerate(src.frames)
                  if (f.scene_id, f.im_id) in est]
    Ts, T_gts = [], []
    for i, T_init in starts:
        f = src.frames[i]
        rgb, _ = src.image(i)
        image, K = jnp.asarray(rgb, jnp.float32) / 255, jnp.asarray(f.K, jnp.float32)
        w = jaxlie.SE3.from_matrix(jnp.asarray(T_init, jnp.float32)).wxyz_xyz
        its = [np.asarray(T_init)]
        for _ in range(a.n_iter):
            w = step(image, K, w)
            its.append(np.asarray(jaxlie.SE3(w).as_matrix()))
        Ts.append(its)
        T_gts.append(f.T_m2c)
    Ts, T_gts = np.asarray(Ts), np.asarray(T_gts)  # (num, n_iter + 1, 4, 4), (num, 4, 4)
    rows = []
    for k in range(a.n_iter + 1):
        e = _errors(Ts[:, k], T_gts, points)
        rows.append({"refiner": str(a.refiner), "data": str(a.data), "split": a.split, "iteration": k, "n": len(starts),
                     "starts": "drawn" if a.iml_json is None else "iml",
                     "pm_m": float(e["pm"].mean()), "median_pm_m": float(np.median(e["pm"])), "depth_cm": float(100 * e["depth"].mean()),
                     "lateral_cm": float(100 * e["lateral"].mean()), "dpsi_deg": float(np.rad2deg(e["dpsi"]).mean()),
                     "median_dpsi_deg": float(np.rad2deg(np.median(e["dpsi"]))),
                     "range_bias_pct": float(100 * np.median(e["range"])), "flips": int((e["dpsi"] > np.pi / 2).sum())})
    return rows


def main() -> None:
    a = tyro.cli(Args, description=__doc__.split("\n\n")[0])
    allocator.tune_allocator()
    rows = run(a)
    for r in rows:
        print(json.dumps(r))
    if a.json is not None:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
