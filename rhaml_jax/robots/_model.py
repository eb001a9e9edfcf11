"""RobotModel: a coloured triangle mesh in the robot frame, plus what renderers need of it."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from rhaml_jax.errors import RhamlError

DEFAULT_COLOR = (0.6, 0.6, 0.6)
# A robot longer than this along its largest axis was almost certainly modelled in millimetres.
MM_SUSPECT_EXTENT_M = 20.0
PIONEER_LENGTH_M = 0.455  # the built-in Pioneer's length (robots.fingerprint: 45.5 x 38.1 x 23.7 cm)


@dataclasses.dataclass(frozen=True, eq=False)
class RobotModel:
    """A robot's visual mesh in its robot frame (REP 103: x forward, y left, z up; metres).

    Fields:
      name: human-readable name (built-in name or file stem).
      vertices: (V, 3) float32, metres; the lowest point is at z = 0 after `normalized()`.
      faces: (F, 3) int32 indices into `vertices`.
      face_colors: (F, 3) float32 RGB in [0, 1] (the part colours).
      face_parts: (F,) int32 index into `part_names`.
      part_names: names of the parts (URDF links' visuals, or primitives).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    face_colors: np.ndarray
    face_parts: np.ndarray
    part_names: tuple[str, ...]

    @classmethod
    def from_parts(cls, name: str, parts: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]) -> "RobotModel":
        """Joins parts [(part_name, vertices (V,3), faces (F,3), face_colors (F,3) or (3,))]."""
        verts, faces, colors, ids = [], [], [], []
        offset = 0
        for i, (_, v, f, c) in enumerate(parts):
            v = np.asarray(v, np.float64).reshape(-1, 3)
            f = np.asarray(f, np.int64).reshape(-1, 3)
            c = np.broadcast_to(np.asarray(c, np.float32).reshape(-1, 3), (len(f), 3))
            verts.append(v), faces.append(f + offset), colors.append(c), ids.append(np.full(len(f), i))
            offset += len(v)
        if not parts:
            raise RhamlError(f"{name}: the model has no visual geometry")
        return cls(
            name=name,
            vertices=np.concatenate(verts).astype(np.float32),
            faces=np.concatenate(faces).astype(np.int32),
            face_colors=np.concatenate(colors).astype(np.float32),
            face_parts=np.concatenate(ids).astype(np.int32),
            part_names=tuple(p[0] for p in parts),
        )

    # --- checks and normalisation ---------------------------------------------------------

    def validated(self, source: str) -> "RobotModel":
        """Raises a RhamlError naming `source` if the mesh is empty, non-finite or malformed."""
        if len(self.faces) == 0 or len(self.vertices) == 0:
            raise RhamlError(f"{source}: the mesh is empty (no faces)")
        if not np.all(np.isfinite(self.vertices)):
            raise RhamlError(f"{source}: the mesh has non-finite vertex coordinates (NaN or Inf)")
        if self.faces.min() < 0 or self.faces.max() >= len(self.vertices):
            raise RhamlError(f"{source}: face indices out of range 0..{len(self.vertices) - 1}")
        ext = self.extents
        if ext.max() <= 0:
            raise RhamlError(f"{source}: the mesh is degenerate (zero size)")
        if ext.max() > MM_SUSPECT_EXTENT_M:
            warnings.warn(
                f"{source}: the model is {ext.max():.1f} m long; its units are probably millimetres "
                "(scale it by 0.001, e.g. with scale=\"0.001 0.001 0.001\" in the URDF)",
                stacklevel=2,
            )
        return self

    def normalized(self) -> "RobotModel":
        """Shifted vertically so the lowest point is at z = 0 (x, y of base_link are kept)."""
        v = self.vertices.copy()
        v[:, 2] -= v[:, 2].min()
        return dataclasses.replace(self, vertices=v)

    # --- derived quantities -----------------------------------------------------------------

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner."""
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    @property
    def extents(self) -> np.ndarray:
        """(3,) size along x, y, z in metres."""
        b = self.bounds
        return b[1] - b[0]

    @property
    def world_scale(self) -> float:
        """The robot's planar length over the built-in Pioneer's, to two decimals: every distance of
        its world (training depths, scenario paths and rooms, the refiner's training noise) is
        DESIGN.md's Pioneer distance times this, so a small robot is seen at a Pioneer's pixel sizes
        (1 for the Pioneer; 0.39 for the 0.178 m TurtleBot3)."""
        return round(float(max(self.extents[0], self.extents[1])) / PIONEER_LENGTH_M, 2)

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit normals from the triangle winding (zero for zero-area faces).

        Recomputed from the geometry: mesh files may store zero or wrong normals.
        """
        tri = self.vertices[self.faces].astype(np.float64)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return (n / np.where(norm > 0, norm, 1.0)).astype(np.float32)

    @property
    def face_areas(self) -> np.ndarray:
        tri = self.vertices[self.faces].astype(np.float64)
        return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)

    def sample_surface(self, n: int, seed: int = 0) -> np.ndarray:
        """(n, 3) float32 points uniformly distributed over the surface (area-weighted)."""
        return self._sample(n, seed)[0].astype(np.float32)

    def _sample(self, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) float64 area-uniform surface points and (n,) the faces they lie on."""
        rng = np.random.default_rng(seed)
        area = self.face_areas
        if area.sum() <= 0:
            raise RhamlError(f"{self.name}: the mesh has zero surface area")
        idx = rng.choice(len(area), size=n, p=area / area.sum())
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        a, b, c = 1 - s, s * (1 - r2), s * r2
        tri = self.vertices[self.faces[idx]].astype(np.float64)
        return a[:, None] * tri[:, 0] + b[:, None] * tri[:, 1] + c[:, None] * tri[:, 2], idx

    def mirror_asymmetry(self, n: int = 20000, seed: int = 0) -> tuple[float, float]:
        """How far the model is from its left-right mirror image (y -> -y in the robot frame):
        (shape in metres, colour as a fraction), both about 0 for a symmetric robot.

        From two independent area-uniform draws P, Q of n surface points: shape = the 99th
        percentile of the distance from a mirrored point of P to the nearest point of Q, minus
        the same without mirroring (what sampling alone gives); colour = the fraction of
        mirrored points whose nearest point of Q has another face colour (any channel off by
        more than 0.1), minus the same without mirroring. Test-time mirroring of the zoom stage
        (`evaluate --zoom-mirror`) assumes both are small."""
        from scipy.spatial import cKDTree

        (p, fp), (q, fq) = self._sample(n, seed), self._sample(n, seed + 1)
        tree = cKDTree(q)
        d0, i0 = tree.query(p)
        d1, i1 = tree.query(p * np.array([1.0, -1.0, 1.0]))
        cp, cq = self.face_colors[fp], self.face_colors[fq]

        def recoloured(i):
            return float((np.abs(cp - cq[i]).max(1) > 0.1).mean())

        return float(np.quantile(d1, 0.99) - np.quantile(d0, 0.99)), recoloured(i1) - recoloured(i0)

    def to_trimesh(self):
        """A trimesh.Trimesh with the face colours (for export, ray casting and viewing)."""
        import trimesh

        rgba = np.concatenate([self.face_colors, np.ones((len(self.faces), 1), np.float32)], 1)
        return trimesh.Trimesh(
            self.vertices.astype(np.float64),
            self.faces,
            face_colors=(rgba * 255).round().astype(np.uint8),
            process=False,
        )

    def simplify(self, max_faces: int) -> "RobotModel":
        """A model of at most about `max_faces` faces that keeps the silhouette: vertices merged
        on a grid whose cell size is found by bisection, each cell keeping its outermost vertex,
        so no vertex leaves the bounding box and the outline moves by at most a cell
        (`robots._simplify`; quadric decimation was measured to destroy thin parts)."""
        from rhaml_jax.robots._simplify import simplify_model

        return simplify_model(self, max_faces)

    def describe(self) -> dict:
        """JSON-able summary (what `python -m rhaml_jax.info --robot` prints)."""
        b = self.bounds
        return {
            "name": self.name,
            "vertices": int(len(self.vertices)),
            "faces": int(len(self.faces)),
            "parts": list(self.part_names),
            "extents_m": [round(float(x), 5) for x in self.extents],
            "min_z": round(float(b[0, 2]), 6),
            "bounds_m": [[round(float(x), 5) for x in row] for row in b],
        }
