"""Table III (module ablation) on our circle + sine and on the held-out appearance set, with
both information models for the pose graph: the numbers of BENCHMARKS.md's pipeline section.

  python experiments/table_iii.py --ours /work/data --heldout /work/data/heldout --out table_iii.json
      [--combos iml iml,pgo iml,ir iml,ir,pgo] [--frames N] [--amlnet CKPT --zoom CKPT] [--refiner CKPT [--fine-refiner CKPT [CKPT ...]] [--segmenter CKPT]]

Each data root holds `circle/` and `sine/` BOP scenarios (`generate --scenario`, `generate --heldout`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ours", required=True)
    ap.add_argument("--heldout")
    ap.add_argument("--out", required=True)
    ap.add_argument("--combos", nargs="+", default=["iml", "iml,pgo"])
    ap.add_argument("--frames", type=int, default=None, help="first N frames of each scenario (default: all)")
    ap.add_argument("--amlnet", default=None, help="AMLNet checkpoint folder (default: the shipped one)")
    ap.add_argument("--zoom", default=None, help="zoom-stage checkpoint folder (default: the shipped one)")
    ap.add_argument("--refiner", default=None, help="refiner checkpoint folder for ir (default: the shipped cascade)")
    ap.add_argument("--fine-refiner", nargs="+", default=None,
                    help="a cascade's fine refiner after --refiner (fit's networks/fine; several: an ensemble; "
                         "without --refiner the shipped ones run, 'none' turns them off)")
    ap.add_argument("--segmenter", default=None,
                    help="the segmenter whose masks IR aligns to after the cascade (without --refiner the shipped one "
                         "runs, 'none' turns it off)")
    a = ap.parse_args(argv)
    from rhaml_jax import iml, pgo, tune_allocator

    tune_allocator()
    from rhaml_jax.data import read_bop
    from rhaml_jax.demo import run_combination
    from rhaml_jax.sequence import group_scenes

    iml_model, iml_params = iml.load_iml(a.amlnet, a.zoom, zoom_mirror=True)
    sets = {"ours": Path(a.ours)} | ({"heldout": Path(a.heldout)} if a.heldout else {})
    out = {"rows": []}
    for set_name, root in sets.items():
        scenes = [s[: a.frames] for name in ("circle", "sine") for s in group_scenes(read_bop(root / name)).values()]
        for combo in a.combos:
            mods = tuple(combo.split(","))
            infos = ["noise_model", "paper"] if "pgo" in mods else [None]
            for info in infos:
                fusion = pgo.FusionConfig(information=info) if info else None
                t = time.perf_counter()
                m, _ = run_combination(mods, iml_model, iml_params, scenes, root / "circle", fusion, a.refiner,
                                       a.fine_refiner, a.segmenter)
                row = {"set": set_name, "modules": combo, "information": info, **m,
                       "wall_seconds": round(time.perf_counter() - t, 1)}
                print(json.dumps(row), flush=True)
                out["rows"].append(row)
                Path(a.out).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
