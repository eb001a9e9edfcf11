"""The renderer's view of a model: a pytree of device arrays, checked once at the boundary."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from rhaml_jax.errors import RhamlError, check_finite, check_shape

DEFAULT_COLOR = (0.6, 0.6, 0.6)


class Mesh(NamedTuple):
    """Triangle mesh in its model frame (metres).

    vertices: (V, 3) float; faces: (F, 3) int32 indices into vertices;
    face_colors: (F, 3) float RGB in [0, 1]; winding: () +1 if the surface is closed with its
    faces wound counter-clockwise seen from outside, -1 if closed and wound the other way, 0
    otherwise (`closed_winding`). Where it is not 0 the renderers skip the faces turned away from
    the camera: from outside a closed surface the nearest face on every ray faces the camera, so
    the hard render is unchanged (and `silhouette` culls only if asked, `RenderConfig.soft_cull`).
    """

    vertices: jnp.ndarray
    faces: jnp.ndarray
    face_colors: jnp.ndarray
    winding: jnp.ndarray = np.float32(0.0)


def closed_winding(vertices: np.ndarray, faces: np.ndarray) -> float:
    """`Mesh.winding` of a mesh (host-side NumPy): closed means every directed edge (a, b) of a face
    occurs exactly once and its reverse (b, a) exactly once (each edge shared by two faces wound
    alike); the sign is that of the enclosed volume. Faces of zero area count as faces."""
    f = np.asarray(faces, np.int64)
    n = int(np.asarray(vertices).shape[0])
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])  # (3F, 2) directed edges
    fwd = e[:, 0] * n + e[:, 1]
    rev = e[:, 1] * n + e[:, 0]
    keys, counts = np.unique(fwd, return_counts=True)
    if np.any(counts != 1) or np.any(e[:, 0] == e[:, 1]) or not np.all(np.isin(rev, keys)):
        return 0.0
    v = np.asarray(vertices, np.float64)[f]  # (F, 3, 3)
    volume = np.einsum("fi,fi->", v[:, 0], np.cross(v[:, 1], v[:, 2])) / 6.0
    return 0.0 if volume == 0 else float(np.sign(volume))


def as_mesh(model, dtype=jnp.float32) -> Mesh:
    """A Mesh (dtype `dtype`) from a RobotModel, a trimesh.Trimesh or a (vertices, faces[, colors])
    tuple; a Mesh is returned as it is (it was checked when made).

    Raises RhamlError naming the field at fault (empty model, bad shape, bad index, NaN).
    """
    if isinstance(model, Mesh):
        return model
    if isinstance(model, tuple) and len(model) in (2, 3):
        v, f = model[0], model[1]
        c = model[2] if len(model) == 3 else None
    elif hasattr(model, "vertices") and hasattr(model, "faces"):
        v, f = model.vertices, model.faces
        c = getattr(model, "face_colors", None)
        if c is not None and np.asarray(c).dtype == np.uint8:  # trimesh: (F, 4) uint8 RGBA
            c = np.asarray(c)[:, :3] / 255.0
    else:
        raise RhamlError(f"model: expected a Mesh, RobotModel, trimesh or (vertices, faces), got {type(model).__name__}")
    if any(_is_tracer(a) for a in (v, f, c)):
        # Inside someone's jit/vmap: shapes were checked by the caller's first concrete call.
        c = jnp.broadcast_to(jnp.asarray(DEFAULT_COLOR, dtype), (jnp.shape(f)[0], 3)) if c is None else c
        return Mesh(jnp.asarray(v, dtype), jnp.asarray(f, jnp.int32), jnp.asarray(c, dtype))
    v = np.asarray(v)
    f = np.asarray(f)
    check_shape("model.vertices", v, (None, 3))
    check_shape("model.faces", f, (None, 3))
    if v.shape[0] == 0 or f.shape[0] == 0:
        raise RhamlError(f"model: empty mesh ({v.shape[0]} vertices, {f.shape[0]} faces)")
    check_finite("model.vertices", v)
    if not np.issubdtype(f.dtype, np.integer) or f.min() < 0 or f.max() >= v.shape[0]:
        raise RhamlError(f"model.faces: indices must be integers in [0, {v.shape[0]}), got range [{f.min()}, {f.max()}]")
    if c is None:
        c = np.broadcast_to(np.asarray(DEFAULT_COLOR), (f.shape[0], 3))
    c = np.asarray(c)
    check_shape("model.face_colors", c, (f.shape[0], 3))
    check_finite("model.face_colors", c)
    return Mesh(jnp.asarray(v, dtype), jnp.asarray(f, jnp.int32), jnp.asarray(c, dtype),
                jnp.asarray(closed_winding(v, f), dtype))


def _is_tracer(a) -> bool:
    import jax

    return isinstance(a, jax.core.Tracer)
