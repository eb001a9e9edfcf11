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
    face_colors: (F, 3) float RGB in [0, 1].
    """

    vertices: jnp.ndarray
    faces: jnp.ndarray
    face_colors: jnp.ndarray


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
    return Mesh(jnp.asarray(v, dtype), jnp.asarray(f, jnp.int32), jnp.asarray(c, dtype))


def _is_tracer(a) -> bool:
    import jax

    return isinstance(a, jax.core.Tracer)
