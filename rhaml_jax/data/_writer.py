"""Writing whole data sets: training sets and scenarios, in parallel processes, as BOP + TUM."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from rhaml_jax.camera import Camera, T_cam_robot
from rhaml_jax.data import _trajectories as traj
from rhaml_jax.data._backdrop import sample_light, sample_room
from rhaml_jax.data._bop import write_dataset_header, write_frame, write_scene_json
from rhaml_jax.data._synth import SynthConfig, check_scale, sample_rng, scenario_frame, scenario_frame_v2, training_sample, training_sample_v2
from rhaml_jax.data._tum import write_tum
from rhaml_jax.frames import se3_from_xypsi

SCENE_SIZE = 1000  # images per BOP scene folder
SPLITS = ("train", "val", "test")


def split_of(index: int, val_every: int = 20) -> str:
    """Deterministic split of global image `index`: 1 in val_every each to val and test."""
    r = index % val_every
    return "val" if r == 0 else "test" if r == 1 else "train"


def layout(num: int, negatives: int, val_every: int = 20) -> dict[str, list[int]]:
    """Global image indices of each split, in order (positives 0..num-1, then negatives)."""
    out = {s: [] for s in SPLITS}
    for i in range(num + negatives):
        out[split_of(i, val_every)].append(i)
    return out


# Worker-side state: each process loads the model and compiles the renderer once.
_WORKER: dict = {}


def _worker_init(robot: str, max_faces: int | None):
    from rhaml_jax.render import as_mesh
    from rhaml_jax.robots import load_robot

    _WORKER["mesh"] = as_mesh(load_robot(robot, max_faces))
    _WORKER["key"] = (robot, max_faces)


def _mesh(robot, max_faces):
    # keyed by the robot: a process that renders one robot and then another (jobs run in-process
    # with workers=1) must not draw the second with the first's mesh
    if _WORKER.get("key") != (robot, max_faces):
        _worker_init(robot, max_faces)
    return _WORKER["mesh"]


@dataclasses.dataclass(frozen=True)
class Job:
    """A chunk of images to render and write (picklable)."""

    robot: str
    max_faces: int | None
    camera: Camera
    seed: int
    num: int  # positives come first: global index < num
    items: tuple[tuple[int, str, int], ...]  # (global index, scene folder, im_id)
    cfg: SynthConfig
    heldout: object = None  # a HeldoutConfig: the held-out benchmark's look


def _run_training_job(job: Job) -> list[tuple[str, int, dict]]:
    mesh = _mesh(job.robot, job.max_faces)
    records = []
    for index, folder, im_id in job.items:
        if job.heldout is None:
            s = training_sample(mesh, job.camera, job.seed, index, negative=index >= job.num, cfg=job.cfg)
        else:
            s = training_sample_v2(mesh, job.camera, job.seed, index, negative=index >= job.num, cfg=job.cfg, heldout=job.heldout)
        T_w2c = np.asarray(T_cam_robot(s.camera_height).as_matrix(), np.float64)
        T_m2c = T_w2c @ np.asarray(se3_from_xypsi(s.xypsi).as_matrix(), np.float64) if s.observed else None
        records.append((folder, im_id, write_frame(Path(folder), job.camera, im_id, s.rgb, T_w2c, T_m2c, s.mask_visib, s.mask_all)))
    return records


def _pool(workers: int, robot: str, max_faces):
    ctx = multiprocessing.get_context("spawn")  # JAX is not fork-safe
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(robot, max_faces))


def _progress(total: int, label: str):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    p = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    return p, p.add_task(label, total=total)


def write_training_set(out: Path, robot: str, camera: Camera, seed: int, num: int, negatives: int, workers: int = 2,
                       chunk: int = 25, max_faces: int | None = None, cfg: SynthConfig = SynthConfig(),
                       heldout=None) -> dict:
    """A BOP training set of `num` robot images and `negatives` background-only images.

    With `heldout` (a HeldoutConfig), the held-out benchmark's random-pose images instead, all
    in split `test`."""
    from rhaml_jax.robots import load_robot

    out = Path(out)
    write_dataset_header(out, load_robot(robot, max_faces), camera)
    items = []
    splits = layout(num, negatives) if heldout is None else {"test": list(range(num + negatives))}
    for split, indices in splits.items():
        for k, index in enumerate(indices):
            items.append((index, str(out / split / f"{k // SCENE_SIZE:06d}"), k % SCENE_SIZE))
    _run(items, lambda chunk_items: Job(robot, max_faces, camera, seed, num, chunk_items, cfg, heldout), _run_training_job,
         workers, robot, max_faces, "rendering", chunk)
    return {"images": len(items), "positives": num, "negatives": negatives, "out": str(out)}


def _scene_done(folder: Path, ids: list[int]) -> bool:
    """Whether a scene was completely written by an earlier run (its JSON lists every image)."""
    try:
        gt = json.loads((folder / "scene_gt.json").read_text())
    except (OSError, json.JSONDecodeError):
        return False
    return sorted(int(k) for k in gt) == sorted(ids) and all((folder / "rgb" / f"{i:06d}.png").exists() for i in ids)


def _run(items, make_job, fn, workers, robot, max_faces, label, chunk: int) -> int:
    """Renders `items` [(.., folder, im_id, ..)] in chunks; writes each scene's JSON as soon as
    its last image is done, and skips scenes an interrupted earlier run completed (the images
    are a pure function of their index, so the result is the same as one uninterrupted run).
    Returns the number of frames with the robot in view."""
    by_scene: dict[str, list[int]] = {}
    for it in items:
        by_scene.setdefault(it[1], []).append(it[2])
    todo = [it for it in items if not _scene_done(Path(it[1]), by_scene[it[1]])]
    skipped = {f for f in by_scene if not any(it[1] == f for it in todo)}
    seen = sum(sum(1 for v in json.loads((Path(f) / "scene_gt.json").read_text()).values() if v) for f in skipped)
    jobs = [make_job(tuple(todo[i : i + chunk])) for i in range(0, len(todo), chunk)]
    pending: dict[str, dict] = {}
    progress, task = _progress(len(items), label)
    progress.advance(task, len(items) - len(todo))
    with progress:
        if workers <= 1:
            results = map(fn, jobs)
            pool = None
        else:
            pool = _pool(workers, robot, max_faces)
            results = pool.map(fn, jobs)
        try:
            for recs in results:
                for folder, im_id, rec in recs:
                    scene = pending.setdefault(folder, {})
                    scene[im_id] = rec
                    seen += bool(rec.gt)
                    if len(scene) == len(by_scene[folder]):
                        write_scene_json(Path(folder), pending.pop(folder))
                progress.advance(task, len(recs))
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
    return seen


# ----------------------------------------------------------------------------- scenarios


@dataclasses.dataclass(frozen=True)
class ScenarioJob:
    robot: str
    max_faces: int | None
    camera: Camera
    seed: int
    room_bounds: tuple[float, float, float, float]
    frames: tuple[tuple[int, str, int, tuple, tuple], ...]  # (key, folder, im_id, observer pose, observed pose), world frame
    heldout: object = None  # a HeldoutConfig: the held-out benchmark's look
    look_index: int = 0  # which held-out look (one per scenario)


def _scene_look(seed: int, bounds):
    rng = sample_rng(seed, 2**32 - 1)  # the room and light of a scenario: one draw for all frames
    return sample_room(rng, bounds, height=2.8), sample_light(rng)


def _heldout_scene_look(mesh, job: ScenarioJob):
    """The held-out room and look of a scenario: one draw for all its frames."""
    from rhaml_jax.data._appearance import color_groups, sample_heldout_look
    from rhaml_jax.data._backdrop import RoomLook

    groups, _ = color_groups(np.asarray(mesh.face_colors))
    look = sample_heldout_look(job.heldout, job.seed, 2**31 + job.look_index, groups)
    return RoomLook(tuple(float(b) for b in job.room_bounds), 2.8, look.textures), look


def _run_scenario_job(job: ScenarioJob):
    mesh = _mesh(job.robot, job.max_faces)
    if job.heldout is None:
        room, light = _scene_look(job.seed, job.room_bounds)
    else:
        room, look = _heldout_scene_look(mesh, job)
    records = []
    for _, folder, im_id, obs, tgt in job.frames:
        if job.heldout is None:
            rgb, visib, rel, seen = scenario_frame(mesh, job.camera, room, light, obs, tgt)
        else:
            rgb, visib, rel, seen = scenario_frame_v2(mesh, job.camera, room, look, obs, tgt, frame_seed=im_id)
        h = 0.30
        T_w2c = np.asarray(T_cam_robot(h).as_matrix(), np.float64)
        T_m2c = T_w2c @ np.asarray(se3_from_xypsi(rel).as_matrix(), np.float64) if seen else None
        records.append((folder, im_id, write_frame(Path(folder), job.camera, im_id, rgb, T_w2c, T_m2c, visib, visib)))
    return records


def scenario_poses(name: str, frames: int, seed: int, scale: float = 1.0):
    """World-frame truth of (observer, observed) robots; returns list of scenes:
    [(scene_id, observer truth (N, 3), observed truth (N, 3), observer odo, observed odo)] and the room bounds.

    `scale` multiplies every distance (paths and room; headings unchanged): DESIGN.md's scenarios
    at 1, a smaller robot's world below it (`RobotModel.world_scale`)."""
    from rhaml_jax.errors import RhamlError

    check_scale(scale)
    k = np.array([scale, scale, 1.0])
    if name in ("circle", "sine"):
        target = (traj.circle(frames) if name == "circle" else traj.sine(frames)) * k
        observer = np.zeros_like(target)
        odo_target = traj.noisy_odometry(target, seed=seed * 2 + 1)
        return [(0, observer, target, observer.copy(), odo_target)], tuple(scale * b for b in (-1.0, 9.0, -4.0, 4.0))
    if name == "rendezvous":
        room = traj.Room()
        a, b = (p * k for p in traj.rendezvous(frames, seed, room))
        oa, ob = traj.noisy_odometry(a, seed * 2 + 1), traj.noisy_odometry(b, seed * 2 + 2)
        return [(0, a, b, oa, ob), (1, b, a, ob, oa)], tuple(scale * v for v in (room.x0, room.x1, room.y0, room.y1))
    raise RhamlError(f"--scenario: unknown scenario {name!r} (expected circle, sine or rendezvous)")


def write_sequence(out: Path, scenes, bounds, robot: str, camera: Camera, seed: int, workers: int = 2, chunk: int = 25,
                   max_faces: int | None = None, timestamps=None, label: str = "rendering", heldout=None,
                   look_index: int = 0) -> int:
    """Renders scenes given by their poses into a BOP data set (split `test`) with the four TUM files
    per scene; returns the number of frames with the robot in view.

    scenes: [(scene_id, observer truth (N, 3), observed truth (N, 3), observer odometry (N, 3),
    observed odometry (N, 3))], truth in a common world frame whose room has `bounds`
    (x0, x1, y0, y1) and its look drawn from `seed` (and `look_index`); `timestamps` (N,) s
    (default 10 per second); with `heldout` (a HeldoutConfig), under the held-out benchmark's look."""
    from rhaml_jax.robots import load_robot

    out = Path(out)
    write_dataset_header(out, load_robot(robot, max_faces), camera)
    items = []
    for scene_id, observer, observed, odo_observer, odo_observed in scenes:
        folder = out / "test" / f"{scene_id:06d}"
        folder.mkdir(parents=True, exist_ok=True)
        # Static observer scenarios: the world is the observer's frame (identity on every line).
        write_tum(folder / "observer_groundtruth.txt", observer, timestamps)
        write_tum(folder / "observed_groundtruth.txt", observed, timestamps)
        write_tum(folder / "observer_odometry.txt", odo_observer, timestamps)
        write_tum(folder / "observed_odometry.txt", odo_observed, timestamps)
        items += [(i, str(folder), i, tuple(observer[i]), tuple(observed[i])) for i in range(len(observer))]
    return _run(items, lambda chunk_items: ScenarioJob(robot, max_faces, camera, seed, tuple(bounds), chunk_items, heldout,
                                                       look_index), _run_scenario_job, workers, robot, max_faces, label, chunk)


def write_scenario(out: Path, name: str, robot: str, camera: Camera, seed: int, frames: int = 500, workers: int = 2,
                   chunk: int = 25, max_faces: int | None = None, heldout=None, scale: float = 1.0) -> dict:
    """A BOP scenario (split `test`) with the four TUM files per scene (DESIGN.md sections 3-4);
    with `heldout` (a HeldoutConfig), under the held-out benchmark's look; `scale` multiplies its
    distances (`scenario_poses`)."""
    scenes, bounds = scenario_poses(name, frames, seed, scale)
    seen = write_sequence(out, scenes, bounds, robot, camera, seed, workers, chunk, max_faces, label=f"rendering {name}",
                          heldout=heldout, look_index=("circle", "sine", "rendezvous").index(name))
    return {"scenario": name, "scenes": len(scenes), "frames": frames, "observed_frames": seen, "out": str(out)}


HELDOUT_PARTS = ("circle", "sine", "background", "random")


def write_heldout(out: Path, robot: str, camera: Camera, seed: int, frames: int = 500, random: int = 500, background: int = 100,
                  workers: int = 2, max_faces: int | None = None, heldout=None, appearance=None, scale: float = 1.0) -> dict:
    """The held-out appearance benchmark: four BOP data sets under `out`, `circle` and `sine`
    (DESIGN.md scenarios, `frames` each), `background` (`background` frames without the robot)
    and `random` (`random` robot frames at training-like random poses), all rendered with the
    held-out settings of `heldout` (see rhaml_jax.data._appearance), checked to lie outside
    `appearance`'s training ranges first. Nothing may train or tune on it. `scale` multiplies the
    scenarios' distances and the random poses' depths (`scenario_poses`)."""
    from rhaml_jax.data._appearance import AppearanceConfig, HeldoutConfig, check_heldout

    heldout = HeldoutConfig() if heldout is None else heldout
    appearance = AppearanceConfig() if appearance is None else appearance
    check_heldout(appearance, heldout)
    out = Path(out)
    cfg = SynthConfig(appearance=appearance).scaled(scale)
    res = {}
    for name in ("circle", "sine"):
        if frames:
            res[name] = write_scenario(out / name, name, robot, camera, seed, frames, workers, max_faces=max_faces, heldout=heldout,
                                       scale=scale)
    if background:
        res["background"] = write_training_set(out / "background", robot, camera, seed + 1, 0, background, workers, max_faces=max_faces,
                                               cfg=cfg, heldout=heldout)
    if random:
        res["random"] = write_training_set(out / "random", robot, camera, seed + 2, random, 0, workers, max_faces=max_faces, cfg=cfg,
                                           heldout=heldout)
    return {"heldout": str(out), "parts": res}
