"""Planar and spatial poses in the robot frame, and BOP's model-to-camera convention.

Robot frame (REP 103): x forward, y left, z up, origin on the ground under base_link.
A mutual-localization result is the observed robot's pose in the observer's robot frame,
either SE(2) as an array (..., 3) = (x, y, psi) or SE(3) (jaxlie) with z = roll = pitch = 0.
All functions broadcast over leading axes and are safe under jit, vmap and grad.
"""

from __future__ import annotations

import jax.numpy as jnp
import jaxlie
import numpy as np

from rhaml_jax import camera as _camera
from rhaml_jax.planar import wrap_angle  # re-exported: the one definition lives in rhaml_jax.planar

__all__ = [
    "wrap_angle",
    "se2_from_xypsi",
    "xypsi_from_se2",
    "se3_from_xypsi",
    "xypsi_from_se3",
    "roll_pitch_yaw",
    "bop_from_pose",
    "pose_from_bop",
]


def se2_from_xypsi(xypsi: jnp.ndarray) -> jaxlie.SE2:
    """(..., 3) (x, y, psi) -> SE2 with batch axes (...)."""
    xypsi = jnp.asarray(xypsi)
    return jaxlie.SE2.from_xy_theta(xypsi[..., 0], xypsi[..., 1], xypsi[..., 2])


def xypsi_from_se2(T: jaxlie.SE2) -> jnp.ndarray:
    """SE2 -> (..., 3) (x, y, psi), psi in (-pi, pi]."""
    xy = T.translation()
    psi = T.rotation().as_radians()
    return jnp.concatenate([xy, psi[..., None]], axis=-1)


def se3_from_xypsi(xypsi: jnp.ndarray, z: jnp.ndarray | float = 0.0) -> jaxlie.SE3:
    """(..., 3) (x, y, psi) -> SE3 on the ground plane (roll = pitch = 0, height z)."""
    xypsi = jnp.asarray(xypsi)
    rot = jaxlie.SO3.from_z_radians(xypsi[..., 2])
    t = jnp.stack([xypsi[..., 0], xypsi[..., 1], jnp.broadcast_to(z, xypsi[..., 0].shape)], -1)
    return jaxlie.SE3.from_rotation_and_translation(rot, t)


def roll_pitch_yaw(T: jaxlie.SE3) -> jnp.ndarray:
    """(..., 3) ZYX Euler angles (roll, pitch, yaw) of an SE3's rotation.

    Pitch comes from atan2 of the matrix (not arcsin) so its gradient stays finite at
    +-90 degrees.
    """
    R = T.rotation().as_matrix()
    roll = jnp.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = jnp.arctan2(-R[..., 2, 0], jnp.hypot(R[..., 0, 0], R[..., 1, 0]))
    yaw = jnp.arctan2(R[..., 1, 0], R[..., 0, 0])
    return jnp.stack([roll, pitch, yaw], axis=-1)


def xypsi_from_se3(T: jaxlie.SE3) -> jnp.ndarray:
    """SE3 -> (..., 3) planar projection (x, y, yaw); z, roll and pitch are dropped."""
    t = T.translation()
    R = T.rotation().as_matrix()
    yaw = jnp.arctan2(R[..., 1, 0], R[..., 0, 0])
    return jnp.concatenate([t[..., :2], yaw[..., None]], axis=-1)


# BOP stores the model-to-camera transform with translations in millimetres. The world of our
# data sets is the observer's robot frame, so T_cam_model = T_cam_observer @ T_observer_model.


def bop_from_pose(T_obs_model: jaxlie.SE3, camera_height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Observer-frame pose of the observed robot -> BOP (cam_R_m2c (9,), cam_t_m2c (3,) mm)."""
    T = _camera.T_cam_robot(camera_height_m) @ T_obs_model
    R = np.asarray(T.rotation().as_matrix(), dtype=np.float64)
    t = np.asarray(T.translation(), dtype=np.float64) * 1000.0
    return R.reshape(9), t


def pose_from_bop(cam_R_m2c, cam_t_m2c, camera_height_m: float) -> jaxlie.SE3:
    """BOP cam_R_m2c (9,) or (3, 3) and cam_t_m2c (3,) mm -> observer-frame SE3 of the model."""
    R = jnp.asarray(cam_R_m2c, dtype=jnp.float32).reshape(3, 3)
    t = jnp.asarray(cam_t_m2c, dtype=jnp.float32).reshape(3) / 1000.0
    T_cam_model = jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(R), t)
    return _camera.T_cam_robot(camera_height_m).inverse() @ T_cam_model
