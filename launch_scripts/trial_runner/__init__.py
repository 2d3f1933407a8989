"""Running laundry-grasping trials: the orchestration around the task of ``sim.laundry``.

- ``trial``: ``run_trial(seed, TrialConfig)``, the one trial function (pool, Ray, tests):
  it starts the services, streams the scene's frames to them and records the outcome.
- ``unfold``: the unfold task (``TrialConfig(task="unfold")``): the cloth tracked while one
  arm lifts it by a corner, a second arm taking an adjacent corner, the edge stretched.
- ``report``: REPORT.json and the markdown summary, with Wilson intervals.

The task itself (scene, controller policy, judge) is ``sim.laundry``'s. The command line
is ``python -m launch_scripts.trials``.
"""

from launch_scripts.trial_runner.trial import TrialConfig, run_trial

__all__ = ["TrialConfig", "run_trial"]
