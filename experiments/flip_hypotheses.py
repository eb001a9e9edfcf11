"""Does the IR cascade tell front from back when started both ways? For every frame a stored
`evaluate` run detected, the default IR stage (`refine.load_stage()`, as the pipeline runs it) is
started from IML's estimate and from it turned by 180 deg; per frame are stored both answers'
headings and each run's last coarse step (`|log(r_n / r_(n-1))|`, the convergence check's
figure). Then candidate rules that pick one of the two are scored: flips fixed and made, against
IR started from IML alone.

    python experiments/flip_hypotheses.py --run EV/default_val_scen_s7_500_sine.json /work/data/val_scen_s7_500/sine \
        [--run ...] --out OUT.json

No rule is chosen here: the JSON keeps the per-frame figures, and the rules' counts are printed per
run for validation sets (choose there) and reported elsewhere.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhaml_jax import refine
from rhaml_jax.data import read_bop
from rhaml_jax.metrics import flipped
from rhaml_jax.sequence import group_scenes, load_scene


def run_both(cfg, p, images, K, starts, batch: int = 16):
    """(N, 2, ...) IR results from `starts` (N, 3) and from them turned by 180 deg."""
    turned = starts.at[:, 2].add(jnp.pi)

    @jax.jit
    def go(im, k, s):
        f = lambda i, kk, x: refine.refine(p.refiner, p.mesh, i, kk, x, cfg, fine=p.fine)  # noqa: E731
        return jax.vmap(f)(im, k, s)

    outs = {"iml": [], "turned": []}
    for name, st in (("iml", starts), ("turned", turned)):
        for i in range(0, len(images), batch):
            sl = slice(i, i + batch)
            im = jnp.asarray(images[sl], jnp.float32) / 255.0
            r = go(im, jnp.asarray(K[sl]), st[sl])
            outs[name].append(jax.tree.map(np.asarray, (r.xypsi, r.iterates, r.converged, r.declined)))
    return {k: [np.concatenate([o[j] for o in v]) for j in range(4)] for k, v in outs.items()}


def last_step(iterates, n_iter: int) -> np.ndarray:
    """(N,) the convergence check's figure of each frame's iterates (N, rows, 3): the last coarse step."""
    return np.asarray(jax.vmap(refine._final_step)(iterates[:, n_iter - 1], iterates[:, n_iter]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", nargs=2, action="append", metavar=("EVAL_JSON", "DATA"), required=True)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    cfg, p = refine.load_stage()
    results = {}
    for ev, data in a.run:
        rows = json.loads(Path(ev).read_text())["frames"]
        frames = read_bop(data)
        scenes = list(group_scenes(frames).values())
        if len(scenes) != 1:
            raise SystemExit(f"{data}: one scene expected")
        sc = load_scene(scenes[0])
        keep = np.array([r["detected"] and r["observed"] for r in rows])
        starts = jnp.asarray([r["iml_est"] for r in rows], jnp.float32)[keep]
        out = run_both(cfg, p, sc.seq.images[keep], sc.seq.K[keep], starts)
        gt = np.asarray(sc.gt)[keep]
        n_iter = p.refiner.cfg.n_iter if cfg.n_iter is None else cfg.n_iter
        per = {}
        for name, (xypsi, it, conv, dec) in out.items():
            per[name] = {"psi": xypsi[:, 2].tolist(), "step": last_step(it, n_iter).tolist(), "converged": conv.tolist(),
                         "declined": dec.tolist(), "flipped": flipped(xypsi[:, 2], gt[:, 2]).tolist()}
        per["iml_flipped"] = flipped(starts[:, 2], gt[:, 2]).tolist()
        per["flip_prob"] = [r["iml_flip_prob"] for r, k in zip(rows, keep) if k]
        results[ev] = per
        fa, fb = np.array(per["iml"]["flipped"]), np.array(per["turned"]["flipped"])
        sa, sb = np.array(per["iml"]["step"]), np.array(per["turned"]["step"])
        same = ~(fa ^ fb)  # both runs ended facing the same way (the heading is then decided either way)
        print(f"{ev}: {keep.sum()} frames; IML flips {int(np.sum(per['iml_flipped']))}; IR from IML {int(fa.sum())}, "
              f"from turned {int(fb.sum())}; the two agree on {int(same.sum())}")
        for margin in (1.0, 2.0, 4.0):
            pick_b = sb * margin < sa  # the turned run settled clearly better
            res = np.where(pick_b, fb, fa)
            print(f"  turned where its last step is {margin:g}x smaller: flips {int(res.sum())} "
                  f"(fixed {int(np.sum(fa & ~res))}, made {int(np.sum(~fa & res))}, turned {int(pick_b.sum())})")
    a.out.write_text(json.dumps(results))


if __name__ == "__main__":
    main()
