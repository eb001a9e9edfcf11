"""Per-face screen-space data: camera transform, near-plane clipping, projection, depth planes.

Triangles are clipped against the plane z = near in the camera frame, so a model partly
behind the camera is drawn correctly without projecting points with z <= 0. A clipped
triangle is a convex polygon of 3 or 4 vertices; it is stored with 4 vertices, a triangle
repeating its last vertex (a zero-length edge, harmless in every test below).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

# A face whose projected area is below this (px^2) covers no pixel centre in practice and has
# no well-defined orientation: it is dropped (edge-on and zero-area faces).
MIN_AREA_PX2 = 1e-6
# Projected coordinates are clamped to this range (px) before any integer conversion.
COORD_LIMIT = 1e6


class ScreenFaces(NamedTuple):
    """Screen-space description of F faces for one camera (all arrays lead with F).

    poly: (F, 4, 2) clipped polygon in pixels (x right, y down), vertex 3 = vertex 2 for
        triangles. orient: (F,) +1 or -1, sign of the polygon's signed area (0 if invalid).
    valid: (F,) bool, the face has a visible, non-degenerate part in front of `near`.
    inv_depth: (F, 3) (a, b, c) with 1/z = a u + b v + c on the face's plane (pixels u, v).
    normal: (F, 3) unit normal in the camera frame, turned towards the camera.
    lo, hi: (F, 2) bounding box of poly in pixels.
    """

    poly: jnp.ndarray
    orient: jnp.ndarray
    valid: jnp.ndarray
    inv_depth: jnp.ndarray
    normal: jnp.ndarray
    lo: jnp.ndarray
    hi: jnp.ndarray


def _clip_near(tri: jnp.ndarray, near: float):
    """(F, 3, 3) camera-frame triangles -> (F, 4, 3) polygon of their part with z >= near, (F,) count.

    Written vertex by vertex with selects and explicit sums (no reductions over small axes: on
    XLA's CPU backend those ran 10-100x slower than the same sums written as adds).
    """
    v = [tri[:, i] for i in range(3)]  # (F, 3) each
    ins = [vi[:, 2] >= near for vi in v]
    slots, ok = [], []
    for i in range(3):  # Sutherland-Hodgman slots in order: a0, i01, a1, i12, a2, i20
        a, b = v[i], v[(i + 1) % 3]
        cross = ins[i] != ins[(i + 1) % 3]
        # Guard: den is only used where the edge crosses the plane (den != 0 there); elsewhere
        # a dummy 1 avoids 0/0 whose NaN would leak into gradients through jnp.where.
        den = jnp.where(cross, b[:, 2] - a[:, 2], 1.0)
        t = jnp.clip((near - a[:, 2]) / den, 0.0, 1.0)
        ip = a + t[:, None] * (b - a)
        ip = jnp.concatenate([ip[:, :2], jnp.where(cross, near, ip[:, 2])[:, None]], 1)
        slots += [a, ip]
        ok += [ins[i], cross]
    rank, n = [], jnp.zeros(tri.shape[0], jnp.int32)
    for o in ok:
        n = n + o.astype(jnp.int32)
        rank.append(n - 1)  # output position of each kept slot
    zero = jnp.zeros_like(v[0])
    poly = []
    for k in range(4):
        out = zero
        for sl, o, r in zip(slots, ok, rank):
            out = jnp.where((o & (r == k))[:, None], sl, out)
        poly.append(out)
    poly[3] = jnp.where((n == 4)[:, None], poly[3], poly[2])  # n is 0, 3 or 4
    return jnp.stack(poly, 1), n


def screen_faces(vertices_cam: jnp.ndarray, faces: jnp.ndarray, K: jnp.ndarray, near: float, cull=0.0) -> ScreenFaces:
    """vertices_cam (V, 3) in the optical frame, faces (F, 3), K (3, 3) -> ScreenFaces. cull (): a
    closed mesh's `Mesh.winding` (+1 or -1) marks the faces turned away from the camera not valid
    (skipped); 0 keeps them."""
    tri = vertices_cam[faces]  # (F, 3, 3)
    poly3, n = _clip_near(tri, near)
    has = n >= 3
    # Guard: faces wholly behind `near` get a dummy point at z = 1 so the division stays finite.
    p = jnp.where(has[:, None, None], poly3, jnp.array([0.0, 0.0, 1.0], tri.dtype))
    zs = jnp.maximum(p[..., 2], near)
    uv = jnp.stack(
        [(K[0, 0] * p[..., 0] + K[0, 1] * p[..., 1]) / zs + K[0, 2], K[1, 1] * p[..., 1] / zs + K[1, 2]], -1
    )
    uv = jnp.clip(uv, -COORD_LIMIT, COORD_LIMIT)
    x, y = [uv[:, i, 0] for i in range(4)], [uv[:, i, 1] for i in range(4)]
    # twice the signed area
    area2 = sum(x[i] * y[(i + 1) % 4] - x[(i + 1) % 4] * y[i] for i in range(4))
    valid = has & (jnp.abs(area2) > 2 * MIN_AREA_PX2)

    # Plane of the (unclipped) triangle: n.P = d; a ray P = z r with r = K^-1 [u, v, 1] hits it
    # at 1/z = (n . r) / d, affine in (u, v).
    nrm = jnp.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nlen = jnp.sqrt(nrm[:, 0] ** 2 + nrm[:, 1] ** 2 + nrm[:, 2] ** 2)
    nrm = nrm / jnp.maximum(nlen, 1e-30)[:, None]  # guard: zero-area 3D faces (already invalid)
    d = nrm[:, 0] * tri[:, 0, 0] + nrm[:, 1] * tri[:, 0, 1] + nrm[:, 2] * tri[:, 0, 2]
    # d < 0: the face's wound normal points towards the camera (it sees the side the winding calls outside)
    valid = valid & (jnp.abs(d) > 1e-9) & (nlen > 0) & (cull * d <= 0)
    d_safe = jnp.where(jnp.abs(d) > 1e-9, d, 1.0)  # guard: plane through the camera centre
    Kinv = jnp.linalg.inv(K)
    inv_depth = (nrm @ Kinv) / d_safe[:, None]  # (n^T K^-1) [u, v, 1] / d
    normal = -jnp.sign(d_safe)[:, None] * nrm  # towards the camera (the camera is at the origin)

    lo = jnp.stack([jnp.minimum(jnp.minimum(c[0], c[1]), jnp.minimum(c[2], c[3])) for c in (x, y)], -1)
    hi = jnp.stack([jnp.maximum(jnp.maximum(c[0], c[1]), jnp.maximum(c[2], c[3])) for c in (x, y)], -1)
    orient = jnp.where(valid, jnp.sign(area2), 0.0)
    return ScreenFaces(uv, orient, valid, inv_depth, normal, lo, hi)


def transform_points(T, points: jnp.ndarray) -> jnp.ndarray:
    """jaxlie SE3 (unbatched) applied to (V, 3) points."""
    R = T.rotation().as_matrix()
    t = T.translation()
    # Written as products and adds: XLA's CPU dot is slow on a (V, 3) x (3, 3) product.
    return sum(points[:, i:i + 1] * R[:, i][None, :] for i in range(3)) + t
