"""sim.panda: a Franka Panda that carries the simulated gripper, its reach and its drawing."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perception.geometry import rigid_transform
from sim.panda import ANGLE_TOLERANCE_RAD, POSITION_TOLERANCE_M, PandaArm

#: a gripper pointing straight down, fingers closing along world x
DOWN = np.column_stack([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
SHOULDER = np.array([-0.55, 0.0, 1.3])


def _pose(position, R=DOWN) -> np.ndarray:
    return rigid_transform(R, position)


@pytest.fixture(scope="module")
def arm():
    with PandaArm.at_shoulder(SHOULDER, [0.0, 0.0, 0.7], stands_on_z=0.7) as a:
        yield a


def test_the_arm_puts_its_grasp_frame_on_poses_within_its_reach(arm):
    rng = np.random.default_rng(3)
    for _ in range(12):
        R = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix() \
            @ Rotation.from_euler("x", rng.uniform(0.0, 0.4)).as_matrix() @ DOWN
        T = _pose([rng.uniform(-0.4, 0.0), rng.uniform(-0.3, 0.3), rng.uniform(0.72, 1.0)], R)
        reach = arm.solve(T)
        assert reach.reachable, reach.describe()
        got = arm.grasp_pose()
        assert np.linalg.norm(got[:3, 3] - T[:3, 3]) == pytest.approx(reach.position_error_m, abs=1e-9)
        assert reach.position_error_m < 0.003
        # the same grasp, or the same turned half a turn about the approach (a parallel gripper's twin)
        assert np.allclose(got[:3, 2], T[:3, 2], atol=2 * ANGLE_TOLERANCE_RAD)
        assert abs(abs(float(got[:3, 0] @ T[:3, 0])) - 1.0) < 0.01


def test_a_pose_out_of_reach_is_said_to_be_so(arm):
    reach = arm.solve(_pose([1.6, 0.0, 0.8]))
    assert not reach.reachable
    assert reach.position_error_m > 0.8
    assert "cm" in reach.describe()
    assert POSITION_TOLERANCE_M < 0.02


def test_checking_a_reach_leaves_the_arm_where_it_was(arm):
    arm.reach(_pose([-0.2, 0.1, 0.9]))
    before = arm.joints.copy()
    assert arm.can_reach(_pose([-0.3, -0.2, 0.75])).reachable
    assert np.array_equal(arm.joints, before)
    assert np.linalg.norm(arm.grasp_pose()[:3, 3] - [-0.2, 0.1, 0.9]) < 0.003


def test_the_drawn_arm_stands_on_its_column_and_opens_its_fingers(arm):
    arm.reach(_pose([-0.25, 0.0, 0.8]))
    open_, closed = arm.mesh(0.08), arm.mesh(0.0)
    assert len(open_.faces) > 3000
    assert open_.points[:, 2].min() == pytest.approx(0.7, abs=1e-6), "the column reaches down to the table"
    assert open_.points[:, 2].max() > SHOULDER[2], "links above the shoulder"
    # closed, the fingertips meet at the grasp point; open, they stand 4 cm either side of it
    def near_grasp(mesh):
        return int((np.linalg.norm(mesh.points - [-0.25, 0.0, 0.8], axis=1) < 0.015).sum())

    assert near_grasp(closed) > 0 and near_grasp(open_) == 0
    assert np.linalg.norm(open_.points - [-0.25, 0.0, 0.8], axis=1).min() == pytest.approx(0.04, abs=0.01)


def test_a_mount_that_is_no_rigid_transform_is_refused():
    with pytest.raises(ValueError, match="T_world_base"):
        PandaArm(np.zeros((4, 4)))


def test_a_laundry_scene_draws_a_panda_carrying_each_hand_and_knows_what_it_reaches():
    from sim.laundry import LaundryScene, laundry_spec
    from sim.laundry.unfold import UnfoldConfig, arm_for

    spec = laundry_spec(2, view="room", state="flat")
    down = Rotation.from_matrix(DOWN).as_quat()
    masks = {}
    for arm in ("drawn", "panda"):
        with LaundryScene(spec, noise=False, known_occluders=True, arm=arm) as scene:
            corner = scene.corners_world()[0]
            near = arm_for(corner, spec.table_top_z, UnfoldConfig(), arm=arm)  # the arm on the corner's side
            far = arm_for(corner, spec.table_top_z, UnfoldConfig(), taken=near, arm=arm)
            hand = scene.add_robot_hand(corner + [0.0, 0.0, 0.05], down, near)
            masks[arm] = scene.render().occluder_mask.astype(bool)
            assert not (masks[arm] & scene.cloth_mask()).any()  # in front of the cloth
            if arm == "drawn":
                assert hand.arm is None and scene.can_reach(near, _pose(corner)) is None  # reaches anywhere
                continue
            assert hand.arm is not None
            assert np.linalg.norm(hand.arm.grasp_pose()[:3, 3] - hand.gripper.position) < 0.003
            assert scene.can_reach(near, _pose(corner + [0.0, 0.0, 0.05])).reachable
            # the other arm, across the table, cannot reach down to that corner
            assert abs(corner[0]) > 0.15 and not scene.can_reach(far, _pose(corner)).reachable
            scene.reset()
            assert scene.hands == [] and scene.render().occluder_mask is None
    # the Panda's links, column and hand hide more of the view than the drawn arm
    assert masks["panda"].sum() > 1.5 * masks["drawn"].sum()
    with pytest.raises(ValueError, match="arm"):
        LaundryScene(spec, noise=False, arm="ur5")


def test_a_panda_lifts_the_cloth_to_the_middle_between_the_arms_and_only_in_the_unfold_task():
    from launch_scripts.trial_runner.trial import TrialConfig
    from sim.laundry.unfold import UnfoldConfig, lift_target

    canonical = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    straight = lift_target(np.array([0.3, 0.1, 0.75]), canonical, 0, 0.75, UnfoldConfig())
    middle = lift_target(np.array([0.3, 0.1, 0.75]), canonical, 0, 0.75, UnfoldConfig(), over_x_m=0.0)
    np.testing.assert_allclose(straight, [0.3, 0.1, middle[2]])
    np.testing.assert_allclose(middle[:2], [0.0, 0.1])
    assert TrialConfig(task="unfold", arm="panda").arm == "panda"
    with pytest.raises(ValueError, match="arm"):
        TrialConfig(task="corner", arm="panda")
    with pytest.raises(ValueError, match="arm"):
        TrialConfig(task="unfold", arm="ur5")


def test_the_first_corner_goes_to_an_arm_that_reaches_it_or_is_refused_as_out_of_reach():
    from types import SimpleNamespace

    from ipc.messages import GraspPlan
    from launch_scripts.trial_runner.trial import TrialConfig
    from launch_scripts.trial_runner.unfold import _first_arm
    from perception.geometry import invert_transform, transform_points
    from sim.laundry import LaundryScene, laundry_spec
    from sim.laundry.unfold import UnfoldConfig, shoulders

    spec = laundry_spec(2, view="room", state="flat")
    config = TrialConfig(task="unfold", arm="panda")
    estimate = SimpleNamespace(canonical=np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0]]))
    left, right = shoulders(spec.table_top_z, UnfoldConfig(), "panda")
    with LaundryScene(spec, noise=False, arm="panda") as scene:
        T_cam_world = invert_transform(scene.T_world_cam)

        def plan(position_world, R_world_gripper) -> GraspPlan:
            R = T_cam_world[:3, :3] @ R_world_gripper
            return GraspPlan(position=transform_points(T_cam_world, np.asarray(position_world)[None])[0],
                             approach=R[:, 2], quat_xyzw=Rotation.from_matrix(R).as_quat(), opening_width_m=0.08,
                             score=1.0, vertex_id=0, kind="corner")

        at = [0.12, 0.0, spec.table_top_z + 0.01]
        shoulder, why = _first_arm(scene, config, plan(at, DOWN), estimate)
        assert why is None and np.allclose(shoulder, right), "from above: the arm on its side"
        # when the arm on its side cannot reach it (a Panda cannot turn its gripper back at its
        # own base), the other one takes it
        reaches = scene.can_reach
        scene.can_reach = lambda shoulder, T: dataclasses.replace(reaches(shoulder, T), position_error_m=1.0) \
            if np.allclose(shoulder, right) else reaches(shoulder, T)
        shoulder, why = _first_arm(scene, config, plan(at, DOWN), estimate)
        assert why is None and np.allclose(shoulder, left)
        del scene.can_reach
        # from under the table, pointing up: no arm gets its hand there
        shoulder, why = _first_arm(scene, config, plan(at, np.eye(3)), estimate)
        assert why is not None and why.startswith("unreachable: the arm cannot bring its gripper to the first corner")


def test_a_cloth_held_up_is_grasped_from_the_side_an_arm_reaches_not_from_under_it():
    from types import SimpleNamespace

    from ipc.messages import GraspPlan
    from launch_scripts.trial_runner.trial import TrialConfig
    from launch_scripts.trial_runner.unfold import _first_arm, _from_a_side_reached
    from perception.geometry import invert_transform, transform_points
    from sim.laundry import LaundryScene, laundry_spec

    spec = laundry_spec(2, view="room", state="flat")
    config = TrialConfig(task="unfold", arm="panda")
    estimate = SimpleNamespace(canonical=np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0]]))
    with LaundryScene(spec, noise=False, arm="panda") as scene:
        T_cam_world = invert_transform(scene.T_world_cam)
        # a lowest-point grasp as grasping.lowest_point_grasp makes it: up from below, closing along y,
        # 2 cm above the table in its middle (a cloth hanging from the holder)
        R = T_cam_world[:3, :3] @ np.column_stack([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        at = [0.02, 0.05, spec.table_top_z + 0.02]
        below = GraspPlan(position=transform_points(T_cam_world, np.asarray(at)[None])[0], approach=R[:, 2],
                          quat_xyzw=Rotation.from_matrix(R).as_quat(), opening_width_m=0.04, score=1.0,
                          vertex_id=-1, kind="corner")
        assert _first_arm(scene, config, below, estimate)[1] is not None
        side, _, _ = _from_a_side_reached(scene, config, below, estimate)
        assert _first_arm(scene, config, side, estimate)[1] is None
        approach_world = scene.T_world_cam[:3, :3] @ side.approach
        assert abs(approach_world[2]) < 1e-9 and abs(approach_world[0]) > 0.999  # level, across the closing (y)
        position_world = scene.T_world_cam[:3, :3] @ side.position + scene.T_world_cam[:3, 3]
        assert position_world[2] == pytest.approx(at[2]) and np.linalg.norm(position_world - at) < 0.015  # level with the tip
