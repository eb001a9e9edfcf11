"""Renderer benchmarks (medians on this machine): soft silhouette of a 64 x 64 zoom-in crop
(forward, forward+backward of a silhouette loss wrt the pose), the same with XLA's reverse mode
and with a naive all-pairs formulation (side by side), a batch of 32 crops, the 640 x 480 shaded
render, and how cost grows with faces and pixels.

    .venv/bin/python experiments/bench_render.py [--repeats 20] [--json out.json] [--before REV]

--before REV also times the renderer package as it was at git revision REV (extracted to a
temporary folder), side by side with the current one on the 64 x 64 crop.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax import render as R
from rhaml_jax.camera import DEFAULT_CAMERA as CAM, T_cam_robot
from rhaml_jax.robots import load_robot

URDF = Path(__file__).resolve().parents[2] / "shared" / "data" / "robots" / "pioneer3dx" / "urdf" / "pioneer3dx.urdf"


def view(x, y, psi, h=0.30):
    T = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_z_radians(jnp.float32(psi)),
                                                 jnp.asarray([x, y, 0.0], jnp.float32))
    return T_cam_robot(h) @ T


def crop_box(mesh, T, grow=1.3):
    M = np.asarray(T.as_matrix())
    p = np.asarray(mesh.vertices) @ M[:3, :3].T + M[:3, 3]
    uv = p @ CAM.K.T
    uv = uv[:, :2] / uv[:, 2:3]
    c, half = (uv.min(0) + uv.max(0)) / 2, grow * (uv.max(0) - uv.min(0)).max() / 2
    return jnp.asarray([c[0] - half, c[1] - half, c[0] + half, c[1] + half], jnp.float32)


def timed(fns: dict, args: dict, repeats: int) -> dict:
    """Median ms of each jitted fn, run round-robin (side by side) after one warm-up call each."""
    for k, f in fns.items():
        jax.block_until_ready(f(*args[k]))
    ts = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(f(*args[k]))
            ts[k].append(time.perf_counter() - t)
    return {k: 1e3 * float(np.median(v)) for k, v in ts.items()}


def soft_fns(mesh, size, sharpness, config, naive=False):
    """Jitted forward and forward+backward (loss wrt the pose's tangent) of one crop."""
    sil = R.silhouette_naive if naive else R.silhouette
    kw = dict(sharpness=sharpness) if naive else dict(sharpness=sharpness, config=config)

    def loss(delta, T0, box, target):
        s = sil(mesh, T0 @ jaxlie.SE3.exp(delta), CAM.K, size, size, box=box, **kw)
        return jnp.sum((s - target) ** 2)

    fwd = jax.jit(lambda T0, box: sil(mesh, T0, CAM.K, size, size, box=box, **kw))
    return fwd, jax.jit(jax.value_and_grad(loss))


def render_at(rev: str):
    """The rhaml_jax.render package of git revision `rev`, imported as `render_before`."""
    root = Path(__file__).resolve().parents[1]
    names = subprocess.run(["git", "ls-tree", "--name-only", rev, "rhaml_jax/render/"], cwd=root, check=True,
                           capture_output=True, text=True).stdout.split()
    out = Path(tempfile.mkdtemp()) / "render_before"
    out.mkdir()
    for n in names:
        src = subprocess.run(["git", "show", f"{rev}:{n}"], cwd=root, check=True, capture_output=True, text=True).stdout
        (out / Path(n).name).write_text(src.replace("rhaml_jax.render", "render_before"))
    sys.path.insert(0, str(out.parent))
    import render_before

    return render_before


def before_fns(B, mesh, size, sharpness):
    m = B.as_mesh((np.asarray(mesh.vertices), np.asarray(mesh.faces)))

    def loss(delta, T0, box, target):
        s = B.silhouette(m, T0 @ jaxlie.SE3.exp(delta), CAM.K, size, size, box=box, sharpness=sharpness)
        return jnp.sum((s - target) ** 2)

    return (jax.jit(lambda T0, box: B.silhouette(m, T0, CAM.K, size, size, box=box, sharpness=sharpness)),
            jax.jit(jax.value_and_grad(loss)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--sharpness", type=float, default=2.0)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--before", help="git revision whose renderer to time side by side")
    a = ap.parse_args()
    k = a.sharpness
    print(f"load average before: {os.getloadavg()}")
    model = load_robot(str(URDF), max_faces=2000) if URDF.exists() else load_robot("pioneer3dx")
    mesh = R.as_mesh(model)
    F = int(mesh.faces.shape[0])
    T0, T1 = view(3.0, 0.3, 0.8), view(3.05, 0.26, 0.9)
    box = crop_box(mesh, T0)
    target = R.silhouette(mesh, T1, CAM.K, 64, 64, box=box, sharpness=k)
    need = int(R.pairs_needed(mesh, T0, CAM.K, 64, 64, box=box, sharpness=k))
    res = {"model": model.name, "faces": F, "sharpness": k, "pairs_64": need}
    print(f"model {model.name}: {F} faces; 64x64 crop of a view at 3 m; sharpness {k}/px; {need} (face, block) pairs")

    # 1. one 64 x 64 crop: binned + custom VJP, binned + XLA autodiff, naive all pairs
    cfg = R.RenderConfig()
    auto = R.RenderConfig(vjp="autodiff", capacity=need + 512)
    f_fwd, f_vg = soft_fns(mesh, 64, k, cfg)
    _, a_vg = soft_fns(mesh, 64, k, auto)
    n_fwd, n_vg = soft_fns(mesh, 64, k, None, naive=True)
    z = jnp.zeros(6)
    fns = {"fwd": f_fwd, "fwd_bwd": f_vg, "autodiff_fwd_bwd": a_vg, "naive_fwd": n_fwd, "naive_fwd_bwd": n_vg}
    args = {"fwd": (T0, box), "fwd_bwd": (z, T0, box, target), "autodiff_fwd_bwd": (z, T0, box, target),
            "naive_fwd": (T0, box), "naive_fwd_bwd": (z, T0, box, target)}
    if a.before:
        b_fwd, b_vg = before_fns(render_at(a.before), mesh, 64, k)
        fns.update(before_fwd=b_fwd, before_fwd_bwd=b_vg)
        args.update(before_fwd=(T0, box), before_fwd_bwd=(z, T0, box, target))
        res["before"] = a.before
        print(f"before ({a.before}) vs now, max |difference| of the forward:",
              float(jnp.abs(b_fwd(T0, box) - f_fwd(T0, box)).max()))
    t = timed(fns, args, a.repeats)
    res["crop64"] = t
    print(json.dumps({"crop64_ms": t}))

    # 2. batch of 32 crops (32 poses around the estimate, a box each)
    rng = np.random.default_rng(0)
    poses = [view(3.0 + rng.normal(0, 0.15), 0.3 + rng.normal(0, 0.15), 0.8 + rng.normal(0, 0.35)) for _ in range(32)]
    Tb = jaxlie.SE3(jnp.stack([p.wxyz_xyz for p in poses]))
    boxes = jnp.stack([crop_box(mesh, p) for p in poses])
    tb = jnp.broadcast_to(target, (32, 64, 64))

    def bloss(delta, T0, box, target):
        s = R.silhouette(mesh, T0 @ jaxlie.SE3.exp(delta), CAM.K, 64, 64, box=box, sharpness=k)
        return jnp.sum((s - target) ** 2)

    b_fwd = jax.jit(lambda T, bx: R.silhouette(mesh, T, CAM.K, 64, 64, box=bx, sharpness=k))
    b_vg = jax.jit(jax.vmap(jax.value_and_grad(bloss)))
    t = timed({"batch32_fwd": b_fwd, "batch32_fwd_bwd": b_vg},
              {"batch32_fwd": (Tb, boxes), "batch32_fwd_bwd": (jnp.zeros((32, 6)), Tb, boxes, tb)}, max(5, a.repeats // 4))
    res["batch32"] = t
    print(json.dumps({"batch32_ms": t}))

    # 3. 640 x 480 shaded render at 2 m and 5 m
    rfn = jax.jit(lambda T: R.render(mesh, T, CAM.K, CAM.width, CAM.height))
    Tn, Tf = view(2.0, 0.2, 0.7), view(5.0, -0.5, 2.0)
    t = timed({"render_640x480_2m": rfn, "render_640x480_5m": lambda T: rfn(T)}, {"render_640x480_2m": (Tn,),
              "render_640x480_5m": (Tf,)}, a.repeats)
    res["render"] = t
    print(json.dumps({"render_ms": t}))

    # 4. scaling with faces (64 x 64 crop; 640 x 480 render) and with crop pixels
    rows = []
    for mf in (500, 1000, 2000, None):
        m = R.as_mesh(load_robot(str(URDF), max_faces=mf) if URDF.exists() else load_robot("pioneer3dx", max_faces=mf or 604))
        bx = crop_box(m, T0)
        tg = R.silhouette(m, T1, CAM.K, 64, 64, box=bx, sharpness=k)
        fw, vg = soft_fns(m, 64, k, cfg)
        rf = jax.jit(lambda T, m=m: R.render(m, T, CAM.K, CAM.width, CAM.height))
        t = timed({"fwd": fw, "fwd_bwd": vg, "render": rf}, {"fwd": (T0, bx), "fwd_bwd": (z, T0, bx, tg), "render": (Tn,)},
                  max(5, a.repeats // 2))
        rows.append({"faces": int(m.faces.shape[0]), "pixels": 64 * 64, **t})
        print(json.dumps(rows[-1]))
    for size in (32, 128):
        tg = R.silhouette(mesh, T1, CAM.K, size, size, box=box, sharpness=k * size / 64)
        fw, vg = soft_fns(mesh, size, k * size / 64, cfg)  # same softness in full-image pixels
        t = timed({"fwd": fw, "fwd_bwd": vg}, {"fwd": (T0, box), "fwd_bwd": (z, T0, box, tg)}, max(5, a.repeats // 2))
        rows.append({"faces": F, "pixels": size * size, **t})
        print(json.dumps(rows[-1]))
    res["scaling"] = rows
    print(f"load average after: {os.getloadavg()}")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
