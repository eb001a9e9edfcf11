"""Rendering of a triangle mesh through a pinhole camera, in JAX (jit, vmap, grad).

- :func:`silhouette`: soft, differentiable silhouette (coverage in [0, 1]) whose limit for
  sharpness -> infinity is the hard silhouette.
- :func:`render`: hard z-buffer rasterizer: shaded RGB, visible mask, depth, face ids.
- :func:`silhouette_naive`: every pixel against every face (reference and benchmark only).

Conventions: the pose `T_cam_model` is a `jaxlie.SE3` taking model points to the OpenCV
optical frame (z forward, x right, y down), optionally with batch axes (...); `K` is the
(3, 3) intrinsic matrix of the full image (pixel centres at integer coordinates). With
`box` (..., 4) = (x0, y0, x1, y1) in full-image pixels (edges at pixel borders, as
`rhaml_jax.camera.crop_intrinsics`), the output is that crop resampled to width x height
(DeepIM zoom-in); without it, the full image of width x height. Batch axes of the pose and
of the box broadcast together.

The model is anything `as_mesh` accepts (a RobotModel, a trimesh, (vertices, faces) or a
Mesh); convert once with `as_mesh` when rendering in a loop.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax.camera import crop_intrinsics
from rhaml_jax.render import _checks
from rhaml_jax.render._geometry import ScreenFaces, screen_faces, transform_points
from rhaml_jax.render._mesh import Mesh, as_mesh
from rhaml_jax.render._naive import naive_coverage
from rhaml_jax.render._raster import RenderOutput, rasterize
from rhaml_jax.render._soft import coverage, coverage_autodiff
from rhaml_jax.render._tiles import chunk_size, layout

__all__ = ["RenderConfig", "RenderOutput", "Mesh", "as_mesh", "silhouette", "silhouette_naive", "render",
           "pairs_needed", "DEFAULT_LIGHT"]

DEFAULT_LIGHT = (-0.3, -0.6, -1.0)  # towards the light, camera frame: upper left, behind the camera


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """Static settings (hashable; a change recompiles).

    block: side (px) of the blocks each face's box is cut into (hard render);
    soft_block: the same for `silhouette` (and its XLA-autodiff VJP); soft_block_bwd: the same
    for the backward pass of its custom VJP. chunk_pixels: pixel tests per step of the pair loop.
    near: near clipping plane (m). cutoff: a face's soft edge fades out at cutoff / sharpness px.
    soft_cull: `silhouette` also skips a closed mesh's faces turned away from the camera (`Mesh.winding`;
    `render` always does, which changes nothing there). Half the (face, block) pairs, 1.8-2.2x faster
    at 64 px (`experiments/profile_ir.py --cull`), and the soft edge is
    then the front face's alone rather than the union of the front and back faces sharing it, so
    its 0.5 level sits nearer the hard edge; seams between front faces inside the silhouette are
    no longer filled by the faces behind them (a pixel centred on one reads 0.75).
    vjp: "custom" (nearest-edge VJP) or "autodiff" (XLA's reverse mode over `capacity` pairs,
    pairs beyond it dropped; a reference for tests and benchmarks) for `silhouette`.
    """

    block: int = 8
    soft_block: int = 8
    soft_block_bwd: int = 4
    chunk_pixels: int = 32768
    near: float = 0.01
    cutoff: float = 7.0
    vjp: str = "custom"
    capacity: int = 16384
    soft_cull: bool = False


def _prepare(model, T_cam_model, K, width, height, box):
    mesh = as_mesh(model)
    dt = mesh.vertices.dtype
    w, h = _checks.image_size(width, height)
    params = jnp.asarray(_checks.pose_params(T_cam_model), dt)
    K = jnp.asarray(_checks.intrinsics(K), dt)
    box = _checks.crop_box(box)
    if box is None:
        Ks = K
    else:
        Ks = crop_intrinsics(K, jnp.asarray(box, dt), w, h).astype(dt)  # (..., 3, 3)
    batch = jnp.broadcast_shapes(params.shape[:-1], Ks.shape[:-2])
    params = jnp.broadcast_to(params, batch + (7,)).reshape(-1, 7)
    Ks = jnp.broadcast_to(Ks, batch + (3, 3)).reshape(-1, 3, 3)
    return mesh, params, Ks, w, h, batch


def _screen(mesh: Mesh, params, K, near, cull: bool) -> ScreenFaces:
    """The mesh's faces on screen; `cull`: skip a closed mesh's back faces (`Mesh.winding`), only
    where the whole mesh lies beyond the near plane: a camera inside the surface, or a near plane
    cutting it open, sees back faces."""
    T = jaxlie.SE3(params)
    v = transform_points(T, mesh.vertices)
    winding = jnp.where(jnp.min(v[:, 2]) > near, mesh.winding, 0.0) if cull else 0.0
    return screen_faces(v, mesh.faces, K, near, winding)


@functools.partial(jax.jit, static_argnames=("width", "height", "config"))
def _silhouette(mesh, params, Ks, sharpness, width, height, config):
    blk, blk_b = config.soft_block, config.soft_block_bwd
    size, size_b = chunk_size(blk, config.chunk_pixels), chunk_size(blk_b, config.chunk_pixels)

    def one(p, K):
        sf = _screen(mesh, p, K, config.near, config.soft_cull)
        # The window margin only decides which pixels are visited (the taper makes the image
        # continuous across it): no gradient through it.
        margin = jax.lax.stop_gradient(config.cutoff / sharpness)
        lay = layout(sf, margin, width, height, blk)
        if config.vjp == "custom":
            lays = (lay, layout(sf, margin, width, height, blk_b))
            cov = coverage(sf.poly, sharpness, sf.orient, lays, width, height, (blk, blk_b), (size, size_b),
                           config.cutoff)
        else:
            cov = coverage_autodiff(sf.poly, sharpness, sf.orient, lay, width, height, blk, size, config.cutoff,
                                    config.capacity)
        return cov.reshape(height, width)

    return jax.vmap(one)(params, Ks)


def silhouette(model, T_cam_model: jaxlie.SE3, K, width: int, height: int, *, sharpness=2.0, box=None,
               config: RenderConfig = RenderConfig()) -> jax.Array:
    """Soft silhouette (..., height, width) in [0, 1], differentiable wrt pose, vertices, sharpness.

    sharpness (1/px): a face covers a pixel centre at signed distance s px (positive inside)
    with probability sigmoid(sharpness * s); the faces combine as a probabilistic union.
    """
    mesh, params, Ks, w, h, batch = _prepare(model, T_cam_model, K, width, height, box)
    k = jnp.asarray(_checks.positive_scalar("sharpness", sharpness), mesh.vertices.dtype)
    return _silhouette(mesh, params, Ks, k, w, h, config).reshape(batch + (h, w))


@functools.partial(jax.jit, static_argnames=("width", "height", "chunk", "near", "cutoff", "cull"))
def _naive(mesh, params, Ks, sharpness, width, height, chunk, near, cutoff, cull):
    def one(p, K):
        sf = _screen(mesh, p, K, near, cull)
        return naive_coverage(sf, sharpness, width, height, chunk, cutoff)

    return jax.vmap(one)(params, Ks)


def silhouette_naive(model, T_cam_model, K, width: int, height: int, *, sharpness=2.0, box=None,
                     config: RenderConfig = RenderConfig(), chunk: int = 128) -> jax.Array:
    """The same soft silhouette as `silhouette`, with every pixel against every face (no binning)
    and XLA's reverse mode: the baseline for benchmarks and a check of the binning."""
    mesh, params, Ks, w, h, batch = _prepare(model, T_cam_model, K, width, height, box)
    k = jnp.asarray(_checks.positive_scalar("sharpness", sharpness), mesh.vertices.dtype)
    return _naive(mesh, params, Ks, k, w, h, chunk, config.near, config.cutoff, config.soft_cull).reshape(batch + (h, w))


@functools.partial(jax.jit, static_argnames=("width", "height", "config"))
def _render(mesh, params, Ks, light_dir, ambient, diffuse, width, height, config):
    def one(p, K):
        sf = _screen(mesh, p, K, config.near, True)
        return rasterize(sf, mesh.face_colors, width, height, block=config.block, chunk_pixels=config.chunk_pixels,
                         light_dir=light_dir, ambient=ambient, diffuse=diffuse, near=config.near)

    return jax.vmap(one)(params, Ks)


def render(model, T_cam_model: jaxlie.SE3, K, width: int, height: int, *, box=None, light_dir=DEFAULT_LIGHT,
           ambient=0.35, diffuse=0.65, config: RenderConfig = RenderConfig()) -> RenderOutput:
    """Hard z-buffer render: RenderOutput of rgb (..., H, W, 3), mask (..., H, W), depth (..., H, W)
    (metres along the optical axis, 0 on background), face_id (..., H, W) (-1 on background) and
    pairs (...), the (face, block) pairs visited.

    Shading: face colour * (ambient + diffuse * max(0, n . l)), n the face normal turned towards
    the camera, l = light_dir (camera frame, towards the light, normalised). A closed mesh's back
    faces are skipped (`Mesh.winding`): the same image from about half the pairs.
    """
    mesh, params, Ks, w, h, batch = _prepare(model, T_cam_model, K, width, height, box)
    dt = mesh.vertices.dtype
    light = jnp.asarray(light_dir, dt)
    if _checks.concrete(light) and (light.shape != (3,) or not np.all(np.isfinite(light)) or not np.any(light)):
        from rhaml_jax.errors import RhamlError

        raise RhamlError(f"light_dir: expected a finite non-zero (3,) vector, got {np.asarray(light).tolist()}")
    out = _render(mesh, params, Ks, light, jnp.asarray(ambient, dt), jnp.asarray(diffuse, dt), w, h, config)
    return jax.tree_util.tree_map(lambda a: a.reshape(batch + a.shape[1:]), out)


@functools.partial(jax.jit, static_argnames=("width", "height", "block", "near", "cull"))
def _needed(mesh, params, Ks, margin, width, height, block, near, cull):
    def one(p, K):
        return layout(_screen(mesh, p, K, near, cull), margin, width, height, block).needed

    return jax.vmap(one)(params, Ks)


def pairs_needed(model, T_cam_model, K, width: int, height: int, *, box=None, sharpness=None,
                 config: RenderConfig = RenderConfig()) -> jax.Array:
    """(...,) (face, block) pairs a view visits: hard render (sharpness None) or soft silhouette.

    The work of a render is proportional to it (rounded up to whole chunks).
    """
    mesh, params, Ks, w, h, batch = _prepare(model, T_cam_model, K, width, height, box)
    if sharpness is None:
        margin, block, cull = 0.0, config.block, True
    else:
        margin, block = config.cutoff / float(_checks.positive_scalar("sharpness", sharpness)), config.soft_block
        cull = config.soft_cull
    out = _needed(mesh, params, Ks, jnp.asarray(margin, mesh.vertices.dtype), w, h, block, config.near, cull)
    return out.reshape(batch)
