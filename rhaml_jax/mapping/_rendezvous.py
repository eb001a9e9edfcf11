"""A rendezvous sequence folder -> A_0 T B_0, the pose of B's map origin in A's (the paper's eq. 13).

A rendezvous sequence is what `generate --scenario rendezvous` and `explore` write: a BOP data
set with two scenes in split `test`, scene 0 seen by robot A's camera (A observes B) and scene 1
by B's, each with the four TUM files (DESIGN.md section 4), line i = image i in both scenes.
Each robot's odometry is in its own odometry frame, which is the frame its map is drawn in
(the map origin is where the odometry started), so B's odometry frame in A's odometry frame,
which the pose graph returns, is the transform that places B's map in A's.

`estimate_a0_T_b0` runs the jitted pipeline (`rhaml_jax.pipeline`, modules iml + pgo, the
shipped checkpoints) on both cameras' images or, for tests and to separate the localisation's
error from the fusion's, fuses the ground truth plus Gaussian noise with the same pose graph.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Literal

import numpy as np

from rhaml_jax.errors import RhamlError

__all__ = ["RendezvousEstimate", "estimate_a0_T_b0", "read_sequence", "Sequence"]

Observations = Literal["iml", "truth"]


@dataclasses.dataclass(frozen=True)
class Sequence:
    """The two scenes of a rendezvous sequence, aligned frame by frame."""

    frames_a: list  # BopFrame of A's camera (A observes B), image i = frame i
    frames_b: list  # BopFrame of B's camera
    odom_a: np.ndarray  # (N, 3) A's odometry in its own frame
    odom_b: np.ndarray  # (N, 3) B's odometry in its own frame
    truth_a: np.ndarray  # (N, 3) true poses (a common world frame)
    truth_b: np.ndarray
    timestamps: np.ndarray  # (N,) s


def read_sequence(root: Path) -> Sequence:
    """Reads and checks a rendezvous sequence folder (two scenes, four TUM files each)."""
    from rhaml_jax.data import read_bop, read_tum, scene_folders

    root = Path(root)
    scenes = scene_folders(root, "test") if (root / "test").is_dir() else scene_folders(root)
    if len(scenes) != 2:
        raise RhamlError(f"{root}: a rendezvous sequence has two scenes (one per robot's camera), found {len(scenes)}")
    (split_a, fa), (split_b, fb) = scenes
    frames_a = read_bop(root, split_a, int(fa.name))
    frames_b = read_bop(root, split_b, int(fb.name))
    if len(frames_a) != len(frames_b):
        raise RhamlError(f"{root}: the two scenes have {len(frames_a)} and {len(frames_b)} images; a rendezvous "
                         "sequence has one image per frame from each robot's camera")
    tum = {}
    for name in ("observer_odometry", "observed_odometry", "observer_groundtruth", "observed_groundtruth"):
        for tag, folder in (("a", fa), ("b", fb)):
            t, x = read_tum(folder / f"{name}.txt")
            if len(x) != len(frames_a):
                raise RhamlError(f"{folder / (name + '.txt')}: {len(x)} lines for {len(frames_a)} images (line i = image i)")
            tum[name, tag] = (t, x)
    odom_a, odom_b = tum["observer_odometry", "a"][1], tum["observer_odometry", "b"][1]
    if not np.allclose(tum["observed_odometry", "a"][1], odom_b, atol=1e-6):
        raise RhamlError(f"{fa / 'observed_odometry.txt'} differs from {fb / 'observer_odometry.txt'}: "
                         "the two scenes are not one rendezvous (B's odometry must be the same in both)")
    return Sequence(frames_a, frames_b, odom_a, odom_b, tum["observer_groundtruth", "a"][1],
                    tum["observed_groundtruth", "a"][1], tum["observer_odometry", "a"][0])


@dataclasses.dataclass(frozen=True)
class RendezvousEstimate:
    a0_T_b0: np.ndarray  # (3,) x, y, psi: B's map (odometry) origin in A's
    used: tuple[tuple[str, int], ...]  # ("A" | "B" = whose camera, image id) of each observation kept by the graph
    rejected: tuple[tuple[str, int], ...]  # detections the graph's erroneous-node deletion dropped
    observations: np.ndarray  # (K, 3) observed robot in the observer's frame, time order
    a_observes: np.ndarray  # (K,) bool
    source: str  # "iml" or "truth+noise(...)"
    frames: int  # frames in the sequence


def _pipeline(root: Path, zoom_mirror: bool):
    """The shipped IML in a pipeline with the pgo module (mirroring only for a left-right
    symmetric robot)."""
    from rhaml_jax import iml
    from rhaml_jax.data import bop_model_path, load_bop_model

    if zoom_mirror:
        try:
            iml.check_mirror_symmetric(load_bop_model(root), bop_model_path(root))
        except RhamlError:
            zoom_mirror = False  # not a left-right symmetric robot: no mirrored crops
    return _shipped_pipeline(zoom_mirror)


@functools.lru_cache(maxsize=2)
def _shipped_pipeline(zoom_mirror: bool):
    """One model object per setting: the jitted pipeline compiles once per sequence length
    (its static argument is compared by identity), however many sequences are fused."""
    from rhaml_jax import iml, pipeline

    iml_model, iml_params = iml.load_iml(zoom_mirror=zoom_mirror)
    model = pipeline.PipelineModel(iml_model, pipeline.PipelineConfig(modules=("iml", "pgo")))
    return model, pipeline.PipelineParams(iml_params)


def _truth_observations(seq: Sequence, sigma_xy: float, sigma_psi: float, seed: int):
    rng = np.random.default_rng(seed)
    out = []
    for frames in (seq.frames_a, seq.frames_b):
        seen = np.array([f.observed for f in frames])
        gt = np.array([f.xypsi if f.observed else np.zeros(3) for f in frames])
        noise = rng.standard_normal(gt.shape) * np.array([sigma_xy, sigma_xy, sigma_psi])
        out += [gt + noise, seen]
    return out


def estimate_a0_T_b0(sequence: Path, observations: Observations = "iml", *, sigma_xy: float = 0.05,
                     sigma_psi_deg: float = 2.0, seed: int = 0, min_probability: float = 0.5,
                     zoom_mirror: bool = True) -> RendezvousEstimate:
    """A_0 T B_0 from a rendezvous sequence folder: every frame in which one robot detects the
    other is a mutual observation, fused with both odometries by the pipeline's pose graph
    (`pipeline.fuse_estimates`: robust fusion, range calibration; the frames in time order, at
    each time A's image, then B's).

    observations: "iml" (the shipped AMLNet + zoom-in stage on the images; a detection is
    o >= min_probability) or "truth" (the BOP ground truth of every frame with the robot in view,
    plus Gaussian noise sigma_xy m, sigma_psi_deg deg; deterministic in `seed`)."""
    import jax.numpy as jnp

    from rhaml_jax import pipeline, planar
    from rhaml_jax.iml import Estimate

    root = Path(sequence)
    seq = read_sequence(root)
    from rhaml_jax.sequence import interleave, load_scene

    data = interleave(load_scene(seq.frames_a), load_scene(seq.frames_b))  # time order: A's image, then B's
    frames, a_observes = data.frames, np.asarray(data.seq.a_observes)
    odom_a, odom_b = data.seq.odom_a, data.seq.odom_b
    if observations == "iml":
        model, params = _pipeline(root, zoom_mirror)
        res = pipeline.run_jit(model, params, data.seq)
        est, detected, fusion = np.asarray(res.iml.xypsi), np.asarray(res.iml.o) >= min_probability, res.fusion
        source = "iml"
    elif observations == "truth":
        est_a, det_a, est_b, det_b = _truth_observations(seq, sigma_xy, np.radians(sigma_psi_deg), seed)
        est = np.stack([est_a, est_b], 1).reshape(-1, 3)
        detected = np.stack([det_a, det_b], 1).reshape(-1)
        n = len(est)
        e = Estimate(jnp.asarray(est, jnp.float32), jnp.ones(n), jnp.full(n, 0.5), jnp.zeros((n, 2)))
        fusion, _ = pipeline.fuse_estimates(pipeline.PipelineConfig(modules=("iml", "pgo")), e, jnp.asarray(detected),
                                            jnp.asarray(odom_a), jnp.asarray(odom_b), jnp.asarray(a_observes))
        source = f"truth+noise(sigma {100 * sigma_xy:g} cm, {sigma_psi_deg:g} deg)"
    else:
        raise RhamlError(f"observations: expected iml or truth, got {observations!r}")
    if not detected.any():
        what = "no image in which the IML detects a robot" if observations == "iml" else "no image with a robot in view"
        raise RhamlError(f"{root}: no rendezvous frames ({what} among {len(seq.frames_a)} frames per camera)")
    who = [("A" if a else "B", int(f.im_id)) for f, a in zip(frames, a_observes)]
    inlier = np.asarray(fusion.inlier)
    T = np.asarray(fusion.odom_a_T_odom_b, np.float64)
    T = np.array([T[0], T[1], float(planar.wrap_angle(T[2]))])
    return RendezvousEstimate(T, tuple(w for w, d, k in zip(who, detected, inlier) if d and k),
                              tuple(w for w, d, k in zip(who, detected, inlier) if d and not k),
                              est[detected], a_observes[detected], source, len(seq.frames_a))
