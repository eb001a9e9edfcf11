"""Host side of the pipeline: a BOP scene with its TUM odometry as a `pipeline.Sequence`.

A scene folder (DESIGN.md section 4) is one observer camera: its images, `scene_camera.json`,
`scene_gt.json` and the four TUM files, line i belonging to image i. The observer is robot A
(its camera took every image), the observed robot B. Decoding, file checks and the ground
truth stay here, in NumPy; the traced pipeline gets arrays only.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from rhaml_jax.data import BopFrame, load_rgb, read_tum
from rhaml_jax.errors import RhamlError
from rhaml_jax.pipeline import Sequence

__all__ = ["SceneData", "SceneRun", "load_scene", "group_scenes", "run_scenes"]


class SceneData(NamedTuple):
    seq: Sequence  # NumPy arrays, ready for pipeline.run
    frames: list  # (N,) BopFrame, time order
    gt: np.ndarray  # (N, 3) true pose of the observed robot in the observer's frame (zeros where not in view)
    observed: np.ndarray  # (N,) bool: the robot is in view (ground truth)


def group_scenes(frames: list[BopFrame]) -> dict[tuple[str, int], list[BopFrame]]:
    """Frames by (split, scene_id), each list in image-id order."""
    out: dict[tuple[str, int], list[BopFrame]] = {}
    for f in frames:
        out.setdefault((f.split, f.scene_id), []).append(f)
    return {k: sorted(v, key=lambda f: f.im_id) for k, v in out.items()}


def _odometry(folder: Path, name: str, n: int, ids: np.ndarray) -> np.ndarray:
    path = folder / name
    if not path.is_file():
        raise RhamlError(f"{path}: not found; the pgo module needs the scene's TUM odometry "
                         "(observer_odometry.txt and observed_odometry.txt, line i = image i)")
    _, poses = read_tum(path)
    if len(poses) <= ids.max():
        raise RhamlError(f"{path}: {len(poses)} lines, but the scene has image id {int(ids.max())} "
                         f"({n} images): odometry shorter than the image list")
    return poses[ids]


def load_scene(frames: list[BopFrame], need_odometry: bool = True, length: int | None = None) -> SceneData:
    """One scene's frames (time order) -> SceneData, padded to `length` frames if given. Without
    odometry (need_odometry False) A and B stand still at the origin."""
    if not frames:
        raise RhamlError("load_scene: no frames")
    folder = Path(frames[0].rgb).parent.parent
    n = len(frames)
    N = n if length is None else length
    if N < n:
        raise RhamlError(f"load_scene: length {N} is shorter than the scene's {n} frames")
    images = [load_rgb(f.rgb) for f in frames]
    h, w = images[0].shape[:2]
    for f, im in zip(frames, images):
        if im.shape[:2] != (h, w):
            raise RhamlError(f"{f.rgb}: {im.shape[1]}x{im.shape[0]} px, but the scene's first image is {w}x{h}")
        if abs(f.K[0, 2] - (w - 1) / 2) > w or abs(f.K[1, 2] - (h - 1) / 2) > h:
            raise RhamlError(f"{f.rgb}: a {w}x{h} image, but its cam_K has the principal point at "
                             f"({f.K[0, 2]:.0f}, {f.K[1, 2]:.0f}): intrinsics of another image size")
    ids = np.array([f.im_id for f in frames])
    if need_odometry:
        oa = _odometry(folder, "observer_odometry.txt", n, ids)
        ob = _odometry(folder, "observed_odometry.txt", n, ids)
    else:
        oa = ob = np.zeros((n, 3))
    pad = N - n
    imgs = np.stack(images + [np.zeros_like(images[0])] * pad)
    K = np.stack([f.K for f in frames] + [frames[-1].K] * pad).astype(np.float32)
    padrows = lambda a: np.concatenate([a, np.repeat(a[-1:], pad, 0)]).astype(np.float32)  # noqa: E731
    seq = Sequence(imgs, K, padrows(oa), padrows(ob), np.ones(N, bool), np.arange(N) < n)
    observed = np.array([f.observed for f in frames] + [False] * pad)
    gt = np.array([f.xypsi if f.observed else np.zeros(3) for f in frames] + [np.zeros(3)] * pad)
    return SceneData(seq, list(frames), gt, observed)


class SceneRun(NamedTuple):
    data: SceneData  # the scene as loaded (padding dropped from `result`)
    result: object  # pipeline.PipelineResult as NumPy arrays, first len(data.frames) rows


def _first(res, n: int):
    """The per-frame fields of a PipelineResult cut to the scene's n frames (padding dropped)."""
    cut = lambda tree: None if tree is None else type(tree)(*(np.asarray(a)[:n] for a in tree))  # noqa: E731
    fusion = res.fusion
    if fusion is not None:
        per_row = ("relative", "inlier", "flipped", "weights", "deleted", "consensus")
        fusion = fusion._replace(**{k: np.asarray(getattr(fusion, k))[:n] for k in per_row})
    return res._replace(iml=cut(res.iml), ir=cut(res.ir), detected=np.asarray(res.detected)[:n],
                        xypsi=np.asarray(res.xypsi)[:n], fusion=fusion)


def run_scenes(model, params, scenes: list[list[BopFrame]]) -> tuple[list[SceneRun], float, float]:
    """Every scene through the pipeline, padded to one length so that it compiles once:
    (runs, compile seconds, pipeline seconds of the compiled calls)."""
    import time

    import jax

    from rhaml_jax import pipeline

    need_odometry = "pgo" in model.config.modules
    length = max(len(s) for s in scenes)
    compiled, compile_s, seconds, runs = None, 0.0, 0.0, []
    for scene in scenes:
        data = load_scene(scene, need_odometry=need_odometry, length=length)
        if compiled is None:
            t = time.perf_counter()
            compiled = pipeline.run_jit.lower(model, params, data.seq).compile()
            compile_s = time.perf_counter() - t
        t = time.perf_counter()
        res = jax.block_until_ready(compiled(params, data.seq))
        seconds += time.perf_counter() - t
        n = len(scene)
        runs.append(SceneRun(data._replace(gt=data.gt[:n], observed=data.observed[:n]), _first(jax.device_get(res), n)))
    return runs, compile_s, seconds
