"""How well do one image's pixels pin the range? Our scenario images are rendered without
anti-aliasing (the hard rasterizer samples each pixel at its centre), so an edge is seen only as
the pixel centres it covers. For each frame the robot is rendered at its true bearing and heading
with the range scaled by (1 + e) over a grid of e, at the image's own pixel centres, and compared
with the render at the true pose: the silhouette, and the silhouette with the colours (default
light, 8 bits; a pixel counts as changed beyond `colour_step` levels). The contiguous run of e
whose renders differ from the truth's in at most `t` pixels is the range interval the image
cannot tell apart at that tolerance. Knowing the bearing and heading exactly, an estimate from
that image can do no better than the interval's midpoint: its mean |dx| (= |e| x) and the
interval's mean half-width are printed by range band, end-on views (relative heading within 20
deg of head-on or tail-on) apart. Geometry only: the set's rooms, lights and noise do not enter.

  python experiments/range_quantization.py --data DIR [DIR ...] --stride 10 [--json OUT]
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

from refine_bands import BANDS, end_on, relative_heading_deg  # noqa: E402 (experiments/, the script's folder)
from rhaml_jax import allocator, crop, data, frames, render
from rhaml_jax.camera import T_cam_robot
from rhaml_jax.refine.alignment import _corners


@dataclasses.dataclass(frozen=True)
class Args:
    data: tuple[Path, ...]
    """BOP scenario folders"""
    stride: int = 10
    """every stride-th observed frame"""
    max_scale: float = 0.03
    """the grid of e spans +-max_scale"""
    step: float = 0.0002
    """grid step of e"""
    window: int = 192
    """side (px) of the pixel window rendered around the robot's projection"""
    tolerances: tuple[int, ...] = (0, 2, 5)
    """pixels allowed to change for two renders to count as the same"""
    colour_step: int = 4
    """a pixel's colour counts as changed beyond this many 8-bit levels (any channel)"""
    camera_height_m: float = 0.30
    json: Path | None = None


def identical_interval(same: np.ndarray, e: np.ndarray) -> tuple[float, float]:
    """The contiguous run of True in `same` (n,) around e == 0 (e sorted, 0 included): (lo, hi),
    each extended half a grid step outwards (the first different render lies beyond)."""
    i0 = int(np.argmin(np.abs(e)))
    lo = hi = i0
    while lo > 0 and same[lo - 1]:
        lo -= 1
    while hi < len(e) - 1 and same[hi + 1]:
        hi += 1
    half = 0.5 * (e[1] - e[0])
    return float(e[lo] - half), float(e[hi] + half)


def main(a: Args) -> dict:
    allocator.tune_allocator()
    frs = []
    for root in a.data:
        frs += [f for f in data.read_bop(root) if f.observed][:: a.stride]
    mesh = render.as_mesh(data.load_bop_model(a.data[0]))
    corners = _corners(mesh)
    e = np.round(np.arange(-a.max_scale, a.max_scale + a.step / 2, a.step) / a.step) * a.step
    S = a.window
    T_rc = T_cam_robot(a.camera_height_m)

    @jax.jit
    def masks_and_rgb(xypsi, K, box):
        scaled = jnp.concatenate([xypsi[None, :2] * (1.0 + jnp.asarray(e, jnp.float32))[:, None],
                                  jnp.broadcast_to(xypsi[2], (len(e), 1))], 1)
        T = jax.vmap(lambda p: (T_rc @ frames.se3_from_xypsi(p)).wxyz_xyz)(scaled)
        out = render.render(mesh, jaxlie.SE3(T), K, S, S, box=box)
        return out.mask, jnp.round(out.rgb * 255).astype(jnp.int32)

    i0 = int(np.argmin(np.abs(e)))
    rows = []
    for fr in frs:
        gt = np.asarray(fr.xypsi, np.float32)
        K = jnp.asarray(fr.K, jnp.float32)
        T = T_rc @ frames.se3_from_xypsi(jnp.asarray(gt))
        c = np.asarray(crop.object_box(K, T @ corners, margin=1.0))
        u0, v0 = np.round(0.5 * (c[:2] + c[2:])) - S // 2  # a window of whole pixels: its centres are the image's
        box = jnp.asarray([u0 - 0.5, v0 - 0.5, u0 + S - 0.5, v0 + S - 0.5], jnp.float32)
        mask, rgb = (np.asarray(x) for x in masks_and_rgb(jnp.asarray(gt), K, box))
        n_mask = np.sum(mask != mask[i0], axis=(1, 2))  # (len(e),) silhouette pixels changed
        n_rgb = np.sum(np.abs(rgb - rgb[i0]).max(-1) > a.colour_step, axis=(1, 2))  # pixels whose colour changed
        rows.append({"rgb": str(fr.rgb), "range_m": float(np.hypot(gt[0], gt[1])), "x_m": float(gt[0]),
                     "relative_heading_deg": float(relative_heading_deg(gt[None])[0]),
                     "mask_px": int(mask[i0].sum()), "width_px": float(c[2] - c[0]),
                     **{f"silhouette_{t}": identical_interval(n_mask <= t, e) for t in a.tolerances},
                     **{f"colours_{t}": identical_interval((n_mask <= t) & (n_rgb <= t), e) for t in a.tolerances}})
    out = {"args": {k: str(v) for k, v in dataclasses.asdict(a).items()}, "frames": rows, "bands": summary(rows, a.tolerances)}
    if a.json:
        a.json.write_text(json.dumps(out))
    return out


def summary(rows: list[dict], tolerances) -> list[dict]:
    """Per band and view: frames, mean half-width of the identical interval (%) and the mean |dx|
    (cm) of its midpoint, for the silhouette and for the colours, at each tolerance."""
    r = np.array([x["range_m"] for x in rows])
    x = np.array([x["x_m"] for x in rows])
    ends = end_on(np.array([x["relative_heading_deg"] for x in rows]))
    out = []
    for view, m in (("end-on", ends), ("other", ~ends), ("all", np.ones_like(ends))):
        for lo, hi in zip(BANDS[:-1], BANDS[1:]):
            k = m & (r >= lo) & (r < hi)
            if not k.any():
                continue
            row = {"view": view, "band_m": [lo, hi], "frames": int(k.sum())}
            for what in [f"{w}_{t}" for w in ("silhouette", "colours") for t in tolerances]:
                iv = np.array([rows[i][what] for i in np.flatnonzero(k)])
                half = 0.5 * (iv[:, 1] - iv[:, 0])
                mid = 0.5 * (iv[:, 1] + iv[:, 0])
                row[what] = {"half_width_pct": float(100 * half.mean()), "midpoint_abs_pct": float(100 * np.abs(mid).mean()),
                             "midpoint_dx_cm": float(100 * np.mean(np.abs(mid * x[k])))}
            out.append(row)
            print(json.dumps(row), flush=True)
    return out


if __name__ == "__main__":
    main(tyro.cli(Args))
