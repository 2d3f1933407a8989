"""A trial's settings: one TrackerConfig and one GraspPlannerConfig, and how each reaches its service."""

import dataclasses
import json
import math

import numpy as np
import pytest

from grasping import GraspPlannerConfig
from launch_scripts.planner_service import arguments_from_config, build_parser, config_from_args
from launch_scripts.trial_runner.trial import (
    TRIAL_TRACKER,
    TrialConfig,
    tracker_parameters_to_send,
    trial_config_dict,
)
from perception.geometry import look_at
from perception.parameters import tracker_parameters
from perception.tracker import TrackerConfig


def test_the_tracker_travels_as_the_parameters_that_differ_from_the_service():
    started = tracker_parameters(TrackerConfig())
    assert tracker_parameters_to_send(TRIAL_TRACKER, started) == {"spacing_m": 0.015, "use_boundary": False,
                                                                   "features": "klt"}
    # nothing to send once the service runs it
    assert tracker_parameters_to_send(TRIAL_TRACKER, tracker_parameters(TRIAL_TRACKER)) == {}
    # a setting a request cannot carry is refused, not silently dropped
    with pytest.raises(ValueError, match="TrialConfig.tracker.outlier_radii_m"):
        tracker_parameters_to_send(TrackerConfig(outlier_radii_m=(0.1,)), started)


def test_the_planner_options_give_the_service_the_trial_planner():
    config = GraspPlannerConfig(pinch_inset_m=0.0, T_world_cam=look_at([0.2, -1.1, 1.9], [0.0, 0.0, 0.74]),
                                up_world=np.array([0.0, 0.0, 1.0]), workspace_min_world=[-0.8, -0.6, 0.7123456789],
                                workspace_max_world=[0.8, 0.6, 2.25], corner_max_angle_rad=math.radians(120.0),
                                min_score=0.1, tip_search_radius_m=0.1, tip_max_step_m=0.03)
    served = config_from_args(build_parser().parse_args(arguments_from_config(config)))
    for f in dataclasses.fields(GraspPlannerConfig):
        assert np.array_equal(getattr(served, f.name), getattr(config, f.name)), f.name
    # a camera looking straight down: its rotation holds tiny negative numbers that, written
    # "-1.2e-16", argparse would take for an option
    c, s = math.cos(-math.pi), math.sin(-math.pi)
    down = np.array([[1.0, 0.0, 0.0, 0.1], [0.0, c, -s, -0.2], [0.0, s, c, 1.9], [0.0, 0.0, 0.0, 1.0]])
    assert down[2, 1] < 0 and abs(down[2, 1]) < 1e-15
    served = config_from_args(build_parser().parse_args(arguments_from_config(GraspPlannerConfig(T_world_cam=down))))
    assert np.array_equal(served.T_world_cam, down)
    unbounded = config_from_args(build_parser().parse_args(arguments_from_config(GraspPlannerConfig())))
    assert np.all(np.isinf(unbounded.workspace_min_world))
    with pytest.raises(ValueError, match="GraspPlannerConfig.clearance_radius_m: the planner service has no option"):
        arguments_from_config(GraspPlannerConfig(clearance_radius_m=0.2))


def test_the_settings_are_strict_json():
    settings = trial_config_dict(TrialConfig())
    text = json.dumps(settings, allow_nan=False)
    assert json.loads(text)["tracker"]["spacing_m"] == 0.015
    assert settings["planner"]["workspace_min_world"] == [None, None, None]  # unbounded
    assert settings["planner"]["pinch_inset_m"] == 0.0 and settings["kind"] == "corner"


def test_tracking_error_follows_only_the_mesh_the_plan_was_made_on():
    from ipc.messages import MeshEstimate
    from launch_scripts.trial_runner.trial import _one_mesh_run

    def estimate(n):
        canonical = np.c_[np.arange(n, dtype=np.float64), np.zeros((n, 2))]
        return MeshEstimate(vertices=canonical.copy(), faces=np.zeros((0, 3), np.int32),
                            boundary=np.zeros(0, np.int32), canonical=canonical, confidence=1.0, lost=False)

    # frames 0-2 on a 5-vertex mesh, found again at frame 3 with a 7-vertex one
    estimates = {0: estimate(5), 1: estimate(5), 2: estimate(5), 3: estimate(7), 4: estimate(7), 6: estimate(7)}
    assert _one_mesh_run(estimates, 4) == [3, 4]  # neither the old mesh's frames nor later ones
    assert _one_mesh_run(estimates, 6) == [3, 4, 6]
    assert _one_mesh_run(estimates, 2) == [0, 1, 2]
