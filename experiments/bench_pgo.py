"""Pose-graph benchmarks, ours and GTSAM side by side in one run, plus the outlier table.

    .venv/bin/python experiments/bench_pgo.py --out runs/bench_pgo.md [--repeats 3] [--datasets M3500,intel]

Ours: `rhaml_jax.pgo.optimize` in float64, compile timed apart (the first call), then the
median over repeats of the compiled solve. GTSAM 4.3 (pip): graph from our parsed file (same
initial guess), tight prior on the first pose as in ../shared/data/pgo/REFERENCE_VALUES.md,
default Gauss-Newton (or Levenberg-Marquardt where its GN fails: MITb, ais2klinik) params,
median over repeats of optimizer construction + optimize(). Both report GTSAM's cost.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rhaml_jax.pgo import RhamlPGOConfig, SolverConfig, optimize, read_g2o, rhaml_pgo_jit, rhaml_pose_graph  # noqa: E402
from rhaml_jax.pgo import simulate_rendezvous  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "pgo"
DEFAULT = "ring,MITb,FR079,CSAIL,FRH,intel,ringCity,M3500,manhattan,city10000,ais2klinik"
LM_ONLY = {"MITb", "ais2klinik"}  # GTSAM's GN stops on an indeterminate system there


def gtsam_run(graph, method, repeats):
    import gtsam

    fg = gtsam.NonlinearFactorGraph()
    for (i, j), z, L in zip(graph.edges, graph.measurements, graph.information):
        fg.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), gtsam.noiseModel.Gaussian.Information(L)))
    fg.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*graph.poses[0]),
                                  gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))))
    init = gtsam.Values()
    for k, p in enumerate(graph.poses):
        init.insert(k, gtsam.Pose2(*p))
    times, err, its = [], None, None
    for _ in range(repeats):
        t = time.perf_counter()
        if method == "lm":
            opt = gtsam.LevenbergMarquardtOptimizer(fg, init, gtsam.LevenbergMarquardtParams())
        else:
            opt = gtsam.GaussNewtonOptimizer(fg, init, gtsam.GaussNewtonParams())
        res = opt.optimize()
        times.append(time.perf_counter() - t)
        err, its = fg.error(res), opt.iterations()
    return statistics.median(times), err, its


def bench_datasets(names, repeats, rows):
    for name in names:
        path = DATA / f"{name}.g2o"
        if not path.exists():
            print(f"skip {name}: {path} missing", file=sys.stderr)
            continue
        graph = read_g2o(path)
        method = "lm" if name in LM_ONLY else "gn"
        cfg = SolverConfig(method=method, relative_tolerance=1e-5, absolute_tolerance=1e-5)
        first = optimize(graph, cfg)
        runs = [optimize(graph, cfg) for _ in range(repeats)]
        ours_t = statistics.median(r.seconds for r in runs)
        g_t, g_err, g_its = gtsam_run(graph, method, repeats)
        rows.append((name, graph.num_nodes, graph.num_edges, method, first.final_cost, first.iterations, ours_t,
                     first.compile_seconds, g_err, g_its, g_t))
        print(rows[-1], flush=True)


def _time_rhaml(rv, repeats, config):
    """(median s, compile wall s, compile CPU s, result) of `rhaml_pgo_jit` on `rv`."""
    t, c = time.perf_counter(), time.process_time()
    compiled = rhaml_pgo_jit.lower(rv, config=config).compile()
    compile_s, compile_cpu = time.perf_counter() - t, time.process_time() - c
    out = jax.block_until_ready(compiled(rv))
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(compiled(rv))
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), compile_s, compile_cpu, out


def bench_rhaml(K, repeats):
    """Ours: `rhaml_pgo_jit` (Algorithm 1 end to end) on the padded K-rendezvous input, with
    each band solver, in float64 and in float32 (JAX's default, what the pipeline runs);
    GTSAM: Gauss-Newton on the same graph (`rhaml_pose_graph`, same initial guess).
    Returns ({(band solver, dtype): (median s, compile s, compile CPU s, iterations, cost)},
    (GTSAM median s, GTSAM cost, GTSAM iterations))."""
    sim = simulate_rendezvous(K, seed=0)
    rv64 = jax.tree.map(jnp.asarray, sim.rendezvous)
    out = {}
    for how in ("twisted", "thomas"):
        cfg = RhamlPGOConfig()
        cfg = dataclasses.replace(cfg, solver=dataclasses.replace(cfg.solver, band_solver=how))
        for dt in ("float64", "float32"):
            with jax.enable_x64(dt == "float64"):
                rv = rv64 if dt == "float64" else jax.tree.map(
                    lambda a: jnp.asarray(a, jnp.float32) if a.dtype == np.float64 else jnp.asarray(a), sim.rendezvous)
                t, c, ccpu, res = _time_rhaml(rv, repeats, cfg)
                out[how, dt] = (t, c, ccpu, int(res.iterations), float(res.final_cost))
                print((how, dt), out[how, dt], flush=True)
    return out, gtsam_run(rhaml_pose_graph(sim.rendezvous), "gn", repeats)


def outlier_table(K, seeds):
    kernels = {
        "none": RhamlPGOConfig(),
        "huber (k=1)": RhamlPGOConfig(solver=SolverConfig(linear_solver="banded", robust="huber", robust_delta=1.0,
                                                          max_iterations=50)),
        "cauchy (k=1)": RhamlPGOConfig(solver=SolverConfig(linear_solver="banded", robust="cauchy", robust_delta=1.0,
                                                           max_iterations=50)),
    }
    rows = []
    for frac in (0.0, 0.1, 0.3):
        for kname, cfg in kernels.items():
            et, er = [], []
            for seed in range(seeds):
                sim = simulate_rendezvous(K, seed=100 + seed, outlier_fraction=frac)
                out = rhaml_pgo_jit(jax.tree.map(jnp.asarray, sim.rendezvous), config=cfg)
                e = np.asarray(out.a0_T_b0) - sim.a0_T_b0
                et.append(100 * np.hypot(e[0], e[1]))
                er.append(np.rad2deg(abs(np.arctan2(np.sin(e[2]), np.cos(e[2])))))
            rows.append((frac, kname, np.median(et), np.mean(et), np.max(et), np.median(er), np.max(er)))
            print(rows[-1], flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("runs/bench_pgo.md"), help="markdown file to write")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats per dataset (median)")
    ap.add_argument("--datasets", default=DEFAULT, help="comma-separated names in ../shared/data/pgo")
    ap.add_argument("--rhaml-k", type=int, default=100, help="rendezvous in the RHAML-size graph")
    ap.add_argument("--rhaml-repeats", type=int, default=500, help="timed runs of the RHAML graph (median)")
    ap.add_argument("--outlier-seeds", type=int, default=10, help="sequences per outlier-table cell")
    ap.add_argument("--skip-datasets", action="store_true", help="only the RHAML graph and the outlier table")
    args = ap.parse_args()
    cmd = "python experiments/bench_pgo.py " + " ".join(sys.argv[1:])
    lines = [f"Command: `{cmd}` (float64; medians of {args.repeats} runs; compile timed apart)", ""]
    if not args.skip_datasets:
        rows = []
        bench_datasets([n for n in args.datasets.split(",") if n], args.repeats, rows)
        lines += ["| dataset | poses | edges | method | ours final cost | ours iters | ours s (compiled) | ours compile s "
                  "| GTSAM final cost | GTSAM iters | GTSAM s | GTSAM / ours time |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for n, N, E, m, c, it, t, ct, gc, git, gt in rows:
            lines.append(f"| {n} | {N} | {E} | {m} | {c:.6g} | {it} | {t:.3f} | {ct:.1f} | {gc:.6g} | {git} | {gt:.3f} "
                         f"| {gt / t:.2f} |")
        lines.append("")
    res, (gt, gcost, git) = bench_rhaml(args.rhaml_k, args.rhaml_repeats)
    lines += [f"RHAML two-robot graph, {args.rhaml_k} rendezvous ({2 * args.rhaml_k + 2} poses, "
              f"{3 * args.rhaml_k} edges), `rhaml_pgo_jit` (Algorithm 1 end to end, ladder solver), "
              f"medians over {args.rhaml_repeats} runs; GTSAM Gauss-Newton on the same graph (`rhaml_pose_graph`, "
              f"same initial guess; graph construction not included): median {gt * 1e3:.2f} ms, {git} iterations, "
              f"final cost {gcost:.6g}. Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.", "",
              "| band solver | dtype | median ms | GTSAM / ours | iterations | final cost | compile s (CPU s) |",
              "|---|---|---|---|---|---|---|"]
    for (how, dt), (t, ct, ccpu, it, cost) in res.items():
        lines.append(f"| {how} | {dt} | {t * 1e3:.2f} | {gt / t:.2f} | {it} | {cost:.6g} | {ct:.1f} ({ccpu:.1f}) |")
    lines.append("")
    orows = outlier_table(40, args.outlier_seeds)
    lines += [f"Outliers: {args.outlier_seeds} simulated sequences of 40 rendezvous per row; a fraction of the mutual "
              "observations replaced by wrong ones (off by 1-3 m and 90-180 deg); error of A_0 T B_0.", "",
              "| wrong observations | kernel | median cm | mean cm | max cm | median deg | max deg |",
              "|---|---|---|---|---|---|---|"]
    for frac, k, med, mean, mx, rmed, rmx in orows:
        lines.append(f"| {int(frac * 100)} % | {k} | {med:.1f} | {mean:.1f} | {mx:.1f} | {rmed:.2f} | {rmx:.2f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
