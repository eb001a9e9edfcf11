"""Every network for one robot, in one resumable run (`python -m rhaml_jax.fit`): its training
data, AMLNet, the zoom stage and the refiner, their evaluation on our scenarios and the held-out
appearance set, and a report.

- `make_plan(budget_minutes, size, faces, scale)`: the budget rule (data sizes, steps, evaluation
  sizes; the robot's distances relative to the Pioneer's are `RobotModel.world_scale`);
- `run_fit(robot, out, plan, resume)`: the stages (`STAGES`), each recorded when done;
- `load_checked_robot(spec)`: the robot, refused when it has no visual geometry or an
  implausible size; `write_report(out, model, plan)`.
"""

from rhaml_jax.fitting._plan import Plan, make_plan
from rhaml_jax.fitting._report import write_report
from rhaml_jax.fitting._run import STAGES, FitState, load_checked_robot, run_fit

__all__ = ["FitState", "Plan", "STAGES", "load_checked_robot", "make_plan", "run_fit", "write_report"]
