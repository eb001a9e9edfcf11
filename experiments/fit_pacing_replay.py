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


def speeds(stored: dict, faces: int) -> dict[str, float | None]:
    """stage -> its seconds over what its counts cost at today's rates (None: the rule charges nothing)."""
    cost = stage_seconds(Plan.from_dict(stored["plan"]), faces)
    return {k: stored["done"][k] / cost[k] if cost[k] > 0 else None for k in STAGES}


def replay(stored: dict, faces: int, speed: dict, pace: bool) -> tuple[float, Plan]:
    """(minutes, the last plan) of today's plan for the stored run's budget at its stages' `speed`."""
    ran = Plan.from_dict(stored["plan"])
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
    ran, speed = Plan.from_dict(stored["plan"]), speeds(stored, faces)
    print("speed against today's rates:", {k: round(v, 2) for k, v in speed.items() if v is not None})
    print(f"as run: {sum(stored['done'].values()) / 60:.1f} min of {ran.budget_minutes:g}; counts {stage_counts(ran)}")
    for pace in (False, True):
        minutes, p = replay(stored, faces, speed, pace)
        print(f"today's plan, {'paced' if pace else 'not paced'}: {minutes:.1f} min; counts {stage_counts(p)}")


if __name__ == "__main__":
    main()
