"""A URDF reader for visual geometry: links, fixed-pose joints, meshes and primitives.

Joints are taken at their zero position (the robot as described). `package://NAME/rest`
paths resolve against the folders above the URDF (the package root is normally the URDF's
parent's parent), so a description copied out of its ROS workspace still loads.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from rhaml_jax.errors import RhamlError
from rhaml_jax.robots._meshio import load_mesh_parts
from rhaml_jax.robots._model import DEFAULT_COLOR, RobotModel


def _floats(text: str | None, n: int, default, where: str) -> np.ndarray:
    if text is None:
        return np.asarray(default, np.float64)
    try:
        vals = np.array([float(x) for x in text.split()], np.float64)
    except ValueError:
        raise RhamlError(f"{where}: expected {n} numbers, got {text!r}") from None
    if vals.shape != (n,) or not np.all(np.isfinite(vals)):
        raise RhamlError(f"{where}: expected {n} finite numbers, got {text!r}")
    return vals


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _origin(elem, where: str) -> np.ndarray:
    """(4, 4) transform of an <origin> child (identity when absent)."""
    T = np.eye(4)
    o = elem.find("origin")
    if o is not None:
        T[:3, :3] = _rpy_matrix(_floats(o.get("rpy"), 3, (0, 0, 0), f"{where} origin rpy"))
        T[:3, 3] = _floats(o.get("xyz"), 3, (0, 0, 0), f"{where} origin xyz")
    return T


def _resolve(filename: str, urdf: Path) -> Path:
    if filename.startswith("file://"):
        return Path(filename[len("file://") :])
    if filename.startswith("package://"):
        pkg, _, rest = filename[len("package://") :].partition("/")
        for d in list(urdf.resolve().parents)[:6]:
            for cand in (d / rest, d / pkg / rest):
                if cand.is_file():
                    return cand
        raise RhamlError(f"{urdf}: mesh {filename!r} not found (looked for {rest!r} in the folders above the URDF)")
    p = Path(filename)
    return p if p.is_absolute() else urdf.parent / p


def _color(material, named: dict[str, np.ndarray]):
    if material is None:
        return None
    c = material.find("color")
    if c is not None and c.get("rgba"):
        return _floats(c.get("rgba"), 4, None, f"material {material.get('name')!r} rgba")[:3]
    return named.get(material.get("name", ""))


def _primitive(geom, where: str):
    import trimesh

    box, cyl, sph = geom.find("box"), geom.find("cylinder"), geom.find("sphere")
    if box is not None:
        m = trimesh.creation.box(extents=_floats(box.get("size"), 3, None, f"{where} box size"))
    elif cyl is not None:
        r = float(_floats(cyl.get("radius"), 1, None, f"{where} cylinder radius")[0])
        h = float(_floats(cyl.get("length"), 1, None, f"{where} cylinder length")[0])
        m = trimesh.creation.cylinder(radius=r, height=h, sections=24)
    elif sph is not None:
        m = trimesh.creation.icosphere(subdivisions=2, radius=float(_floats(sph.get("radius"), 1, None, f"{where} sphere radius")[0]))
    else:
        return None
    return np.asarray(m.vertices), np.asarray(m.faces)


XACRO_NS = "{http://ros.org/wiki/xacro}"
_SUBST = re.compile(r"\$\{([^}]*)\}|\$\(arg ([^)]*)\)")


def _expand_simple_xacro(root, path: Path) -> None:
    """Expands the trivial xacro subset in place: <xacro:arg>, <xacro:property value=...>, ${name}.

    URDFs shipped as "plain" often still carry a namespace argument (the TurtleBot3's does).
    Anything more (macros, includes, conditionals, expressions) needs the real xacro tool.
    """
    values: dict[str, str] = {}

    def subst(text: str, where: str) -> str:
        def one(m):
            name = (m.group(1) or m.group(2)).strip()
            if name not in values:
                raise RhamlError(f"{path}: {where}: xacro expression {m.group(0)!r} is not a plain argument or property; "
                                 f"expand the file first: `xacro {path.name} > robot.urdf`")
            return values[name]
        return _SUBST.sub(one, text)

    for elem in list(root):
        if not isinstance(elem.tag, str) or not elem.tag.startswith(XACRO_NS):
            continue
        kind = elem.tag[len(XACRO_NS):]
        if kind == "arg":
            values[elem.get("name", "")] = subst(elem.get("default", ""), "xacro:arg")
        elif kind == "property" and elem.get("value") is not None:
            values[elem.get("name", "")] = subst(elem.get("value"), "xacro:property")
        else:
            raise RhamlError(f"{path}: uses <xacro:{kind}>; this is a xacro file, expand it first: "
                             f"`xacro {path.name} > robot.urdf`")
        root.remove(elem)
    for elem in root.iter():
        if isinstance(elem.tag, str) and elem.tag.startswith(XACRO_NS):
            raise RhamlError(f"{path}: uses <xacro:{elem.tag[len(XACRO_NS):]}>; this is a xacro file, expand it "
                             f"first: `xacro {path.name} > robot.urdf`")
        for k, v in elem.attrib.items():
            if "$" in v:
                elem.set(k, subst(v, f"<{elem.tag} {k}=...>"))


def load_urdf(path: Path) -> RobotModel:
    path = Path(path)
    if not path.is_file():
        raise RhamlError(f"{path}: URDF file not found")
    try:
        root = ET.fromstring(path.read_text(errors="replace"))
    except ET.ParseError as e:
        raise RhamlError(f"{path}: not valid XML: {e}") from None
    _expand_simple_xacro(root, path)
    if root.tag != "robot":
        raise RhamlError(f"{path}: not a URDF (root element <{root.tag}>, expected <robot>)")

    named = {}
    for m in root.findall("material"):
        c = _color(m, {})
        if c is not None:
            named[m.get("name", "")] = c

    # Link poses from the joint tree, root link at the identity.
    links = {link.get("name"): link for link in root.findall("link")}
    children: dict[str, list[tuple[str, np.ndarray]]] = {}
    child_links = set()
    for j in root.findall("joint"):
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None:
            raise RhamlError(f"{path}: joint {j.get('name')!r} lacks a parent or child")
        p, c = parent.get("link"), child.get("link")
        children.setdefault(p, []).append((c, _origin(j, f"{path}: joint {j.get('name')!r}")))
        child_links.add(c)
    roots = [n for n in links if n not in child_links]
    if len(roots) != 1:
        raise RhamlError(f"{path}: expected one root link, found {roots}")
    poses = {roots[0]: np.eye(4)}
    stack = [roots[0]]
    while stack:
        name = stack.pop()
        for c, T in children.get(name, []):
            poses[c] = poses[name] @ T
            stack.append(c)

    parts = []
    for lname, link in links.items():
        if lname not in poses:
            continue
        for k, vis in enumerate(link.findall("visual")):
            where = f"{path}: link {lname!r} visual {k}"
            T = poses[lname] @ _origin(vis, where)
            color = _color(vis.find("material"), named)
            geom = vis.find("geometry")
            if geom is None:
                raise RhamlError(f"{where}: no <geometry>")
            mesh = geom.find("mesh")
            if mesh is not None:
                if not mesh.get("filename"):
                    raise RhamlError(f"{where}: <mesh> without a filename")
                scale = _floats(mesh.get("scale"), 3, (1, 1, 1), f"{where} mesh scale")
                file = _resolve(mesh.get("filename"), path)
                if not file.is_file():
                    raise RhamlError(f"{where}: mesh file {file} not found")
                for v, f, cols in load_mesh_parts(file, color, DEFAULT_COLOR):
                    v = (v * scale) @ T[:3, :3].T + T[:3, 3]
                    parts.append((lname, v, f, cols))
            else:
                prim = _primitive(geom, where)
                if prim is None:
                    raise RhamlError(f"{where}: unsupported geometry (expected mesh, box, cylinder or sphere)")
                v, f = prim
                parts.append((lname, v @ T[:3, :3].T + T[:3, 3], f, color if color is not None else DEFAULT_COLOR))
    return RobotModel.from_parts(path.stem, parts)
