"""A host-side reference silhouette (OpenCV polygon fill), independent of the JAX renderer.

Used to measure what simplification does to a model's outline; every triangle must lie in
front of the camera (the views used here keep the robot at least `near` ahead).
"""

from __future__ import annotations

import cv2
import numpy as np

from rhaml_jax.errors import RhamlError

_SHIFT = 4  # fixed-point sub-pixel bits for cv2.fillPoly


def reference_silhouette(vertices_cam: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int, near: float = 1e-3) -> np.ndarray:
    """(H, W) bool: pixels whose centre any projected triangle covers.

    vertices_cam: (V, 3) in the camera's optical frame; K: (3, 3).
    """
    v = np.asarray(vertices_cam, np.float64)
    if np.any(v[:, 2] <= near):
        raise RhamlError("reference_silhouette: part of the model is behind the camera")
    uv = (v[:, :2] / v[:, 2:3]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    pts = np.round(uv[faces] * (1 << _SHIFT)).astype(np.int32)  # (F, 3, 2)
    mask = np.zeros((height, width), np.uint8)
    cv2.fillPoly(mask, list(pts), 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return mask.astype(bool)


def random_views(n: int, seed: int = 0, depth=(1.5, 6.0)):
    """n random observer-frame poses (x, y, psi) of a robot in view of the default camera."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(*depth, n)
    y = rng.uniform(-0.5, 0.5, n) * x * 0.8 * (320 / 400)
    psi = rng.uniform(-np.pi, np.pi, n)
    return np.stack([x, y, psi], 1)


def silhouette_iou(model_a, model_b, n_views: int = 50, seed: int = 0) -> np.ndarray:
    """(n_views,) IoU of the two models' silhouettes over random views of the default camera."""
    from rhaml_jax.camera import DEFAULT_CAMERA, NOMINAL_HEIGHT_M, R_ROBOT_OPTICAL

    cam = DEFAULT_CAMERA
    out = []
    for x, y, psi in random_views(n_views, seed):
        c, s = np.cos(psi), np.sin(psi)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        masks = []
        for m in (model_a, model_b):
            p_obs = m.vertices @ R.T + [x, y, 0.0]
            p_cam = (p_obs - [0, 0, NOMINAL_HEIGHT_M]) @ R_ROBOT_OPTICAL
            masks.append(reference_silhouette(p_cam, m.faces, cam.K, cam.width, cam.height))
        inter, union = np.logical_and(*masks).sum(), np.logical_or(*masks).sum()
        out.append(inter / max(union, 1))
    return np.asarray(out)
