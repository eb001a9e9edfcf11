"""End-to-end differentiable ablation: the zoom-in stage fine-tuned with the gradient of the
pose graph's fused error, through refinement (IR) and the pose graph (PGO), against the same
stage fine-tuned alone (its own per-crop loss, `train --stage zoom --init`) on the same images
for the same extra wall time (its steps: the e2e seconds / --alone-step-seconds); then the shipped, the alone and the end-to-end stage each run
IML+IR+PGO on circle + sine (ours and held-out), reporting every stage's error and, per frame,
the change against the shipped stage with a paired bootstrap interval (OUT.npz: the errors;
OUT.png: the figure).

  python experiments/e2e_finetune.py --train /work/data/e2e_rv11 /work/data/e2e_rv12 \
      --val /work/data/e2e_rv13 --ours /work/data/ours --heldout /work/data/heldout \
      --runs /work/runs/e2e --out experiments/results/e2e.json [--steps 300 --window 32 --iml-weight 1]

Training sequences: two-robot rendezvous scenarios (`generate --scenario rendezvous --seed S`,
seeds other than the evaluation's), interleaved in time; each step takes a run of `--window`
consecutive frames with the robot in view, a pure function of (seed, step), so a resumed run is exact.
The loss is the fused pose error over the window's detected frames with the robot in view:
Huber(dx, dy; 5 cm) / 5 cm + (1 - cos dpsi), plus `--iml-weight` times the same error of IML's own
estimates (an anchor; 0 by default). Only the zoom stage's weights move (AMLNet, the
refiner and the BatchNorm statistics stay as shipped); gradient and AdamW update are two jitted
functions (DESIGN.md section 8). Checkpoints every `--ckpt-every` steps (Orbax, atomic) in the
zoom checkpoint layout, so `evaluate --zoom RUN` reads the result.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _paper  # noqa: E402

HUBER_M = 0.05


def load_sequences(roots: list[Path], n: int):
    """Each rendezvous root (two scenes, one per robot's camera) as one interleaved SceneData."""
    from rhaml_jax.data import read_bop
    from rhaml_jax.sequence import group_scenes, interleave, load_scene

    out = []
    for root in roots:
        scenes = list(group_scenes(read_bop(root)).values())
        if len(scenes) != 2:
            raise SystemExit(f"{root}: a rendezvous scenario has two scenes (one per camera), found {len(scenes)}")
        out.append(interleave(load_scene(scenes[0]), load_scene(scenes[1])))
        if out[-1].observed.sum() < n:
            raise SystemExit(f"{root}: {int(out[-1].observed.sum())} frames with the robot in view, fewer than --window {n}")
    return out


def window(seqs, n: int, seed: int, step: int):
    """(Sequence, gt (n, 3), observed (n,)) of n frames in time order: a run of n consecutive
    frames with the robot in view (the others carry no gradient), a pure function of (seed,
    step). Any subset in time order is a valid sequence: each frame carries both odometries."""
    rng = np.random.default_rng([seed, step])
    s = seqs[rng.integers(len(seqs))]
    seen = np.flatnonzero(s.observed)
    start = int(rng.integers(0, len(seen) - n + 1))
    idx = seen[start:start + n]
    return type(s.seq)(*(np.asarray(a)[idx] for a in s.seq)), s.gt[idx].astype(np.float32), s.observed[idx]


def pose_error(est, gt):
    """(n,) Huber(dx, dy; 5 cm) / 5 cm + (1 - cos dpsi) of planar estimates (n, 3) against truth."""
    import jax.numpy as jnp
    import optax

    from rhaml_jax import planar

    d = planar.between(gt, est)  # (n, 3) error in the true pose's frame
    return optax.huber_loss(d[:, :2], delta=HUBER_M).sum(-1) / HUBER_M + (1.0 - jnp.cos(d[:, 2]))


def make_fns(model, tx, iml_weight: float = 0.0):
    """(grad_fn, update_fn), jitted apart: grad_fn(zoom_params, params, seq, gt, observed) ->
    ((loss, fused abs errors (n, 3)), grads); update_fn(grads, opt_state, zoom_params). The loss
    is the fused error, plus `iml_weight` times the same error of IML's own estimates (an
    anchor that keeps the stage's output meaningful on its own; 0: the fused error alone)."""
    import jax
    import jax.numpy as jnp
    import optax

    from rhaml_jax import pipeline, planar

    def loss(zp, params, seq, gt, observed):
        iml = params.iml._replace(zoom=(zp, params.iml.zoom[1]))
        r = pipeline.run(model, params._replace(iml=iml), seq)
        w = (observed & r.detected).astype(jnp.float32)
        e = pose_error(r.xypsi, gt) + iml_weight * pose_error(r.iml.xypsi, gt)
        return jnp.sum(w * e) / jnp.maximum(w.sum(), 1.0), jnp.abs(planar.between(gt, r.xypsi)) * w[:, None]

    def update(grads, opt_state, zp):
        upd, opt_state = tx.update(grads, opt_state, zp)
        return optax.apply_updates(zp, upd), opt_state

    return jax.jit(jax.value_and_grad(loss, has_aux=True)), jax.jit(update)


def shipped_zoom() -> Path:
    """The default IML's zoom-in stage (`iml.DEFAULT_ZOOM`): what both fine-tunings start from
    and what they are compared with, beside the default AMLNet and IR cascade."""
    from rhaml_jax import iml
    from rhaml_jax.amlnet import shipped_checkpoint

    return shipped_checkpoint(iml.DEFAULT_ZOOM)


def train_e2e(a, run_dir: Path) -> dict:
    """The end-to-end fine-tuning (resumable): {"seconds" (steps after each process's first,
    which is mostly compilation), "steps"}."""
    import jax

    from rhaml_jax import iml, pipeline, refine
    from rhaml_jax.amlnet.checkpoint import Checkpoints
    from rhaml_jax.amlnet.steps import make_optimizer

    seqs = load_sequences([Path(p) for p in a.train], a.window)
    iml_model, iml_params = iml.load_iml(zoom=shipped_zoom(), zoom_mirror=True)
    refine_cfg, refiner = refine.load_stage(None, a.train[0])
    mods = tuple(a.through.split(","))
    model = pipeline.PipelineModel(iml_model, pipeline.PipelineConfig(modules=mods, chunk=a.window),
                                   refine_cfg if "ir" in mods else None)
    params = pipeline.PipelineParams(iml_params, refiner if "ir" in mods else None)
    tx = make_optimizer(a.lr, a.steps, weight_decay=0.05, warmup=a.warmup, clip=a.clip)
    grad_fn, update_fn = make_fns(model, tx, a.iml_weight)
    zp, stats = iml_params.zoom
    opt_state = tx.init(zp)

    ck = Checkpoints(run_dir, keep=2)
    src = Checkpoints(shipped_zoom(), read_only=True)
    meta = {k: v for k, v in src.meta().items() if k in ("model_config", "robot")}
    src.close()
    meta |= {"weights_only": False, "train_config": {"clip": a.clip, "lr": a.lr, "steps": a.steps, "window": a.window,
                                                     "through": a.through, "seed": a.seed,
                                                     "iml_weight": a.iml_weight}}
    start, seconds = 0, 0.0
    log_path = run_dir / "metrics.jsonl"
    if ck.latest_step() is not None:
        start = ck.latest_step()
        stored = ck.meta(start)
        # a longer --steps extends a run (its schedule is then not the planned one); nothing else may differ
        diff = {k: (v, meta["train_config"][k]) for k, v in stored["train_config"].items()
                if k != "steps" and v != meta["train_config"][k]}
        if diff:
            raise SystemExit(f"{run_dir}: holds a run with other settings (stored, given): {diff}")
        st = ck.restore(start, {"params": zp, "batch_stats": stats, "opt_state": opt_state})
        zp, opt_state = st["params"], st["opt_state"]
        seconds = stored.get("seconds", 0.0)
        # steps logged after the checkpoint (a killed run) are done again: drop their lines
        kept = [line for line in log_path.read_text().splitlines() if json.loads(line)["step"] <= start]
        log_path.write_text("".join(line + "\n" for line in kept))
    log = log_path.open("a")
    for step in range(start, a.steps):
        t = time.perf_counter()
        seq, gt, observed = window(seqs, a.window, a.seed, step)
        (value, err), g = grad_fn(zp, params, seq, gt, observed)
        zp, opt_state = update_fn(g, opt_state, zp)
        value = float(value)
        if step > start:  # the first step of a process is mostly compilation: not budget
            seconds += time.perf_counter() - t
        n = max(int(observed.sum()), 1)
        err = np.asarray(err).sum(0) / n
        log.write(json.dumps({"step": step + 1, "loss": value, "dx_cm": 100 * float(err[0]), "dy_cm": 100 * float(err[1]),
                              "dpsi_deg": float(np.degrees(err[2])), "seconds": round(seconds, 1)}) + "\n")
        log.flush()
        if (step + 1) % a.ckpt_every == 0 or step + 1 == a.steps:
            ck.save(step + 1, {"params": zp, "batch_stats": stats, "opt_state": opt_state},
                    meta | {"step": step + 1, "seconds": seconds})
        if (step + 1) % 10 == 0:
            print(f"e2e step {step + 1}/{a.steps}: loss {value:.4f} ({seconds:.0f} s)", flush=True)
    log.close()
    ck.close()
    jax.clear_caches()
    return {"seconds": round(seconds, 1), "steps": a.steps}


def bop_for_alone(train: list[str], val: str, out: Path) -> Path:
    """A BOP set whose train split holds the training scenarios' scenes and whose val split the
    validation scenario's (symbolic links), the layout `train --stage zoom` reads."""
    if (out / "camera.json").exists():
        return out
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "train").mkdir(parents=True)
    (tmp / "val").mkdir()
    shutil.copy(Path(train[0]) / "camera.json", tmp / "camera.json")
    shutil.copytree(Path(train[0]) / "models", tmp / "models")
    k = 0
    for root in train:
        for scene in sorted((Path(root) / "test").iterdir()):
            (tmp / "train" / f"{k:06d}").symlink_to(scene.resolve())
            k += 1
    for j, scene in enumerate(sorted((Path(val) / "test").iterdir())):
        (tmp / "val" / f"{j:06d}").symlink_to(scene.resolve())
    tmp.rename(out)
    return out


def evaluate_stages(zoom_dirs: dict, sets: dict) -> tuple[dict, dict]:
    """IML+IR+PGO with the shipped AMLNet and refiner and each zoom stage (same config: one
    compiled pipeline serves them all): (the IML, IR and fused metrics per stage and set, as
    evaluate scores them; per-frame abs errors {"name/set/stage": (n, 3)} of the frames with
    the robot in view, in frame order, for paired comparisons)."""
    from rhaml_jax import iml, metrics, pipeline, refine
    from rhaml_jax.amlnet import load_model
    from rhaml_jax.evaluate import score
    from rhaml_jax.sequence import run_scenes

    first = next(iter(zoom_dirs.values()))
    iml_model, iml_params = iml.load_iml(zoom=first, zoom_mirror=True)
    refine_cfg, refiner = refine.load_stage(None, _paper.data_root(next(iter(sets.values()))[0][0]))
    model = pipeline.PipelineModel(iml_model, pipeline.PipelineConfig(modules=("iml", "ir", "pgo")), refine_cfg)
    out, frames = {}, {}
    for name, zoom_dir in zoom_dirs.items():
        net, zp, zs = load_model(zoom_dir)
        if net.cfg != iml_model.zoom.cfg:
            raise SystemExit(f"{zoom_dir}: zoom config {net.cfg.name}, not {iml_model.zoom.cfg.name}")
        params = pipeline.PipelineParams(iml_params._replace(zoom=(zp, zs)), refiner)
        out[name] = {}
        for set_name, scenes in sets.items():
            runs, _, seconds = run_scenes(model, params, scenes)
            cat = lambda f: np.concatenate([f(r) for r in runs])  # noqa: E731
            det, obs, gt = cat(lambda r: r.result.detected), cat(lambda r: r.data.observed), cat(lambda r: r.data.gt)
            m = {}
            for stage, f in (("iml", lambda r: r.result.iml.xypsi), ("ir", lambda r: r.result.ir.xypsi),
                             ("fused", lambda r: r.result.xypsi)):
                est = cat(f)
                m[stage] = score(est, det, obs, gt)
                frames[f"{name}/{set_name}/{stage}"] = np.asarray(metrics.abs_errors(est[obs], gt[obs]))
            out[name][set_name] = m | {"fps": float(len(obs) / seconds)}
            print(f"{name:8s} {set_name:8s} " + "  ".join(f"{st} {m[st]['dx_cm'][0]:.2f}/{m[st]['dy_cm'][0]:.2f}/"
                                                         f"{m[st]['dpsi_deg'][0]:.2f} ATE {m[st]['ate']:.3f}"
                                                         for st in ("iml", "ir", "fused")), flush=True)
    return out, frames


def paired_change(base: np.ndarray, new: np.ndarray, draws: int = 2000, seed: int = 0) -> dict:
    """Change in mean |dx|, |dy| (cm), |dpsi| (deg) from `base` to `new` (abs errors (n, 3) of
    the same frames) with a 95 % paired bootstrap interval over the frames: the test-set part
    of the noise (not the training seed's)."""
    d = (np.asarray(new) - np.asarray(base)) * np.array([100.0, 100.0, 180.0 / np.pi])
    idx = np.random.default_rng(seed).integers(0, len(d), (draws, len(d)))
    boot = d[idx].mean(1)  # (draws, 3)
    lo, hi = np.percentile(boot, [2.5, 97.5], axis=0)
    return {k: [float(d[:, i].mean()), float(lo[i]), float(hi[i])] for i, k in enumerate(("dx_cm", "dy_cm", "dpsi_deg"))}


def run(a) -> dict:
    from rhaml_jax import tune_allocator
    from rhaml_jax.amlnet.checkpoint import checkpoint_meta

    tune_allocator()
    runs = Path(a.runs)
    e2e_dir = runs / "e2e"
    e2e_dir.mkdir(parents=True, exist_ok=True)
    res = {"protocol": {k: v for k, v in vars(a).items()}}
    res["e2e"] = train_e2e(a, e2e_dir)
    if a.alone_run:  # the baseline of an earlier run with the same budget
        alone_dir = Path(a.alone_run)
        res["alone"] = {"reused": str(alone_dir), "val": _paper.last_validation(alone_dir / "metrics.jsonl")}
    else:  # the alone stage gets the same wall time: steps from the rate its own training reaches here
        alone_dir = runs / "alone"
        alone_steps = a.alone_steps or max(1, int(res["e2e"]["seconds"] / a.alone_step_seconds))
        data = bop_for_alone(a.train, a.val, runs / "alone_bop")
        start = checkpoint_meta(shipped_zoom())  # its own config and its training's loss weights
        res["alone"] = _paper.train("zoom", start["model_config"]["name"], data, alone_dir, alone_steps, a.seed,
                                    "--init", str(shipped_zoom()), "--lr", str(a.lr), "--warmup", str(a.warmup),
                                    "--batch", "32", "--w-xy", *map(str, start["train_config"]["w_xy"]),
                                    "--val-every", str(alone_steps), "--val-batches", "2", *a.train_args)
        res["alone"]["steps"] = alone_steps
        if res["alone"]["seconds"] < res["e2e"]["seconds"]:  # its wall time includes start-up: an upper bound
            print(f"warning: the alone stage trained for {res['alone']['seconds']:.0f} s, less than the end-to-end "
                  f"run's {res['e2e']['seconds']:.0f} s: this machine takes at most "
                  f"{res['alone']['seconds'] / alone_steps:.3f} s per step; set --alone-step-seconds to that and "
                  f"delete {alone_dir} to give it the same time", file=sys.stderr)
    _paper.write_json(Path(a.out), res)
    sets = _paper.scenario_sets(a.ours, a.heldout, a.frames)
    zoom_dirs = {"shipped": shipped_zoom(), "alone": alone_dir, "e2e": e2e_dir}
    zoom_dirs |= dict(c.split("=", 1) for c in a.compare)
    res["eval"], frames = evaluate_stages(zoom_dirs, sets)
    _paper.write_npz(Path(a.out).with_suffix(".npz"), frames)
    res["change_vs_shipped"] = {f"{name}/{key.split('/', 1)[1]}": paired_change(frames[f"shipped/{key.split('/', 1)[1]}"], e)
                                for key, e in frames.items() if (name := key.split("/")[0]) != "shipped"}
    _paper.write_json(Path(a.out), res)
    figure(res, Path(a.out).with_suffix(".png"))
    return res


def figure(res: dict, path: Path) -> None:
    """Per variant of the zoom stage, each pipeline stage's mean |dx|, |dy| (cm) and |dpsi| (deg)
    on our set (log scale: IML's decimetres beside the fused millimetres)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, stages = list(res["eval"]), ("iml", "ir", "fused")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for ax, (metric, label) in zip(axes, (("dx_cm", "abs dx (cm)"), ("dy_cm", "abs dy (cm)"), ("dpsi_deg", "abs dpsi (deg)"))):
        for i, name in enumerate(names):
            v = [res["eval"][name]["ours"][st][metric][0] for st in stages]
            ax.bar(np.arange(3) + (i - (len(names) - 1) / 2) * 0.8 / len(names), v, 0.8 / len(names), label=name)
        ax.set_xticks(range(3), ["IML", "IML+IR", "IML+IR+PGO"])
        ax.set_yscale("log")
        ax.set_title(label, fontsize=9)
        ax.grid(axis="y", alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    fig.suptitle("Zoom stage fine-tuned end to end vs alone: each stage's error on circle + sine (ours)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def parse(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", nargs="+", required=True, help="rendezvous scenario roots to fine-tune on")
    ap.add_argument("--val", required=True, help="a rendezvous root: the alone training's val split")
    ap.add_argument("--ours", required=True)
    ap.add_argument("--heldout", default=None)
    ap.add_argument("--runs", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--through", default="iml,ir,pgo", help="modules the gradient passes through (iml,pgo: without IR)")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--window", type=int, default=32, help="frames per step (all with the robot in view)")
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--clip", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ckpt-every", type=int, default=25)
    ap.add_argument("--iml-weight", type=float, default=0.0, help="add this times IML's own error to the loss (0: fused only)")
    ap.add_argument("--alone-run", default=None, help="reuse this alone run (from an earlier call with the same budget)")
    ap.add_argument("--compare", nargs="*", default=[], help="more zoom stages to evaluate, as NAME=CHECKPOINT_DIR")
    ap.add_argument("--alone-steps", type=int, default=None, help="default: the e2e wall time / --alone-step-seconds")
    ap.add_argument("--alone-step-seconds", type=float, default=0.25,
                    help="a zoom training step of 32 crops on this machine (0.25 s in session 8, 0.15 s on "
                         "session 33's: BENCHMARKS.md; a warning says when it was too high)")
    ap.add_argument("--frames", type=int, default=None, help="first N frames of each evaluation scenario")
    ap.add_argument("--train-args", nargs=argparse.REMAINDER, default=[])
    return ap.parse_args(argv)


def main(argv=None):
    return run(parse(argv))


if __name__ == "__main__":
    main()
