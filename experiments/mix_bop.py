"""Mixes BOP training sets of one robot and camera into one, by symlinking their scene folders
(`rhaml_jax.data.mix_sets`; nothing is copied).

  python experiments/mix_bop.py --out /work/data/mix /work/data/v2_train /work/data/v1_train
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rhaml_jax.data import mix_sets


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("sets", type=Path, nargs="+")
    a = ap.parse_args()
    counts = mix_sets(a.out, a.sets)
    print(f"{a.out}: " + ", ".join(f"{split} {n} scenes" for split, n in counts.items()))


if __name__ == "__main__":
    main()
