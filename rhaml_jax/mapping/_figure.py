"""The merged-map figure: the grid (free white, unknown grey, occupied black) and the trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rhaml_jax.mapping._mapfile import OccupancyMap, map_to_grid

__all__ = ["plot_merged"]

COLOURS = ("tab:blue", "tab:red", "tab:green", "tab:orange")


def plot_merged(path: Path, m: OccupancyMap, trajectories: dict[str, np.ndarray] | None = None,
                origins: dict[str, np.ndarray] | None = None, title: str = "", dpi: int = 90) -> Path:
    """Writes a PNG of map `m` with trajectories {label: (N, 2+) in m's map frame} and map
    origins {label: (3,) pose in m's map frame}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img = np.full(m.shape, 0.75)
    img[m.free] = 1.0
    img[m.occupied] = 0.0
    H, W = m.shape
    res = m.resolution
    # drawn in the grid frame shifted by the origin's (x, y): the map frame itself when yaw = 0
    x0, y0 = m.origin[0], m.origin[1]

    def to_plot(p):
        g = map_to_grid(m.origin, np.asarray(p, np.float64)[..., :2])
        return g + np.array([x0, y0])

    if m.known.any():
        r, c = np.nonzero(m.known)
        H_, W_ = r.max() - r.min() + 20, c.max() - c.min() + 20
    else:
        H_, W_ = H, W
    fig, ax = plt.subplots(figsize=(6.4, min(6.4 * H_ / max(W_, 1), 9.0) + 0.6))
    ax.imshow(img, cmap="gray", vmin=0, vmax=1, origin="lower", extent=(x0, x0 + W * res, y0, y0 + H * res),
              interpolation="nearest")
    for k, (label, tr) in enumerate((trajectories or {}).items()):
        p = to_plot(tr)
        ax.plot(p[:, 0], p[:, 1], "-", color=COLOURS[k % len(COLOURS)], lw=1.2, label=label)
    for k, (label, pose) in enumerate((origins or {}).items()):
        pose = np.asarray(pose, np.float64)
        p = to_plot(pose[None])[0]
        psi = pose[2] - m.origin[2]
        ax.arrow(p[0], p[1], 0.5 * np.cos(psi), 0.5 * np.sin(psi), width=0.04, color=COLOURS[k % len(COLOURS)],
                 length_includes_head=True)
        ax.annotate(label, p, textcoords="offset points", xytext=(4, -10), fontsize=8, color=COLOURS[k % len(COLOURS)])
    if m.known.any():  # frame the known part
        r, c = np.nonzero(m.known)
        ax.set_xlim(x0 + (c.min() - 10) * res, x0 + (c.max() + 10) * res)
        ax.set_ylim(y0 + (r.min() - 10) * res, y0 + (r.max() + 10) * res)
    if trajectories:
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("x (m)" if m.origin[2] == 0 else "x (m, grid axes)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
