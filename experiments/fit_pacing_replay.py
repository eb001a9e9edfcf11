"""Replays a finished `fit` run through today's budget rule and pacing: each stage's speed relative to
today's rates (its seconds over what its counts cost at them) is applied to today's plan for the
same budget, unpaced and paced as `run_fit` paces (BENCHMARKS.md, "Pacing").

    python experiments/fit_pacing_replay.py RUN/fit.json MESH_FACES
"""

from __future__ import annotations

import json
import sys

from rhaml_jax.fitting._plan import Plan, make_plan, paced, slowness, stage_counts, stage_seconds
from rhaml_jax.fitting._run import STAGES


def replay(stored: dict, faces: int, pace: bool) -> tuple[float, Plan]:
    """(minutes, the last plan) of today's plan for the stored run's budget at its stages' speed."""
    ran = Plan.from_dict(stored["plan"])
    cost = stage_seconds(ran, faces)
    speed = {k: stored["done"][k] / cost[k] if cost[k] > 0 else None for k in STAGES}
    plan = p = make_plan(ran.budget_minutes, ran.size, faces, ran.scale, ran.warm_start)
    done, t = {}, 0.0
    for k in STAGES:
        if pace:
            p, _ = paced(p, list(STAGES[STAGES.index(k):]), p.budget_minutes * 60 - t, slowness(p, done, faces), faces, plan)
        # a stage the rule charges nothing (the report) takes what it took
        done[k] = stage_seconds(p, faces)[k] * speed[k] if speed[k] is not None else stored["done"][k]
        t += done[k]
    return t / 60, p


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: python experiments/fit_pacing_replay.py RUN/fit.json MESH_FACES")
    stored, faces = json.loads(open(sys.argv[1]).read()), int(sys.argv[2])
    ran = Plan.from_dict(stored["plan"])
    cost = stage_seconds(ran, faces)
    print("speed against today's rates:", {k: round(stored["done"][k] / cost[k], 2) for k in STAGES if cost[k] > 0})
    print(f"as run: {sum(stored['done'].values()) / 60:.1f} min of {ran.budget_minutes:g}; counts {stage_counts(ran)}")
    for pace in (False, True):
        minutes, p = replay(stored, faces, pace)
        print(f"today's plan, {'paced' if pace else 'not paced'}: {minutes:.1f} min; counts {stage_counts(p)}")


if __name__ == "__main__":
    main()
