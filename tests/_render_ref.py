"""Independent references for the renderer tests: trimesh ray casting (pixel-centre rays)."""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np
import trimesh

from rhaml_jax.camera import T_cam_robot


def raycast(vertices_cam, faces, K, width, height):
    """(mask (H, W) bool, depth (H, W) z in metres, 0 on background) by casting a ray from the
    camera centre through every pixel centre (restricted to the projected vertex box when the
    model is wholly in front of the camera)."""
    v = np.asarray(vertices_cam, np.float64)
    K = np.asarray(K, np.float64)
    x0, y0, x1, y1 = 0, 0, width - 1, height - 1
    if np.all(v[:, 2] > 1e-6):
        uv = (v @ K.T)[:, :2] / v[:, 2:3]
        x0, y0 = np.maximum(np.floor(uv.min(0)).astype(int) - 1, 0)
        x1 = min(int(np.ceil(uv[:, 0].max())) + 1, width - 1)
        y1 = min(int(np.ceil(uv[:, 1].max())) + 1, height - 1)
    mask = np.zeros((height, width), bool)
    depth = np.zeros((height, width))
    if x1 < x0 or y1 < y0:
        return mask, depth
    yy, xx = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
    pix = np.stack([xx.ravel(), yy.ravel(), np.ones(xx.size)], 1)
    dirs = pix @ np.linalg.inv(K).T
    mesh = trimesh.Trimesh(v, np.asarray(faces), process=False)
    locs, ray, _ = trimesh.ray.ray_triangle.RayMeshIntersector(mesh).intersects_location(
        np.zeros_like(dirs), dirs, multiple_hits=False
    )
    keep = locs[:, 2] > 0
    yi, xi = yy.ravel()[ray[keep]], xx.ravel()[ray[keep]]
    mask[yi, xi] = True
    depth[yi, xi] = locs[keep, 2]
    return mask, depth


def random_views(n, seed, depth=(1.5, 6.0)):
    """n random T_cam_model (batched jaxlie.SE3) of a robot on the ground in front of the
    default camera, with the camera height noise of the training data."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(*depth, n)
    y = rng.uniform(-0.35, 0.35, n) * x
    psi = rng.uniform(-np.pi, np.pi, n)
    h = 0.30 + 0.05 * rng.standard_normal(n)
    T_obs = jaxlie.SE3.from_rotation_and_translation(
        jaxlie.SO3.from_z_radians(jnp.asarray(psi, jnp.float32)),
        jnp.asarray(np.stack([x, y, np.zeros(n)], 1), jnp.float32),
    )
    return T_cam_robot(jnp.asarray(h, jnp.float32)) @ T_obs


def iou(a, b):
    return np.logical_and(a, b).sum() / max(np.logical_or(a, b).sum(), 1)
