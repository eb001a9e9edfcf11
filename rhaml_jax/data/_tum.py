"""TUM trajectory files: `timestamp tx ty tz qx qy qz qw`, one line per frame (line i = image i)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rhaml_jax.errors import RhamlError

FRAME_PERIOD_S = 0.1  # timestamps of generated sequences: 10 frames per second


def write_tum(path: Path, xypsi: np.ndarray, timestamps: np.ndarray | None = None) -> None:
    """Writes planar poses (N, 3) as TUM rows (z = 0, rotation about z only)."""
    xypsi = np.asarray(xypsi, np.float64)
    t = np.arange(len(xypsi)) * FRAME_PERIOD_S if timestamps is None else np.asarray(timestamps)
    half = xypsi[:, 2] / 2
    rows = np.stack([t, xypsi[:, 0], xypsi[:, 1], np.zeros_like(t), np.zeros_like(t), np.zeros_like(t), np.sin(half), np.cos(half)], 1)
    tmp = Path(str(path) + ".tmp")
    np.savetxt(tmp, rows, fmt="%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f")
    tmp.replace(path)


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """-> (timestamps (N,), planar poses (N, 3)); the yaw of each quaternion (roll, pitch ignored)."""
    path = Path(path)
    if not path.is_file():
        raise RhamlError(f"{path}: TUM file not found")
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            vals = [float(v) for v in line.split()]
        except ValueError:
            raise RhamlError(f"{path}:{n}: not a number in {line!r}") from None
        if len(vals) != 8 or not np.all(np.isfinite(vals)):
            raise RhamlError(f"{path}:{n}: expected 8 finite numbers (timestamp tx ty tz qx qy qz qw), got {line!r}")
        rows.append(vals)
    a = np.array(rows, np.float64).reshape(-1, 8)
    qx, qy, qz, qw = a[:, 4], a[:, 5], a[:, 6], a[:, 7]
    yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy**2 + qz**2))
    return a[:, 0], np.stack([a[:, 1], a[:, 2], yaw], 1)
