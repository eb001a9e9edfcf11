"""Pinhole camera: intrinsics, the camera-on-robot extrinsic, projection and crops.

Optical frame (OpenCV): z forward, x right, y down; pixel centres at integer coordinates.
The observer's camera sits at (0, 0, h) in its robot frame and looks along +x with no tilt.
Default camera (DESIGN.md section 2): 640 x 480, fx = fy = 400, cx = 320, cy = 240, h = 0.30 m.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax.errors import RhamlError

__all__ = [
    "Camera",
    "DEFAULT_CAMERA",
    "NOMINAL_HEIGHT_M",
    "R_ROBOT_OPTICAL",
    "T_cam_robot",
    "project",
    "backproject",
    "resize_intrinsics",
    "crop_intrinsics",
]

NOMINAL_HEIGHT_M = 0.30

# Columns are the optical axes (x right, y down, z forward) expressed in the robot frame
# (x forward, y left, z up).
R_ROBOT_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclasses.dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics of an image of `width` x `height` pixels.

    Fields: fx, fy (focal lengths, px), cx, cy (principal point, px), width, height (px).
    """

    fx: float = 400.0
    fy: float = 400.0
    cx: float = 320.0
    cy: float = 240.0
    width: int = 640
    height: int = 480

    def __post_init__(self):
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(vals)) or self.fx <= 0 or self.fy <= 0:
            raise RhamlError(f"camera: focal lengths must be finite and positive, got {vals}")
        if self.width <= 0 or self.height <= 0:
            raise RhamlError(f"camera: image size must be positive, got {self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_K(cls, K, width: int, height: int) -> "Camera":
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise RhamlError(f"cam_K: expected a 3x3 matrix, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 or np.any(np.abs(K[2] - [0, 0, 1]) > 1e-9):
            raise RhamlError(f"cam_K: not a pinhole matrix without skew: {K.tolist()}")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for the image resized to width x height (see resize_intrinsics)."""
        K = resize_intrinsics(self.K, (self.width, self.height), (width, height))
        return Camera.from_K(K, width, height)


DEFAULT_CAMERA = Camera()


def T_cam_robot(height_m=NOMINAL_HEIGHT_M) -> jaxlie.SE3:
    """SE3 taking points in the observer's robot frame to its camera's optical frame.

    `height_m` may be an array (...,) for a batch of camera heights.
    """
    h = jnp.asarray(height_m, dtype=jnp.float32)
    R = jnp.broadcast_to(jnp.asarray(R_ROBOT_OPTICAL.T, dtype=jnp.float32), h.shape + (3, 3))
    # p_cam = R^T (p_robot - (0, 0, h)) = R^T p_robot - R^T (0, 0, h)
    t = -jnp.einsum("...ij,...j->...i", R, jnp.stack([jnp.zeros_like(h), jnp.zeros_like(h), h], -1))
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(R), t)


def project(K: jnp.ndarray, points_cam: jnp.ndarray, min_depth: float = 1e-6):
    """Projects (..., 3) optical-frame points through K (3, 3).

    Returns (uv (..., 2) in pixels, depth (...,)). Depth is clamped to `min_depth` in the
    division only, so points at or behind the camera give finite (meaningless) uv: callers
    mask them with `depth > 0`.
    """
    K = jnp.asarray(K)
    z = points_cam[..., 2]
    z_safe = jnp.maximum(z, min_depth)  # guard: no division by zero / sign flip behind camera
    u = K[0, 0] * points_cam[..., 0] / z_safe + K[0, 2]
    v = K[1, 1] * points_cam[..., 1] / z_safe + K[1, 2]
    return jnp.stack([u, v], axis=-1), z


def backproject(K: jnp.ndarray, uv: jnp.ndarray, depth: jnp.ndarray) -> jnp.ndarray:
    """Pixels (..., 2) at depth (...,) -> optical-frame points (..., 3)."""
    K = jnp.asarray(K)
    x = (uv[..., 0] - K[0, 2]) / K[0, 0] * depth
    y = (uv[..., 1] - K[1, 2]) / K[1, 1] * depth
    return jnp.stack([x, y, depth], axis=-1)


def _affine_intrinsics(K, sx, sy, ox, oy):
    """K after the pixel map u' = (u - ox + 0.5) * sx - 0.5 (pixel centres at integers)."""
    K = jnp.asarray(K)
    fx, fy = K[..., 0, 0] * sx, K[..., 1, 1] * sy
    cx = (K[..., 0, 2] - ox + 0.5) * sx - 0.5
    cy = (K[..., 1, 2] - oy + 0.5) * sy - 0.5
    zero, one = jnp.zeros_like(fx), jnp.ones_like(fx)
    return jnp.stack(
        [jnp.stack([fx, zero, cx], -1), jnp.stack([zero, fy, cy], -1), jnp.stack([zero, zero, one], -1)], -2
    )


def resize_intrinsics(K, old_size: tuple[int, int], new_size: tuple[int, int]) -> jnp.ndarray:
    """K of an image resized from old_size (w, h) to new_size (w, h), as cv2.resize does."""
    (w0, h0), (w1, h1) = old_size, new_size
    if min(w0, h0, w1, h1) <= 0:
        raise RhamlError(f"resize_intrinsics: sizes must be positive, got {old_size} -> {new_size}")
    return _affine_intrinsics(K, w1 / w0, h1 / h0, 0.0, 0.0)


def crop_intrinsics(K, box, out_w: int, out_h: int) -> jnp.ndarray:
    """K of the crop box (..., 4) = (x0, y0, x1, y1) resampled to out_w x out_h pixels.

    The box is given in full-image pixel coordinates with edges at pixel borders: the full
    image is (-0.5, -0.5, W - 0.5, H - 0.5). Traceable; batched over the box's leading axes.
    """
    box = jnp.asarray(box)
    x0, y0, x1, y1 = box[..., 0], box[..., 1], box[..., 2], box[..., 3]
    sx = out_w / jnp.maximum(x1 - x0, 1e-6)  # guard: a degenerate box gives a huge, finite zoom
    sy = out_h / jnp.maximum(y1 - y0, 1e-6)
    return _affine_intrinsics(K, sx, sy, x0 + 0.5, y0 + 0.5)
