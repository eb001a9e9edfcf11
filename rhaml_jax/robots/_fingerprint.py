"""Robot fingerprints: which robot a checkpoint was made for, from its geometry alone.

Networks learn one robot's shape and size (the zoom stage's crop is sized to its length, AMLNet
reads its range from its apparent size), so running them on another robot gives confident
garbage. Every checkpoint stores the fingerprint of its robot, and loading compares it with the
data set's model. Colours are left out on purpose: a repainted robot is the same robot, and the
networks must cope with its new paint.

Two fingerprints are the same robot when their extents agree within 2 % (and 3 mm) on every axis
and their surface areas within 5 %: loose enough for the same CAD model written to a BOP ply in
millimetres and read back (tested), tight enough to tell a Pioneer (0.46 m
long) from a TurtleBot3 (0.14 m) or a robot scaled by a tenth. `geometry_hash` (the model's
vertices quantised to 1 mm) is reported so that two users can tell whether they hold the very
same mesh; it is not what decides.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from rhaml_jax.errors import RhamlError
from rhaml_jax.robots._model import RobotModel

EXTENT_RTOL, EXTENT_ATOL_M, AREA_RTOL = 0.02, 3e-3, 0.05


@dataclasses.dataclass(frozen=True)
class RobotFingerprint:
    name: str
    """the robot's name (built-in name, file stem; a BOP set's model is called obj_000001)"""
    extents_m: tuple[float, float, float]
    """size along x, y, z in the robot frame (m)"""
    area_m2: float | None
    """surface area of the visual mesh (m^2); None in checkpoints from before fingerprints, which
    stored the name and extents only"""
    geometry_hash: str = ""
    """sha1 (16 hex digits) of the unique vertices quantised to 1 mm, sorted ("" if unknown)"""

    def to_dict(self) -> dict:
        return {"name": self.name, "extents_m": list(self.extents_m), "area_m2": self.area_m2,
                "geometry_hash": self.geometry_hash}

    @classmethod
    def from_dict(cls, d: dict, where: str = "robot fingerprint") -> "RobotFingerprint":
        try:
            ext = tuple(float(e) for e in d["extents_m"])
            if len(ext) != 3:
                raise ValueError
            area = d.get("area_m2")
            return cls(str(d["name"]), ext, None if area is None else float(area), str(d.get("geometry_hash", "")))
        except (KeyError, TypeError, ValueError):
            raise RhamlError(f"{where}: not a robot fingerprint (needs name and extents_m [3]): {d!r}") from None

    def same_robot(self, other: "RobotFingerprint") -> bool:
        a, b = np.asarray(self.extents_m), np.asarray(other.extents_m)
        ext_ok = bool(np.all(np.abs(a - b) <= EXTENT_ATOL_M + EXTENT_RTOL * np.maximum(a, b)))
        if self.area_m2 is None or other.area_m2 is None:
            return ext_ok
        return ext_ok and abs(self.area_m2 - other.area_m2) <= AREA_RTOL * max(self.area_m2, other.area_m2)

    def describe(self) -> str:
        x, y, z = (100 * e for e in self.extents_m)
        area = "" if self.area_m2 is None else f", {self.area_m2:.3f} m^2"
        geom = f", geometry {self.geometry_hash}" if self.geometry_hash else ""
        return f"{self.name!r} ({x:.1f} x {y:.1f} x {z:.1f} cm{area}{geom})"


def fingerprint(model: RobotModel) -> RobotFingerprint:
    """The fingerprint of a robot model (its geometry only)."""
    q = np.unique(np.round(np.asarray(model.vertices, np.float64) * 1000.0).astype(np.int64), axis=0)
    digest = hashlib.sha1(np.ascontiguousarray(q).tobytes()).hexdigest()[:16]
    ext = tuple(round(float(e), 5) for e in model.extents)
    return RobotFingerprint(model.name, ext, round(float(model.face_areas.sum()), 6), digest)


def require_same_robot(mine: RobotFingerprint, theirs: RobotFingerprint, message: str) -> None:
    """Raises RhamlError(message with {mine} and {theirs} filled by the robots' descriptions)
    unless they are the same robot (`RobotFingerprint.same_robot`): every robot check's one rule."""
    if not mine.same_robot(theirs):
        raise RhamlError(message.format(mine=mine.describe(), theirs=theirs.describe()))


def check_same_robot(stored: dict | None, model: RobotModel, what: str, where: str) -> None:
    """Raises RhamlError naming both robots when the checkpoint's stored fingerprint (`stored`,
    from its meta; None for a checkpoint from before fingerprints, which is let through) is not
    the robot `model` (named by `where`, e.g. the data set's model file)."""
    if stored is None:
        return
    require_same_robot(RobotFingerprint.from_dict(stored, f"{what}: its robot fingerprint"), fingerprint(model),
                       f"{what} was made for robot {{mine}}, but {where} is robot {{theirs}}: train networks for this "
                       "robot (python -m rhaml_jax.fit), or pass --allow-other-robot for a deliberate transfer test")
