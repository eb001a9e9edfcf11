"""Reading mesh files (STL, OBJ, PLY, DAE) into coloured parts, with clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rhaml_jax.errors import RhamlError

MESH_EXTENSIONS = (".stl", ".obj", ".ply", ".dae")


def _mesh_colors(mesh, fallback) -> np.ndarray:
    """(F, 3) face colours of a trimesh mesh, or `fallback` where the file has none."""
    n = len(mesh.faces)
    visual = mesh.visual
    try:
        if visual.kind == "face" or visual.kind == "vertex":
            return np.asarray(visual.face_colors[:, :3], np.float32) / 255.0
        material = getattr(visual, "material", None)
        if material is not None:
            color = getattr(material, "main_color", None)
            if color is None and hasattr(material, "diffuse"):
                color = material.diffuse
            if color is not None:
                return np.broadcast_to(np.asarray(color[:3], np.float32) / 255.0, (n, 3)).copy()
    except Exception:  # unusual visuals (textures without images): use the fallback colour
        pass
    return np.broadcast_to(np.asarray(fallback, np.float32), (n, 3)).copy()


def load_mesh_parts(path: Path, color=None, default_color=(0.6, 0.6, 0.6)):
    """Reads a mesh file -> list of (vertices (V,3) f64, faces (F,3), face_colors (F,3)).

    `color`, when given, overrides the file's colours (a URDF material). Each geometry of a
    scene file (DAE) becomes its own part with the scene's transforms applied.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise RhamlError(f"{path}: mesh file not found")
    ext = path.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise RhamlError(f"{path}: unknown mesh extension {ext!r} (expected one of {', '.join(MESH_EXTENSIONS)})")
    try:
        # process=False: trimesh would otherwise silently drop faces with NaN vertices.
        loaded = trimesh.load(str(path), file_type=ext[1:], process=False)
    except Exception as e:  # trimesh raises many types for corrupt files
        raise RhamlError(f"{path}: cannot read mesh: {type(e).__name__}: {e}".splitlines()[0]) from None
    if isinstance(loaded, trimesh.Scene):
        meshes = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
    else:
        meshes = [loaded] if isinstance(loaded, trimesh.Trimesh) else []
    parts = []
    for m in meshes:
        if len(m.faces) == 0:
            continue
        if not np.all(np.isfinite(m.vertices)):
            raise RhamlError(f"{path}: the mesh has non-finite vertex coordinates (NaN or Inf)")
        m.merge_vertices()
        cols = np.broadcast_to(np.asarray(color, np.float32), (len(m.faces), 3)) if color is not None else _mesh_colors(m, default_color)
        parts.append((np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64), cols))
    if not parts:
        raise RhamlError(f"{path}: the mesh is empty (no faces)")
    return parts
