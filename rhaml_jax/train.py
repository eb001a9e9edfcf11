"""`python -m rhaml_jax.train`: trains a network of the pipeline.

  python -m rhaml_jax.train --stage amlnet --config cpu --out runs/amlnet_cpu [--robot R]
      [--data DIR] [--steps N] [--batch B] [--resume] [--init CKPT]
  python -m rhaml_jax.train --stage zoom --config zoom_cpu --data DIR --out runs/zoom_cpu
  python -m rhaml_jax.train --stage refiner --config refiner_cpu --data DIR --out runs/refiner_cpu [--resume]
  python -m rhaml_jax.train --stage segmenter --config segmenter_cpu --data DIR --out runs/segmenter_cpu [--resume]
  python -m rhaml_jax.train --stage scorer --config scorer_cpu --data DIR --out runs/scorer_cpu [--resume]

Without --data the training images are generated on the fly by `rhaml_jax.data`; with --data
they are read from a BOP folder (also through `rhaml_jax.data`).  The run folder receives
Orbax checkpoints (with the model config), metrics.jsonl (one JSON object per logged step)
and metrics.png.  --toy-data swaps in coloured rectangles: a smoke test of the trainer only,
never a model of the robot.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro

from rhaml_jax.allocator import tune_allocator
from rhaml_jax.amlnet.trainer import TrainConfig
from rhaml_jax.errors import RhamlError, run_cli

__all__ = ["Args", "main", "amlnet_sources", "zoom_sources", "train_refiner"]


@dataclass(frozen=True)
class Args:
    stage: Literal["amlnet", "zoom", "refiner", "segmenter", "scorer"]
    """which network: the AMLNet initial localiser, its zoom-in stage (needs --data), the iterative refiner, the observed-mask segmenter of the silhouette alignment or the refinement's heading scorer"""
    config: str
    """model config name (e.g. paper, cpu, cpu_k0, frontnet, zoom_cpu: rhaml_jax.amlnet.config; refiner_cpu: rhaml_jax.refine.net; segmenter_cpu: rhaml_jax.refine.segmenter; scorer_cpu: rhaml_jax.refine.scorer)"""
    out: Path
    """run folder: checkpoints/, metrics.jsonl, metrics.png"""
    robot: str = "pioneer3dx"
    """robot model: pioneer3dx or a URDF / mesh path (for generated data)"""
    data: Path | None = None
    """BOP training set; default: generate images on the fly"""
    train: tyro.conf.OmitArgPrefixes[TrainConfig] = TrainConfig()
    """optimisation settings (flags --steps, --batch, --lr, ... without a prefix)"""
    resume: bool = False
    """continue the run in --out from its latest checkpoint"""
    zoom_length_m: float | None = None
    """zoom: the robot length the crop is sized to (default: the config's, the built-in robot's 0.455 m)"""
    init: Path | None = None
    """start from the weights of this checkpoint folder of the same network and config (e.g. rhaml_jax/checkpoints/amlnet_cpu, or a refiner run) instead of a random initialisation: fine-tuning (a refinement-stage network: any config of the same network, e.g. refiner_fine_cpu from refiner_cpu)"""
    toy_data: bool = False
    """TEST ONLY: coloured rectangles instead of robot images (exercises the trainer; the model learns nothing about robots)"""
    progress: bool = True
    """show a progress bar"""


def robot_of(args: Args) -> dict:
    """The fingerprint of the robot the training data show: the BOP set's model when --data has
    one (under --robot's name when that is the same robot: a BOP model is called obj_000001),
    else --robot."""
    from rhaml_jax.data import bop_model_path, load_bop_model
    from rhaml_jax.robots import fingerprint, load_robot

    named = fingerprint(load_robot(args.robot))
    if args.data is None or not bop_model_path(args.data).exists():
        return named.to_dict()
    shown = fingerprint(load_bop_model(args.data))
    return (named if named.same_robot(shown) else shown).to_dict()


def amlnet_sources(args: Args, cfg):
    """(train source, validation source, label) for the AMLNet stage."""
    tc = args.train
    if args.toy_data:
        from rhaml_jax.amlnet.data import ToyRectangles

        return (ToyRectangles(cfg.input_hw, tc.batch, tc.seed),
                ToyRectangles(cfg.input_hw, tc.batch, tc.seed + 10_000), "toy rectangles (test only)")
    from rhaml_jax.data import amlnet_batch_source as fn

    common = dict(input_hw=cfg.input_hw, batch=tc.batch, robot=args.robot, data_dir=args.data)
    return (fn(seed=tc.seed, split="train", **common), fn(seed=tc.seed + 10_000, split="val", **common),
            f"{'BOP ' + str(args.data) if args.data else 'generated'} ({args.robot})")


def zoom_sources(args: Args, cfg):
    """(train source, validation source, label) for the zoom stage: crops of the BOP set's
    observed frames around jittered estimates (`rhaml_jax.zoom`)."""
    if args.data is None or args.toy_data:
        raise RhamlError("--stage zoom: needs --data (a BOP training set with a val split); it has no generated or toy data")
    if getattr(cfg, "task", None) != "zoom":
        raise RhamlError(f"--stage zoom: --config {args.config} is not a zoom network (e.g. zoom_cpu)")
    from rhaml_jax.zoom import zoom_batch_sources

    return (*zoom_batch_sources(args.data, cfg, args.train.batch, args.train.seed), f"zoom crops of BOP {args.data}")


def train_refiner(args: Args) -> dict:
    """--stage refiner / segmenter / scorer: a refinement-stage network on a BOP set (crops around drawn
    initial poses, rhaml_jax.refine.train / .segmenter / .scorer); the checkpoint stores the config and the
    robot's fingerprint."""
    from rhaml_jax.data import load_bop_model
    from rhaml_jax.training import fit

    if args.data is None or args.toy_data:
        raise RhamlError(f"--stage {args.stage}: needs --data (a BOP training set with a val split)")
    tc = args.train
    if tc.steps < 1 or tc.batch < 1:
        raise RhamlError(f"--steps {tc.steps} / --batch {tc.batch}: must be positive")
    model = load_bop_model(args.data)
    if args.stage == "refiner":
        from rhaml_jax.refine import net as N
        from rhaml_jax.refine.train import RefinerSource as Source, refiner_task

        cfg, stored = N.get_refiner_config(args.config), (N.config_from_dict, N.init_params)
        make_task = lambda val: refiner_task(cfg, tc, model, model, val)  # noqa: E731
    elif args.stage == "scorer":
        from rhaml_jax.refine import scorer as S

        Source, cfg, stored = S.ScorerSource, S.get_scorer_config(args.config), (S.config_from_dict, S.init_params)
        make_task = lambda val: S.scorer_task(cfg, tc, model, val)  # noqa: E731
    else:
        from rhaml_jax.refine import segmenter as G

        Source, cfg, stored = G.SegmenterSource, G.get_segmenter_config(args.config), (G.config_from_dict, G.init_params)
        make_task = lambda val: G.segmenter_task(cfg, tc, model, val)  # noqa: E731
    source = Source(args.data, "train", cfg, tc.batch, seed=tc.seed)
    task, shardings = make_task(Source(args.data, "val", cfg, tc.batch, seed=tc.seed + 10_000))
    if args.init is not None:  # the starting point; a resumed run then continues from its own checkpoint
        from rhaml_jax.refine._checkpoint import load_params

        params, init_cfg = load_params(args.init, args.stage, model, *stored)
        import jax

        shapes = lambda p: jax.tree.map(lambda a: tuple(a.shape), p)  # noqa: E731
        if shapes(params) != shapes(stored[1](cfg, jax.random.key(0))) or getattr(init_cfg, "luma", None) != getattr(cfg, "luma", None):
            raise RhamlError(f"--init {args.init}: holds a {init_cfg.name!r} {args.stage}, whose network differs from "
                             f"--config {cfg.name!r}'s")
        task = dataclasses.replace(task, params=params, meta={**task.meta, "initialised_from": str(args.init)})
    res = fit(task, tc, args.out, source, shardings=shardings, resume=args.resume,
              data_label=f"{args.stage} crops of BOP {args.data}", progress=args.progress)
    print(f"step {res['step']}: loss {res['loss']:.5f}" + "".join(f", {k} {v:.4g}" for k, v in res["val"].items()))
    return res


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    tune_allocator()  # before JAX starts its threads; see rhaml_jax.allocator
    if args.stage in ("refiner", "segmenter", "scorer"):
        return train_refiner(args)
    from rhaml_jax.amlnet.config import get_config
    from rhaml_jax.amlnet.trainer import train_amlnet

    cfg = get_config(args.config)
    if args.zoom_length_m is not None:
        if getattr(cfg, "task", None) != "zoom" or not args.zoom_length_m > 0:
            raise RhamlError(f"--zoom-length-m {args.zoom_length_m}: needs a zoom config and a positive length")
        cfg = dataclasses.replace(cfg, zoom_length_m=float(args.zoom_length_m))
    tc = args.train
    if tc.steps < 1 or tc.batch < 1:
        raise RhamlError(f"--steps {tc.steps} / --batch {tc.batch}: must be positive")
    if args.stage == "amlnet" and getattr(cfg, "task", None) == "zoom":
        raise RhamlError(f"--stage amlnet: --config {args.config} is a zoom network; use --stage zoom")
    source, val_source, label = (zoom_sources if args.stage == "zoom" else amlnet_sources)(args, cfg)
    if args.toy_data:
        print("warning: --toy-data: training on coloured rectangles (a trainer test), not on robot images")
    res = train_amlnet(cfg, tc, args.out, source, val_source, resume=args.resume, data_label=label,
                       progress=args.progress, init=args.init, robot=None if args.toy_data else robot_of(args))
    print(f"step {res['step']}: loss {res['loss']:.5f}" + "".join(f", {k} {v:.4g}" for k, v in res["val"].items()
                                                              if k in ("dx_cm", "dy_cm", "range_pct", "bearing_deg",
                                                                       "dpsi_deg", "detection_acc")))
    return res


if __name__ == "__main__":
    run_cli(main)
