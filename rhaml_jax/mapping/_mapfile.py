"""ROS map_server occupancy maps (DESIGN.md section 4): an image (PGM, or PNG etc.) plus a YAML.

YAML fields (map_server's): `image` (relative to the YAML's folder), `resolution` (m per cell),
`origin` [x, y, yaw] (the pose of the lower-left cell's lower-left corner in the map frame),
`occupied_thresh`, `free_thresh`, `negate`, `mode` (trinary | scale | raw; default trinary).
Reading follows map_server's image loader: a pixel's occupancy is p = (255 - v) / 255 (v = the
mean of its colour channels, 255 - v first when `negate`); p > occupied_thresh is occupied,
p < free_thresh free, in between unknown (trinary) or (p - free_thresh) / (occupied_thresh -
free_thresh) (scale, as nav2; a pixel that is not opaque is unknown); raw reads v as the OccupancyGrid value itself (0..100, anything else unknown).
This reads what map_server's and nav2's map_saver, slam_toolbox (nav2's saver) and
Cartographer's ROS export (continuous grey levels, unknown 128, comments in the PGM header)
write; one deviation from nav2's loader: in an image holding only map_saver's three grey levels,
205 is unknown even when the YAML says free_thresh 0.25 (nav2's own saver writes that pair, and
its loader then reads unknown as free). Writing is map_saver's trinary image (occupied 0, free 254, unknown 205).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import cv2
import numpy as np

from rhaml_jax.errors import RhamlError

__all__ = ["OccupancyMap", "read_map", "write_map", "read_pgm", "write_pgm"]

# map_saver's grey levels
PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN = 0, 254, 205


@dataclasses.dataclass(frozen=True)
class OccupancyMap:
    """An occupancy grid in ROS OccupancyGrid order: row 0 is the bottom (lowest y).

    `occupancy` (H, W) float32: P(occupied) in [0, 1], NaN where unknown. Cell (i, j) covers
    [j, j+1] x [i, i+1] * resolution in the grid frame, whose pose in the map frame is `origin`.
    """

    occupancy: np.ndarray
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    occupied_thresh: float = 0.65
    free_thresh: float = 0.25

    def __post_init__(self):
        occ = np.asarray(self.occupancy, np.float32)
        if occ.ndim != 2 or occ.size == 0:
            raise RhamlError(f"occupancy map: expected a non-empty (H, W) grid, got shape {occ.shape}")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise RhamlError(f"occupancy map: resolution must be positive, got {self.resolution}")
        if not 0.0 <= self.free_thresh <= self.occupied_thresh <= 1.0:
            raise RhamlError(f"occupancy map: need 0 <= free_thresh <= occupied_thresh <= 1, got "
                             f"{self.free_thresh}, {self.occupied_thresh}")
        object.__setattr__(self, "occupancy", occ)
        object.__setattr__(self, "origin", tuple(float(v) for v in self.origin))

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupancy.shape

    @property
    def known(self) -> np.ndarray:
        return np.isfinite(self.occupancy)

    @property
    def occupied(self) -> np.ndarray:
        """(H, W) bool: the trinary class 'occupied' (p > occupied_thresh)."""
        return np.nan_to_num(self.occupancy, nan=0.0) > self.occupied_thresh

    @property
    def free(self) -> np.ndarray:
        """(H, W) bool: the trinary class 'free' (p < free_thresh)."""
        return np.nan_to_num(self.occupancy, nan=1.0) < self.free_thresh

    def ros_values(self) -> np.ndarray:
        """(H, W) int8 nav_msgs/OccupancyGrid data: -1 unknown, 0..100 occupancy percent."""
        v = np.rint(np.nan_to_num(self.occupancy, nan=0.0) * 100).astype(np.int8)
        return np.where(self.known, v, np.int8(-1))

    def cell_centres(self) -> np.ndarray:
        """(H, W, 2) cell centres in the map frame (m)."""
        H, W = self.shape
        gx, gy = np.meshgrid((np.arange(W) + 0.5) * self.resolution, (np.arange(H) + 0.5) * self.resolution)
        return grid_to_map(self.origin, np.stack([gx, gy], -1))

    def replace(self, **kw) -> "OccupancyMap":
        return dataclasses.replace(self, **kw)


def grid_to_map(origin, pts: np.ndarray) -> np.ndarray:
    """Points (..., 2) in the grid frame -> the map frame, by the grid origin (x, y, yaw)."""
    x, y, yaw = origin
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([x + c * pts[..., 0] - s * pts[..., 1], y + s * pts[..., 0] + c * pts[..., 1]], -1)


def map_to_grid(origin, pts: np.ndarray) -> np.ndarray:
    """Points (..., 2) in the map frame -> the grid frame (m, not cells)."""
    x, y, yaw = origin
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = pts[..., 0] - x, pts[..., 1] - y
    return np.stack([c * dx + s * dy, -s * dx + c * dy], -1)


# ----------------------------------------------------------------------------- PGM


def read_pgm(path: Path) -> np.ndarray:
    """(H, W) uint8 or uint16 of a binary (P5) or ASCII (P2) PGM; header comments allowed."""
    path = Path(path)
    data = path.read_bytes()
    tokens, pos = [], 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if pos < len(data) and data[pos : pos + 1] == b"#":  # a comment runs to the end of its line
            while pos < len(data) and data[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace() and data[pos : pos + 1] != b"#":
            pos += 1
        if start == pos:
            raise RhamlError(f"{path}: truncated PGM header")
        tokens.append(data[start:pos].decode("ascii", "replace"))
    magic = tokens[0]
    if magic not in ("P5", "P2"):
        raise RhamlError(f"{path}: not a PGM image (magic {magic!r}, expected P5 or P2)")
    try:
        W, H, maxval = (int(t) for t in tokens[1:])
    except ValueError:
        raise RhamlError(f"{path}: bad PGM header {tokens[1:]}") from None
    if W < 1 or H < 1 or not 0 < maxval < 65536:
        raise RhamlError(f"{path}: bad PGM size or maxval ({W} x {H}, maxval {maxval})")
    dtype = np.uint8 if maxval < 256 else np.dtype(">u2")
    if magic == "P5":
        pos += 1  # exactly one whitespace byte after maxval
        n = W * H * np.dtype(dtype).itemsize
        if len(data) - pos < n:
            raise RhamlError(f"{path}: PGM data truncated ({len(data) - pos} of {n} bytes)")
        img = np.frombuffer(data, dtype, W * H, pos).reshape(H, W)
    else:
        vals = data[pos:].split()
        if len(vals) < W * H:
            raise RhamlError(f"{path}: ASCII PGM has {len(vals)} of {W * H} values")
        img = np.array([int(v) for v in vals[: W * H]], np.int64).reshape(H, W)
    img = img.astype(np.uint16 if maxval >= 256 else np.uint8)
    if maxval != 255 and maxval < 256:  # rescale to 0..255 as map_server's loader (SDL) sees it
        img = np.rint(img.astype(np.float64) * 255.0 / maxval).astype(np.uint8)
    elif maxval >= 256:
        img = np.rint(img.astype(np.float64) * 255.0 / maxval).astype(np.uint8)
    return img


def write_pgm(path: Path, image: np.ndarray, comment: str | None = None) -> None:
    """Binary PGM (P5, maxval 255) of an (H, W) uint8 image, atomically."""
    image = np.ascontiguousarray(image, np.uint8)
    H, W = image.shape
    head = b"P5\n" + (f"# {comment}\n".encode() if comment else b"") + f"{W} {H}\n255\n".encode()
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(head + image.tobytes())
    os.replace(tmp, path)


# ----------------------------------------------------------------------------- YAML


def _load_yaml(path: Path) -> dict:
    import yaml

    if not path.is_file():
        raise RhamlError(f"{path}: map YAML not found")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise RhamlError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise RhamlError(f"{path}: expected a YAML mapping with image, resolution, origin, ...")
    return doc


def _number(doc: dict, key: str, path: Path, default=None) -> float:
    if key not in doc:
        if default is None:
            raise RhamlError(f"{path}: field '{key}' is missing")
        return default
    try:
        v = float(doc[key])
    except (TypeError, ValueError):
        raise RhamlError(f"{path}: field '{key}' must be a number, got {doc[key]!r}") from None
    if not np.isfinite(v):
        raise RhamlError(f"{path}: field '{key}' must be finite, got {doc[key]!r}")
    return v


def _read_image(path: Path, yaml_path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """-> (grey (H, W) float64 0..255 = the mean of the colour channels, alpha (H, W) or None)."""
    if not path.is_file():
        raise RhamlError(f"{yaml_path}: field 'image' points to {path}, which does not exist")
    if path.suffix.lower() == ".pgm":
        return read_pgm(path).astype(np.float64), None
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RhamlError(f"{yaml_path}: field 'image' points to {path}, which is not a readable image")
    if img.dtype == np.uint16:
        img = (img.astype(np.float64) / 257.0)
    img = img.astype(np.float64)
    if img.ndim == 2:
        return img, None
    if img.shape[2] in (2, 4):  # grey+alpha or BGRA
        return img[..., :-1].mean(-1), img[..., -1]
    return img.mean(-1), None


def read_map(yaml_path: Path) -> OccupancyMap:
    """Reads a map_server map (YAML + image) as map_server's loader interprets it."""
    yaml_path = Path(yaml_path)
    doc = _load_yaml(yaml_path)
    if "image" not in doc:
        raise RhamlError(f"{yaml_path}: field 'image' is missing")
    res = _number(doc, "resolution", yaml_path)
    if res <= 0:
        raise RhamlError(f"{yaml_path}: field 'resolution' must be positive, got {doc['resolution']!r}")
    if "origin" not in doc:
        raise RhamlError(f"{yaml_path}: field 'origin' is missing")
    origin = doc["origin"]
    try:
        origin = [float(v) for v in origin]
    except (TypeError, ValueError):
        raise RhamlError(f"{yaml_path}: field 'origin' must be [x, y, yaw], got {doc['origin']!r}") from None
    if len(origin) != 3 or not np.all(np.isfinite(origin)):
        raise RhamlError(f"{yaml_path}: field 'origin' must be three finite numbers [x, y, yaw], got {doc['origin']!r}")
    occ_th = _number(doc, "occupied_thresh", yaml_path, 0.65)
    free_th = _number(doc, "free_thresh", yaml_path, 0.196)
    negate = doc.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise RhamlError(f"{yaml_path}: field 'negate' must be 0 or 1, got {negate!r}")
    mode = str(doc.get("mode", "trinary")).lower()
    if mode not in ("trinary", "scale", "raw"):
        raise RhamlError(f"{yaml_path}: field 'mode' must be trinary, scale or raw, got {doc['mode']!r}")
    if not 0.0 <= free_th <= occ_th <= 1.0:
        raise RhamlError(f"{yaml_path}: need 0 <= free_thresh <= occupied_thresh <= 1, got {free_th}, {occ_th}")
    image = Path(str(doc["image"]))
    if not image.is_absolute():
        image = yaml_path.parent / image
    grey, alpha = _read_image(image, yaml_path)
    grey, alpha = grey[::-1], (None if alpha is None else alpha[::-1])  # image row 0 is the top: flip to y up
    if negate:
        grey = 255.0 - grey
    if mode == "raw":
        occ = np.where(grey <= 100, grey / 100.0, np.nan)
    else:
        p = (255.0 - grey) / 255.0
        # nav2's scale mode: between the thresholds, 0..1 across [free_thresh, occupied_thresh]
        between = (p - free_th) / max(occ_th - free_th, 1e-12) if mode == "scale" else np.nan
        occ = np.where(p > occ_th, 1.0, np.where(p < free_th, 0.0, between))
        if mode == "trinary" and not negate and free_th > 50 / 255 and set(np.unique(grey).tolist()) <= {0.0, 205.0, 254.0}:
            # A map_saver trinary image (only its three grey levels): 205 is what it wrote for
            # unknown. nav2's saver (slam_toolbox's too) writes free_thresh 0.25 beside it, with
            # which nav2's loader reads 205 (p = 0.196) as free (slam_toolbox issue #587).
            occ = np.where(grey == 205.0, np.nan, occ)
        if mode == "scale" and alpha is not None:
            occ = np.where(alpha < 255, np.nan, occ)  # nav2: a pixel that is not opaque is unknown
    return OccupancyMap(occ.astype(np.float32), res, tuple(origin), occ_th, free_th)


def write_map(yaml_path: Path, m: OccupancyMap, image_name: str | None = None) -> Path:
    """Writes `m` as map_saver does (trinary PGM: occupied 0, free 254, unknown 205; YAML beside it).
    Returns the image path."""
    yaml_path = Path(yaml_path)
    yaml_path.parent.mkdir(parents=True, exist_ok=True)
    image_name = image_name or yaml_path.with_suffix(".pgm").name
    img = np.full(m.shape, PGM_UNKNOWN, np.uint8)
    img[m.free] = PGM_FREE
    img[m.occupied] = PGM_OCCUPIED
    write_pgm(yaml_path.parent / image_name, img[::-1], f"rhaml_jax map; {m.resolution:g} m/pixel")
    x, y, yaw = m.origin
    text = (f"image: {image_name}\nmode: trinary\nresolution: {m.resolution!r}\norigin: [{x!r}, {y!r}, {yaw!r}]\n"
            f"negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")  # map_saver's: 205 (unknown) reads back unknown
    tmp = yaml_path.with_name(yaml_path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, yaml_path)
    return yaml_path.parent / image_name
