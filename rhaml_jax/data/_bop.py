"""BOP data sets (DESIGN.md section 4): writing ours, reading ours and other tools' (BlenderProc).

Layout: DATASET/camera.json, DATASET/models/{obj_000001.ply (mm, vertex colours), models_info.json},
DATASET/<split>/<scene_id:06d>/{rgb/<im_id:06d>.png|.jpg, mask_visib/<im_id:06d>_000000.png,
scene_camera.json, scene_gt.json, scene_gt_info.json}. The world of scene_camera's
cam_R_w2c / cam_t_w2c is the observer's robot frame, so an observation's planar pose is
T_w2c^-1 T_m2c. Translations are millimetres in the files and metres in memory.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from rhaml_jax.errors import RhamlError

MODEL_FILE = "obj_{:06d}.ply"
OBJ_ID = 1
IMAGE_EXTS = (".png", ".jpg", ".jpeg")


# ----------------------------------------------------------------------------- writing


def write_json(path: Path, obj) -> None:
    """Atomic JSON write (a reader never sees a half-written file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, separators=(",", ":")))
    os.replace(tmp, path)


def write_image(path: Path, image: np.ndarray) -> None:
    """PNG (or JPEG by extension) of an RGB uint8 (H, W, 3) or a mask (H, W), atomically."""
    path = Path(path)
    img = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(path.suffix, img, [cv2.IMWRITE_PNG_COMPRESSION, 3] if path.suffix == ".png" else [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise RhamlError(f"{path}: cannot encode image")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buf.tobytes())
    os.replace(tmp, path)


def write_dataset_header(root: Path, model, camera) -> None:
    """camera.json and models/ (the model in millimetres with its part colours as vertex colours)."""
    root = Path(root)
    (root / "models").mkdir(parents=True, exist_ok=True)
    write_json(root / "camera.json", {"cx": camera.cx, "cy": camera.cy, "fx": camera.fx, "fy": camera.fy,
                                      "width": camera.width, "height": camera.height, "depth_scale": 1.0})
    # Unshared vertices, so each face keeps its own colour.
    v_mm = model.vertices[model.faces].reshape(-1, 3).astype(np.float32) * 1000.0
    rgb = np.repeat((model.face_colors * 255).round().astype(np.uint8), 3, axis=0)
    _write_ply(root / "models" / MODEL_FILE.format(OBJ_ID), v_mm, rgb, np.arange(len(v_mm), dtype=np.int32).reshape(-1, 3))
    lo, hi = v_mm.min(0), v_mm.max(0)
    from scipy.spatial.distance import pdist

    hull = _hull_points(v_mm)
    info = {"diameter": float(pdist(hull).max()), "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}
    write_json(root / "models" / "models_info.json", {str(OBJ_ID): info})


def _hull_points(v: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull

    try:
        return v[ConvexHull(v).vertices]
    except Exception:  # flat model: all points
        return v


def _write_ply(path: Path, vertices: np.ndarray, colors: np.ndarray, faces: np.ndarray) -> None:
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment rhaml_jax robot model, millimetres\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    vdt = np.dtype([("p", "<f4", 3), ("c", "u1", 3)])
    vrec = np.empty(len(vertices), vdt)
    vrec["p"], vrec["c"] = vertices, colors
    fdt = np.dtype([("n", "u1"), ("i", "<i4", 3)])
    frec = np.empty(len(faces), fdt)
    frec["n"], frec["i"] = 3, faces
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vrec.tobytes())
        f.write(frec.tobytes())
    os.replace(tmp, path)


def bbox_of(mask: np.ndarray) -> list[int]:
    """BOP bbox [x, y, w, h] of a boolean mask ([-1, -1, -1, -1] when empty)."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


class FrameRecord(NamedTuple):
    """One image's entries of scene_camera.json, scene_gt.json and scene_gt_info.json."""

    cam: dict
    gt: list
    info: list


def write_frame(folder: Path, camera, im_id: int, rgb: np.ndarray, T_w2c: np.ndarray, T_m2c: np.ndarray | None,
                mask_visib: np.ndarray | None = None, mask_all: np.ndarray | None = None, ext: str = ".png") -> FrameRecord:
    """Writes one image (rgb/, mask_visib/) of a scene; returns its JSON entries.

    T_* are (4, 4) in metres; T_m2c None for a frame without the robot. The scene's JSON
    files are written once all its frames are done (`write_scene_json`).
    """
    folder = Path(folder)
    (folder / "rgb").mkdir(parents=True, exist_ok=True)
    write_image(folder / "rgb" / f"{im_id:06d}{ext}", rgb)
    cam = {"cam_K": np.asarray(camera.K).reshape(9).tolist(), "cam_R_w2c": np.asarray(T_w2c)[:3, :3].reshape(9).tolist(),
           "cam_t_w2c": (np.asarray(T_w2c)[:3, 3] * 1000.0).tolist(), "depth_scale": 1.0}
    if T_m2c is None:
        return FrameRecord(cam, [], [])
    gt = [{"obj_id": OBJ_ID, "cam_R_m2c": np.asarray(T_m2c)[:3, :3].reshape(9).tolist(),
           "cam_t_m2c": (np.asarray(T_m2c)[:3, 3] * 1000.0).tolist()}]
    visib = np.zeros(rgb.shape[:2], bool) if mask_visib is None else mask_visib.astype(bool)
    full = visib if mask_all is None else mask_all.astype(bool)
    (folder / "mask_visib").mkdir(exist_ok=True)
    write_image(folder / "mask_visib" / f"{im_id:06d}_000000.png", visib.astype(np.uint8) * 255)
    n_all, n_vis = int(full.sum()), int(visib.sum())
    info = [{"bbox_obj": bbox_of(full), "bbox_visib": bbox_of(visib), "px_count_all": n_all, "px_count_visib": n_vis,
             "visib_fract": float(n_vis / n_all) if n_all else 0.0}]
    return FrameRecord(cam, gt, info)


def write_scene_json(folder: Path, records: dict[int, FrameRecord]) -> None:
    """scene_camera.json, scene_gt.json and scene_gt_info.json of a scene, keyed by image id."""
    ids = sorted(records)
    write_json(Path(folder) / "scene_camera.json", {str(i): records[i].cam for i in ids})
    write_json(Path(folder) / "scene_gt.json", {str(i): records[i].gt for i in ids})
    write_json(Path(folder) / "scene_gt_info.json", {str(i): records[i].info for i in ids})


# ----------------------------------------------------------------------------- reading


@dataclasses.dataclass(frozen=True)
class BopFrame:
    """One image of a BOP scene.

    Fields: split, scene_id, im_id; rgb (path); mask (path of mask_visib, None without robot);
    K (3, 3); T_w2c (4, 4) world (observer's robot frame) to camera, metres; T_m2c (4, 4) model
    to camera, metres, or None when no robot is in view.
    """

    split: str
    scene_id: int
    im_id: int
    rgb: Path
    mask: Path | None
    K: np.ndarray
    T_w2c: np.ndarray
    T_m2c: np.ndarray | None

    @property
    def observed(self) -> bool:
        return self.T_m2c is not None

    @property
    def T_obs_model(self) -> np.ndarray | None:
        """(4, 4) the observed robot in the observer's robot frame (metres), or None."""
        return None if self.T_m2c is None else np.linalg.inv(self.T_w2c) @ self.T_m2c

    @property
    def xypsi(self) -> np.ndarray | None:
        T = self.T_obs_model
        return None if T is None else np.array([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0])])

    @property
    def camera_height_m(self) -> float:
        """Height of the camera above the observer's ground: the z of the camera centre in the world."""
        return float(np.linalg.inv(self.T_w2c)[2, 3])


def _load_json(path: Path):
    if not path.is_file():
        raise RhamlError(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise RhamlError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None


def _numbers(value, n: int, where: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64) if isinstance(value, (list, tuple)) else None
    if a is None or a.size != n or a.ndim not in (1, 2) or not np.all(np.isfinite(a)):
        shape = np.shape(value) if isinstance(value, (list, tuple)) else type(value).__name__
        raise RhamlError(f"{where}: expected {n} finite numbers, got {shape}")
    return a.reshape(-1)


def _rigid(R, t_mm, where: str) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _numbers(R, 9, where.replace("FIELD", "R")).reshape(3, 3)
    T[:3, 3] = _numbers(t_mm, 3, where.replace("FIELD", "t")) / 1000.0
    if abs(np.linalg.det(T[:3, :3]) - 1.0) > 1e-3:
        raise RhamlError(f"{where.replace('FIELD', 'R')}: not a rotation matrix (det {np.linalg.det(T[:3, :3]):.4f})")
    return T


def _default_w2c() -> np.ndarray:
    from rhaml_jax.camera import NOMINAL_HEIGHT_M, T_cam_robot

    return np.asarray(T_cam_robot(NOMINAL_HEIGHT_M).as_matrix(), np.float64)


def scene_folders(root: Path, split: str | None = None) -> list[tuple[str, Path]]:
    """All (split, scene folder) pairs under a BOP dataset root, sorted."""
    root = Path(root)
    if not root.is_dir():
        raise RhamlError(f"{root}: data set folder not found")
    out = []
    for sp in sorted(p for p in root.iterdir() if p.is_dir() and p.name != "models"):
        if split is not None and sp.name != split:
            continue
        for sc in sorted(p for p in sp.iterdir() if p.is_dir() and (p / "scene_gt.json").exists()):
            out.append((sp.name, sc))
    if not out:
        raise RhamlError(f"{root}: no BOP scenes found (expected <split>/<scene_id>/scene_gt.json)")
    return out


def read_scene(folder: Path, split: str = "", obj_id: int = OBJ_ID) -> list[BopFrame]:
    """The frames of one scene folder, checked: every image has a camera, a gt entry and a file."""
    folder = Path(folder)
    cams = _load_json(folder / "scene_camera.json")
    gts = _load_json(folder / "scene_gt.json")
    images = {}
    rgb_dir = folder / "rgb"
    if rgb_dir.is_dir():
        for p in rgb_dir.iterdir():
            if p.suffix.lower() in IMAGE_EXTS and p.stem.isdigit():
                images[int(p.stem)] = p
    ids = sorted(int(k) for k in cams)
    if set(ids) != set(images):
        extra_img = sorted(set(images) - set(ids))[:3]
        extra_cam = sorted(set(ids) - set(images))[:3]
        raise RhamlError(f"{folder}: image ids do not match scene_camera.json (images without camera: {extra_img}, "
                         f"camera entries without image: {extra_cam})")
    frames = []
    for i in ids:
        cam = cams[str(i)]
        where = f"{folder / 'scene_camera.json'}: image {i} cam_K"
        if "cam_K" not in cam:
            raise RhamlError(f"{folder / 'scene_camera.json'}: image {i} has no cam_K")
        K = _numbers(cam["cam_K"], 9, where).reshape(3, 3)
        if "cam_R_w2c" in cam:
            T_w2c = _rigid(cam["cam_R_w2c"], cam.get("cam_t_w2c"), f"{folder / 'scene_camera.json'}: image {i} cam_FIELD_w2c")
        else:  # other tools' scenes: assume our nominal camera on the observer
            T_w2c = _default_w2c()
        if str(i) not in gts:
            raise RhamlError(f"{folder / 'scene_gt.json'}: no entry for image {i}")
        entries = [e for e in gts[str(i)] if int(e.get("obj_id", -1)) == obj_id]
        T_m2c, mask = None, None
        if entries:
            gi = gts[str(i)].index(entries[0])
            e = entries[0]
            T_m2c = _rigid(e.get("cam_R_m2c"), e.get("cam_t_m2c"), f"{folder / 'scene_gt.json'}: image {i} cam_FIELD_m2c")
            mask = folder / "mask_visib" / f"{i:06d}_{gi:06d}.png"
        frames.append(BopFrame(split, int(folder.name) if folder.name.isdigit() else 0, i, images[i], mask, K, T_w2c, T_m2c))
    return frames


def read_bop(root: Path, split: str | None = None, scene: int | None = None, obj_id: int = OBJ_ID) -> list[BopFrame]:
    """Frames of every scene (of `split`, or only `scene`) of a BOP dataset, in order."""
    frames = []
    for sp, folder in scene_folders(root, split):
        if scene is not None and folder.name.isdigit() and int(folder.name) != scene:
            continue
        frames.extend(read_scene(folder, sp, obj_id))
    if scene is not None and not frames:
        raise RhamlError(f"{root}: scene {scene} not found")
    return frames


def load_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB; a corrupt or unreadable file gets an error naming it."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RhamlError(f"{path}: cannot decode image (corrupt or not an image)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def load_mask(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise RhamlError(f"{path}: cannot decode mask (missing, corrupt or not an image)")
    return img > 127


def bop_model_path(root: Path, obj_id: int = OBJ_ID) -> Path:
    """Where a BOP data set keeps its object's model (models/obj_000001.ply)."""
    return Path(root) / "models" / MODEL_FILE.format(obj_id)


def load_bop_model(root: Path, obj_id: int = OBJ_ID):
    """The data set's model (BOP: millimetres) as a RobotModel in metres; checks the units."""
    from rhaml_jax.robots import RobotModel
    from rhaml_jax.robots import load_mesh_parts

    path = bop_model_path(root, obj_id)
    parts = load_mesh_parts(path)
    size = max(np.ptp(np.concatenate([v for v, _, _ in parts]), axis=0))
    if size < 10.0:
        raise RhamlError(f"{path}: the model is {size:.3f} units across; BOP models are in millimetres "
                         "(this one looks like metres: scale it by 1000)")
    model = RobotModel.from_parts(path.stem, [(f"part{i}", v / 1000.0, f, c) for i, (v, f, c) in enumerate(parts)])
    return model.validated(str(path))
