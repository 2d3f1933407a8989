"""Laundry-grasping trials: one trial end to end through the ZeroMQ services, and its parts.

- ``trial``: ``run_trial(seed, TrialConfig)``, the one trial function (pool, Ray, tests).
- ``judge``: success by ground truth (``judge``), Wilson intervals (pure).
- ``segment``: the cloth against a picture of the empty table (pure).
- ``processes``: the trial's child processes, started with bounded waits, always stopped.
- ``pictures``: the plan drawn on the frame, the grasp before and after the lift (pure).
- ``report``: REPORT.json and the markdown summary (pure, plus writing them).

The command line is ``python -m launch_scripts.trials``.
"""

from launch_scripts.trial_runner.judge import (
    TOLERANCE_M,
    Judgement,
    judge,
    wilson_interval,
)
from launch_scripts.trial_runner.trial import (
    TrialConfig,
    View,
    best_candidate,
    lowest_point_when_held,
    run_trial,
)

__all__ = ["TOLERANCE_M", "Judgement", "TrialConfig", "View", "best_candidate", "judge", "lowest_point_when_held",
           "run_trial", "wilson_interval"]
