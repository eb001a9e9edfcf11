"""`python -m rhaml_jax.calibrate_flips`: makes IML's flip probability a probability.

  python -m rhaml_jax.calibrate_flips --data DIR [--split val] --zoom CKPT [--amlnet CKPT] [--zoom-mirror] [--dry-run]

Runs IML on a validation split (never the data you report on), fits the Platt scaling of the
zoom stage's front/back ranking to its flips (`zoom.fit_flip_calibration`) and stores it in the
zoom checkpoint's meta (`zoom.write_flip_calibration`), from which `evaluate`, the pipeline and
the demo read it. Prints how well the ranking and the calibrated probability match the flips
(Brier score, negative log-likelihood, calibration error, ROC area) and one JSON line.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro

from rhaml_jax.allocator import tune_allocator
from rhaml_jax.errors import RhamlError, run_cli

__all__ = ["Args", "calibrate", "main"]


@dataclass(frozen=True)
class Args:
    data: Path
    """BOP data set with the robot (a validation split: calibrating on the data you report on flatters it)"""
    zoom: Path
    """the zoom-in stage checkpoint folder to calibrate (its meta is rewritten; the weights stay)"""
    amlnet: Path | None = None
    """the AMLNet it runs behind (default: the shipped heat_nocart_cpu, `iml.DEFAULT_AMLNET`)"""
    split: str | None = "val"
    """the split of --data to fit on (None: every split)"""
    zoom_mirror: bool = False
    """IML mirrors the crops, as it will when the calibration is used (the calibration records it)"""
    allow_other_robot: bool = False
    """networks made for another robot than the data set's (a deliberate transfer test)"""
    dry_run: bool = False
    """fit and print, write nothing"""
    batch: int = 32
    """frames per network call"""


def calibrate(args: Args) -> dict:
    """Fits (and unless --dry-run stores) the calibration; returns it with the metrics of the
    raw ranking and of the calibrated probability on the fitted frames."""
    from rhaml_jax import evaluate
    from rhaml_jax.metrics import flipped
    from rhaml_jax.zoom import calibration_metrics, fit_flip_calibration, flip_probability, write_flip_calibration

    if not (args.zoom / "checkpoints").is_dir():
        raise RhamlError(f"--zoom {args.zoom}: not a checkpoint folder (no checkpoints/ inside)")
    res = evaluate.run(evaluate.Args(args.data, "iml", split=args.split, amlnet=args.amlnet, zoom=args.zoom,
                                     zoom_mirror=args.zoom_mirror, allow_other_robot=args.allow_other_robot,
                                     batch=args.batch, raw_flip_ranking=True))
    seen = [r for r in res["frames"] if r["observed"] and r["detected"]]
    if len(seen) < 20:
        raise RhamlError(f"--data {args.data} (split {args.split}): {len(seen)} detected robot frames; a calibration needs at least 20")
    ranking = [r["iml_flip_prob"] for r in seen]
    flips = flipped([r["iml_est"][2] for r in seen], [r["gt"][2] for r in seen])
    source = f"{args.data} (split {args.split or 'all'})"
    cal = fit_flip_calibration(ranking, flips, args.zoom_mirror, source)

    out = {"calibration": cal.to_dict(), "ranking": calibration_metrics(ranking, flips),
           "calibrated": calibration_metrics(flip_probability(np.asarray(ranking), cal), flips)}
    if not args.dry_run:
        write_flip_calibration(args.zoom, cal)
    return out


def main(argv: list[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    tune_allocator()  # before JAX starts its threads; see rhaml_jax.allocator
    out = calibrate(args)
    c = out["calibration"]
    f = lambda m: (f"Brier {m['brier']:.4f}  NLL {m['nll']:.4f}  ECE {m['ece']:.4f}  "  # noqa: E731
                   f"AUROC {'-' if m['auroc'] is None else format(m['auroc'], '.3f')}")
    print(f"{c['flips']} of {c['frames']} detected robot frames flipped; P(flip) = sigmoid({c['a']:.3f} + {c['b']:.3f} r)\n"
          f"  raw ranking r : {f(out['ranking'])}\n  calibrated    : {f(out['calibrated'])}\n"
          f"{'(dry run: nothing written)' if args.dry_run else f'written to {args.zoom}'}", file=sys.stderr)
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    run_cli(main)
