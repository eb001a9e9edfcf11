"""Our ATE (eq. 12) against the evo package's APE on the same trajectories, from an
`evaluate --json` file. evo is not a dependency: run this with an interpreter that has both
(e.g. a side venv: `python -m venv /tmp/evo && /tmp/evo/bin/pip install evo -e .`).

Where the definitions coincide (estimates with the true heading, so that log(T_gt^-1 T_est) is a
pure translation), eq. 12 is evo's APE RMSE of the translation part; in general eq. 12 adds the
rotation to SE(3)'s log (through its left Jacobian), which evo reports apart.

  python experiments/ate_vs_evo.py --json circle.json
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def _traj(xypsi):
    from evo.core.trajectory import PoseTrajectory3D

    n = len(xypsi)
    pos = np.c_[xypsi[:, 0], xypsi[:, 1], np.zeros(n)]
    q = np.c_[np.cos(xypsi[:, 2] / 2), np.zeros(n), np.zeros(n), np.sin(xypsi[:, 2] / 2)]  # wxyz about z
    return PoseTrajectory3D(positions_xyz=pos, orientations_quat_wxyz=q, timestamps=np.arange(n, dtype=float))


def evo_ape(est, gt, relation: str) -> float:
    from evo.core import metrics

    ape = metrics.APE(getattr(metrics.PoseRelation, relation))
    ape.process_data((_traj(gt), _traj(est)))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", required=True)
    a = ap.parse_args()
    from rhaml_jax import metrics

    frames = [f for f in json.load(open(a.json))["frames"] if f["observed"] and f["est"] is not None]
    est = np.array([f["est"] for f in frames], np.float64)
    gt = np.array([f["gt"] for f in frames], np.float64)
    same_heading = np.c_[est[:, :2], gt[:, 2]]
    out = {"frames": len(frames),
           "true_heading": {"ours_ate": float(metrics.ate(same_heading, gt)),
                            "evo_ape_translation_rmse": evo_ape(same_heading, gt, "translation_part")},
           "as_estimated": {"ours_ate": float(metrics.ate(est, gt)),
                            "evo_ape_translation_rmse": evo_ape(est, gt, "translation_part"),
                            "evo_ape_rotation_angle_rmse_rad": evo_ape(est, gt, "rotation_angle_rad")}}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
