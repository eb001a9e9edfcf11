"""Robot models: the built-in Pioneer-3DX-like model, URDFs and mesh files.

`load_robot("pioneer3dx")` or `load_robot("path/to/robot.urdf" | "mesh.stl|obj|ply|dae")`
gives a RobotModel in the robot frame (lowest point at z = 0).
"""

from __future__ import annotations

import functools
from pathlib import Path

from rhaml_jax.errors import RhamlError
from rhaml_jax.robots._meshio import MESH_EXTENSIONS, load_mesh_parts
from rhaml_jax.robots._fingerprint import RobotFingerprint, check_same_robot, fingerprint, require_same_robot
from rhaml_jax.robots._model import RobotModel
from rhaml_jax.robots._pioneer import BUILTIN
from rhaml_jax.robots._urdf import load_urdf

from rhaml_jax.robots._silhouette import silhouette_iou

__all__ = ["RobotModel", "RobotFingerprint", "load_robot", "load_mesh_parts", "silhouette_iou", "fingerprint", "check_same_robot", "require_same_robot",
           "BUILTIN_ROBOTS"]

BUILTIN_ROBOTS = tuple(BUILTIN)


@functools.lru_cache(maxsize=8)
def _load(spec: str, max_faces: int | None) -> RobotModel:
    if spec in BUILTIN:
        model = BUILTIN[spec]()
    else:
        path = Path(spec)
        ext = path.suffix.lower()
        if ext in (".urdf", ".xacro"):
            model = load_urdf(path)
        elif ext in MESH_EXTENSIONS:
            parts = [(path.stem if i == 0 else f"{path.stem}_{i}", v, f, c) for i, (v, f, c) in enumerate(load_mesh_parts(path))]
            model = RobotModel.from_parts(path.stem, parts)
        elif not path.exists():
            raise RhamlError(f"--robot {spec!r}: neither a built-in robot ({', '.join(BUILTIN)}) nor an existing file")
        else:
            raise RhamlError(f"{path}: unknown robot file extension {ext!r} (expected .urdf or {', '.join(MESH_EXTENSIONS)})")
        if not path.exists():
            raise RhamlError(f"{path}: file not found")
        model = model.validated(str(path)).normalized()
    if max_faces is not None:
        model = model.simplify(max_faces)
    return model


def load_robot(spec: str, max_faces: int | None = None) -> RobotModel:
    """A built-in robot name or a URDF / mesh path -> RobotModel (cached per spec).

    `max_faces` simplifies the model to about that many faces (silhouette-preserving).
    """
    if max_faces is not None and max_faces <= 0:
        raise RhamlError(f"max_faces must be positive, got {max_faces}")
    return _load(str(spec), max_faces)
