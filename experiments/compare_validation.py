"""Is candidate B better than A on the validation looks, beyond what the choice of frames explains?

    python experiments/compare_validation.py A B [--looks ours ood mono cad] [--ev /work/runs/validation]
        [--data /work/data] [--block 25] [--draws 2000] [--seed 0] [--extra LOOK SET ...]
        [--metric-a KEY JSON ...] [--metric-b KEY JSON ...] [--out OUT.json]

A and B are labels of `experiments/validate_networks.sh` runs (EV/{label}_{set}.json). Per row
(IML, IML+PGO, IML+IR, IML+IR+PGO; the pose-graph rows refitted from the stored estimates as
`pipeline_from_json.py` does) and figure (the ATE, and the RMS position error alone: a flipped
frame's 180 deg dominates the ATE of the single-frame rows, and a refiner is for the position) the
statistic is the geometric mean over sequences of B's figure over A's: a sequence is the unit of
evidence (session 29: the chroma AMLNet's pooled IML+PGO ATE on our look was 4 % better while one
of the four sequences was 53 % worse), and a ratio weighs a 0.02 m sequence like a 1 m one. Its
2.5-97.5 % interval comes from a paired two-level bootstrap, seeded: each look's sequences drawn
with replacement, then, in each drawn sequence, moving blocks of `--block` consecutive frames
(frames are not independent), the same draws for both labels. With few sequences the interval is
wide: that is the point.

Verdict per row and figure: "better" (the interval below 1), "worse" (above 1), "level" (it
straddles 1), per look and over all looks' sequences together. The rule the defaults are chosen by
(BENCHMARKS.md, "How a default is chosen"): B replaces A only if, over all looks together, some
row's figure is better and none is worse.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pipeline_from_json import detections, fused, metric_overrides  # noqa: E402

from rhaml_jax.data import read_bop  # noqa: E402
from rhaml_jax.metrics import flipped  # noqa: E402
from rhaml_jax.sequence import group_scenes, load_scene  # noqa: E402

LOOKS = {  # the validation sets of experiments/validate_networks.sh, by look
    "ours": ["val_scen_s7_500/circle", "val_scen_s7_500/sine", "val_scen_s8_500/circle", "val_scen_s8_500/sine"],
    "ood": ["val_ood/circle", "val_ood/sine", "val_ood_s2/circle", "val_ood_s2/sine"],  # seeds 1 and 2 (s2: session 32 on)
    "mono": [f"val_mono/{s}_{c}" for c in ("purple", "orange", "grey") for s in ("circle", "sine")],
}
LOOKS["cad"] = [s.replace("val_mono/", "val_mono_cad/") for s in LOOKS["mono"]]  # the one-paint images, the robot's own model (session 46 on)
ROWS = ("IML", "IML+PGO", "IML+IR", "IML+IR+PGO")
FIGURES = ("ATE", "position")  # RMS over the observed frames of the twist (eq. 12) and of the position error alone


def sq_twist(est: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-frame squared norms (N,) of the planar twist log(T_gt^-1 T_est), whose mean's root is the
    ATE (metrics.ate, eq. 12)."""
    import jax.numpy as jnp

    from rhaml_jax.frames import se3_from_xypsi

    t = (se3_from_xypsi(jnp.asarray(gt, jnp.float32)).inverse() @ se3_from_xypsi(jnp.asarray(est, jnp.float32))).log()
    return np.asarray(jnp.sum(t**2, axis=-1), np.float64)


def per_frame(path: Path, data: Path, metrics: dict | None = None) -> dict[str, dict]:
    """Row -> {"q": {"ATE": squared twists, "position": squared position errors (m^2)} over the
    observed frames, "flips" and "detected" robots} of one run; `metrics` override its stored ones."""
    run = json.loads(path.read_text())
    run["metrics"] = run["metrics"] | (metrics or {})
    rows = run["frames"]
    scene = load_scene(list(group_scenes(read_bop(data)).values())[0])
    (det, det_all), obs, gt = detections(rows, run["metrics"]), np.asarray(scene.observed), np.asarray(scene.gt)
    ests = {"IML": (np.array([r["iml_est"] for r in rows]), det), "IML+PGO": (fused(rows, scene, "iml_est", det, run["metrics"]), det)}
    if "ir_est" in rows[0]:
        ests |= {"IML+IR": (np.array([r["ir_est"] for r in rows]), det),
                 "IML+IR+PGO": (fused(rows, scene, "ir_est", det_all, run["metrics"]), det_all)}
    out = {}
    for row, (est, d) in ests.items():
        k = d & obs
        q = {"ATE": sq_twist(est[obs], gt[obs]), "position": np.sum((est[obs, :2] - gt[obs, :2]) ** 2, axis=1)}
        out[row] = {"q": q, "flips": int(np.sum(flipped(est[k, 2], gt[k, 2]))), "detected": int(k.sum())}
    return out


def block_indices(rng, n: int, block: int) -> np.ndarray:
    """A moving-block bootstrap draw of n indices: random starts, `block` consecutive frames each."""
    b = min(block, n)
    starts = rng.integers(0, n - b + 1, size=-(-n // b))
    return (starts[:, None] + np.arange(b)[None]).ravel()[:n]


def compare(a: dict[str, list[np.ndarray]], b: dict[str, list[np.ndarray]], block: int, draws: int, seed: int) -> dict:
    """Look -> sequences' per-frame squared errors of A and of B (paired frame by frame): each
    label's pooled RMS ("rms_a", "rms_b"), the geometric mean of the sequences' RMS ratios B / A,
    and its bootstrap interval (sequences resampled within each look, then blocks within each
    sequence)."""
    rng = np.random.default_rng(seed)
    rms = lambda q: np.sqrt(q.mean())  # noqa: E731
    seqs = [(qa, qb) for look in a for qa, qb in zip(a[look], b[look])]
    geo = float(np.exp(np.mean([np.log(rms(qb) / rms(qa)) for qa, qb in seqs])))
    stats = np.empty(draws)
    for d in range(draws):
        logs = []
        for look in a:
            for j in rng.integers(0, len(a[look]), size=len(a[look])):
                qa, qb = a[look][j], b[look][j]
                i = block_indices(rng, len(qa), block)
                logs.append(np.log(rms(qb[i]) / rms(qa[i])))
        stats[d] = np.exp(np.mean(logs))
    lo, hi = np.percentile(stats, [2.5, 97.5])
    verdict = "better" if hi < 1 else "worse" if lo > 1 else "level"
    pooled = lambda qs: float(np.sqrt(np.concatenate([q for look in qs.values() for q in look]).mean()))  # noqa: E731
    return {"rms_a": pooled(a), "rms_b": pooled(b), "sequences": len(seqs), "ratio": geo,
            "ratio_95": [float(lo), float(hi)], "verdict": verdict,
            "sequence_ratios": [float(rms(qb) / rms(qa)) for qa, qb in seqs]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="the default's label")
    ap.add_argument("b", help="the candidate's label")
    ap.add_argument("--looks", nargs="+", default=list(LOOKS), choices=list(LOOKS))
    ap.add_argument("--ev", type=Path, default=Path("/work/runs/validation"))
    ap.add_argument("--data", type=Path, default=Path("/work/data"))
    ap.add_argument("--block", type=int, default=25)
    ap.add_argument("--draws", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--extra", nargs=2, action="append", default=[], metavar=("LOOK", "SET"),
                    help="also count SET (a folder under --data, scored as EV/LABEL_SET.json) in LOOK; repeatable")
    for role in "ab":
        ap.add_argument(f"--metric-{role}", nargs=2, action="append", default=[], metavar=("KEY", "JSON"),
                        help=f"{role.upper()}'s stored metric KEY set to the JSON value before its pose-graph rows are "
                             "refitted (a pose-graph setting compared on the same estimates: A and B may be one label); repeatable")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    metric = {role: metric_overrides(ap, f"--metric-{role}", getattr(a, f"metric_{role}")) for role in "ab"}
    if a.block < 1 or a.draws < 100:
        ap.error("--block must be >= 1 and --draws >= 100")
    looks_sets = {look: list(sets) for look, sets in LOOKS.items()}
    for look, s in a.extra:
        if look not in looks_sets:
            ap.error(f"--extra {look} {s}: no look {look!r} (one of {', '.join(LOOKS)})")
        looks_sets[look].append(s)
    runs = {}  # (role "a" | "b", set) -> per_frame
    for look in a.looks:
        for role, label in (("a", a.a), ("b", a.b)):
            for s in looks_sets[look]:
                path = a.ev / f"{label}_{s.replace('/', '_')}.json"
                if not path.exists():
                    ap.error(f"{path}: not found (run LABEL={label} experiments/validate_networks.sh)")
                runs[role, s] = per_frame(path, a.data / s, metric[role])
                if role == "b" and len(runs["a", s]["IML"]["q"]["ATE"]) != len(runs["b", s]["IML"]["q"]["ATE"]):
                    ap.error(f"{s}: the two labels' runs cover different frames")
    out = {}
    print("| looks | row | figure (RMS) | A | B | B / A (geometric mean over sequences, 95 %) | verdict | flips A / B | detected A / B |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for looks in [[look] for look in a.looks] + ([a.looks] if len(a.looks) > 1 else []):
        name = "+".join(looks)
        out[name] = {}
        for row in ROWS:
            sets = [s for look in looks for s in looks_sets[look]]
            if not all(row in runs[role, s] for role in "ab" for s in sets):
                continue
            for fig in FIGURES:
                q = {role: {look: [runs[role, s][row]["q"][fig] for s in looks_sets[look]] for look in looks} for role in "ab"}
                r = compare(q["a"], q["b"], a.block, a.draws, a.seed)
                for role in "ab":
                    r[f"flips_{role}"] = sum(runs[role, s][row]["flips"] for s in sets)
                    r[f"detected_{role}"] = sum(runs[role, s][row]["detected"] for s in sets)
                out[name][f"{row} {fig}"] = r
                print(f"| {name} | {row} | {fig} | {r['rms_a']:.4f} | {r['rms_b']:.4f} | {r['ratio']:.3f} "
                      f"({r['ratio_95'][0]:.3f}-{r['ratio_95'][1]:.3f}) | {r['verdict']} | "
                      f"{r['flips_a']} / {r['flips_b']} | {r['detected_a']} / {r['detected_b']} |", flush=True)
    rows = list(out[name].values())  # all looks together (the last entry)
    verdict = "replace" if any(r["verdict"] == "better" for r in rows) and not any(r["verdict"] == "worse" for r in rows) else "keep"
    named = {role: label + "".join(f" {k}={v}" for k, v in getattr(a, f"metric_{role}")) for role, label in (("a", a.a), ("b", a.b))}
    print(f"{named['b']} against {named['a']} over {name}: {verdict} the default")
    if a.out:
        a.out.write_text(json.dumps({"a": a.a, "b": a.b, "metric_a": metric["a"], "metric_b": metric["b"], "block": a.block, "draws": a.draws, "seed": a.seed,
                                     "looks": out, "verdict": verdict}, indent=1))


if __name__ == "__main__":
    main()
