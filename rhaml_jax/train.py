"""`python -m rhaml_jax.train`: trains a network of the pipeline.

  python -m rhaml_jax.train --stage amlnet --config cpu --out runs/amlnet_cpu [--robot R]
      [--data DIR] [--steps N] [--batch B] [--resume]

Without --data the training images are generated on the fly by `rhaml_jax.data`; with --data
they are read from a BOP folder (also through `rhaml_jax.data`).  The run folder receives
Orbax checkpoints (with the model config), metrics.jsonl (one JSON object per logged step)
and metrics.png.  --toy-data swaps in coloured rectangles: a smoke test of the trainer only,
never a model of the robot.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro

from rhaml_jax.errors import RhamlError, run_cli

__all__ = ["Args", "main", "amlnet_sources"]


@dataclass(frozen=True)
class Args:
    stage: Literal["amlnet", "refiner"]
    """which network: the AMLNet initial localiser or the iterative refiner"""
    config: str
    """model config name (e.g. paper, cpu, cpu_k0, frontnet; see rhaml_jax.amlnet.config)"""
    out: Path
    """run folder: checkpoints/, metrics.jsonl, metrics.png"""
    robot: str = "pioneer3dx"
    """robot model: pioneer3dx or a URDF / mesh path (for generated data)"""
    data: Path | None = None
    """BOP training set; default: generate images on the fly"""
    steps: int = 5000
    """optimizer steps (the cosine schedule spans them)"""
    batch: int = 32
    """global batch size (a multiple of the device count)"""
    resume: bool = False
    """continue the run in --out from its latest checkpoint"""
    seed: int = 0
    """seed of initialisation, data order and augmentation"""
    lr: float = 1e-3
    """AdamW peak learning rate (cosine annealing to 0)"""
    weight_decay: float = 0.05
    """AdamW weight decay"""
    warmup: int = 0
    """linear learning-rate warm-up steps"""
    w_psi: float = 3.0
    """weight of the heading term in L_p"""
    w_p: float = 2.0
    """weight of L_p in L_A = L_o + w_p L_p"""
    log_every: int = 10
    """steps between metrics.jsonl lines"""
    val_every: int = 500
    """steps between validations"""
    val_batches: int = 8
    """validation batches per validation"""
    ckpt_every: int = 250
    """steps between checkpoints"""
    toy_data: bool = False
    """TEST ONLY: coloured rectangles instead of robot images (exercises the trainer; the model learns nothing about robots)"""
    progress: bool = True
    """show a progress bar"""


def amlnet_sources(args: Args, cfg):
    """(train source, validation source, label) for the AMLNet stage."""
    if args.toy_data:
        from rhaml_jax.amlnet.data import ToyRectangles

        return (ToyRectangles(cfg.input_hw, args.batch, args.seed),
                ToyRectangles(cfg.input_hw, args.batch, args.seed + 10_000), "toy rectangles (test only)")
    try:
        data = importlib.import_module("rhaml_jax.data")
    except ModuleNotFoundError as e:
        if e.name not in ("rhaml_jax.data",):
            raise
        raise RhamlError("--stage amlnet: training data are not available in this build (module rhaml_jax.data is missing); "
                         "nothing to train on") from None
    fn = getattr(data, "amlnet_batch_source", None)
    if fn is None:
        raise RhamlError("--stage amlnet: rhaml_jax.data provides no amlnet_batch_source(input_hw, batch, seed, robot, data_dir, split)")
    common = dict(input_hw=cfg.input_hw, batch=args.batch, robot=args.robot, data_dir=args.data)
    return (fn(seed=args.seed, split="train", **common), fn(seed=args.seed + 10_000, split="val", **common),
            f"{'BOP ' + str(args.data) if args.data else 'generated'} ({args.robot})")


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    if args.stage == "refiner":
        raise RhamlError("--stage refiner: the refiner trainer is not part of this build yet")
    from rhaml_jax.amlnet.config import get_config
    from rhaml_jax.amlnet.trainer import TrainConfig, train_amlnet

    cfg = get_config(args.config)
    if args.steps < 1 or args.batch < 1:
        raise RhamlError(f"--steps {args.steps} / --batch {args.batch}: must be positive")
    source, val_source, label = amlnet_sources(args, cfg)
    if args.toy_data:
        print("warning: --toy-data: training on coloured rectangles (a trainer test), not on robot images")
    tc = TrainConfig(steps=args.steps, batch=args.batch, lr=args.lr, weight_decay=args.weight_decay, warmup=args.warmup,
                     seed=args.seed, w_psi=args.w_psi, w_p=args.w_p, log_every=args.log_every, val_every=args.val_every,
                     val_batches=args.val_batches, ckpt_every=args.ckpt_every)
    res = train_amlnet(cfg, tc, args.out, source, val_source, resume=args.resume, data_label=label, progress=args.progress)
    print(f"step {res['step']}: loss {res['loss']:.5f}" + "".join(f", {k} {v:.4g}" for k, v in res["val"].items()
                                                              if k in ("dx_cm", "dy_cm", "dpsi_deg", "detection_acc")))
    return res


if __name__ == "__main__":
    run_cli(main)
