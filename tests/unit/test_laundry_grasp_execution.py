"""Grasp execution in simulation (sim.grasp_execution): frames, the guarded move, the jaw, the held point."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ipc.messages import GraspPlan
from sim.cloth_mesh import rectangle_cloth
from sim.grasp_execution import (
    ExecutionConfig,
    GraspPose,
    fingertip_target,
    grasped_material_point,
    jaw_faces,
    plan_to_world,
)

CONFIG = ExecutionConfig()
DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # gripper z (approach) pointing down


def plan(position, R):
    return GraspPlan(position=np.asarray(position, float), approach=R[:, 2], quat_xyzw=Rotation.from_matrix(R).as_quat(),
                     opening_width_m=0.04, score=1.0, vertex_id=0, kind="corner")


def test_plan_to_world_applies_the_camera_pose():
    # Camera 1 m above the origin looking straight down, image x along world x.
    T = np.eye(4)
    T[:3, :3] = DOWN
    T[:3, 3] = [0.0, 0.0, 1.0]
    R_cam_gripper = Rotation.from_euler("z", 30, degrees=True).as_matrix()  # approach along the optical axis
    pose = plan_to_world(plan([0.1, 0.2, 0.9], R_cam_gripper), T)
    np.testing.assert_allclose(pose.position, [0.1, -0.2, 0.1])
    np.testing.assert_allclose(pose.approach, [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(pose.R, DOWN @ R_cam_gripper, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(pose.quat_xyzw).as_matrix(), pose.R, atol=1e-12)


def test_plan_to_world_rejects_a_bad_transform():
    with pytest.raises(ValueError, match=r"T_world_cam with shape \(4, 4\), got \(3, 3\)"):
        plan_to_world(plan([0, 0, 1], np.eye(3)), np.eye(3))


@pytest.mark.parametrize("height, expected", [
    (0.010, 0.002),  # 1 cm above the table: down to it (plus clearance)
    (0.050, 0.030),  # 5 cm above: at most 2 cm of overtravel
    (-0.010, 0.002),  # below the table: stops at its surface
])
def test_downward_approach_is_a_guarded_move_onto_the_support(height, expected):
    pose = GraspPose(position=np.array([0.1, 0.0, 0.75 + height]), R=DOWN, opening_width_m=0.04)
    tip = fingertip_target(pose, 0.75, CONFIG)
    np.testing.assert_allclose(tip, [0.1, 0.0, 0.75 + expected], atol=1e-12)


def test_sideways_approach_stops_at_the_plan_position():
    R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # approach along +x, closing along -z
    pose = GraspPose(position=np.array([0.1, 0.0, 0.8]), R=R, opening_width_m=0.04)
    np.testing.assert_array_equal(fingertip_target(pose, 0.75, CONFIG), pose.position)


def flat_cloth():
    """A 0.3 x 0.2 m cloth, 3 cm grid, lying in the plane z = 0 with uv = (x, y)."""
    mesh = rectangle_cloth(0.3, 0.2, spacing_m=0.03)
    return mesh, np.column_stack([mesh.uv_m, np.zeros(mesh.n_vertices)])


def test_jaw_holds_the_cloth_between_the_fingers_even_between_nodes():
    mesh, points = flat_cloth()
    tip = np.array([0.145, 0.128, 0.0])  # no node within 1 cm: nodes sit every 3 cm
    assert np.min(np.linalg.norm(points - tip, axis=1)) > 0.01
    pose = GraspPose(position=tip, R=DOWN, opening_width_m=0.04)
    faces = jaw_faces(points, mesh.faces, tip, pose, CONFIG)
    assert faces.size > 0
    held_uv = mesh.uv_m[mesh.faces[faces]].reshape(-1, 2)
    # Only triangles reaching into the 4 x 2 cm jaw footprint: within one grid cell of it.
    assert np.all(np.abs(held_uv - tip[:2]) <= np.array([0.02, 0.01]) + 0.03 + 1e-9)
    uv, offset = grasped_material_point(points, mesh.faces[faces], mesh.uv_m, tip)
    np.testing.assert_allclose(uv, tip[:2], atol=1e-12)
    assert offset == pytest.approx(0.0, abs=1e-12)


def test_jaw_misses_cloth_beyond_the_fingertips_or_outside_the_opening():
    mesh, points = flat_cloth()
    for tip in ([0.15, 0.10, 0.02], [0.15, 0.10, -0.04], [0.40, 0.10, 0.0]):
        tip = np.asarray(tip)  # 2 cm above (fingertips short of it), 4 cm below (cloth behind the palm), beside
        pose = GraspPose(position=tip, R=DOWN, opening_width_m=0.04)
        assert jaw_faces(points, mesh.faces, tip, pose, CONFIG).size == 0


def test_grasped_point_is_the_nearest_point_of_the_held_triangles():
    mesh, points = flat_cloth()
    tip = np.array([-0.01, 0.05, 0.0])  # 1 cm beyond the cloth's left edge
    pose = GraspPose(position=tip, R=DOWN, opening_width_m=0.04)
    faces = mesh.faces[jaw_faces(points, mesh.faces, tip, pose, CONFIG)]
    uv, offset = grasped_material_point(points, faces, mesh.uv_m, tip)
    np.testing.assert_allclose(uv, [0.0, 0.05], atol=1e-12)
    assert offset == pytest.approx(0.01)
    with pytest.raises(ValueError, match="expected at least one held triangle, got none"):
        grasped_material_point(points, np.zeros((0, 3), int), mesh.uv_m, tip)


@pytest.mark.parametrize("kw, match", [
    ({"finger_length_m": 0.0}, "finger_length_m: expected a positive number, got 0.0"),
    ({"lift_height_m": -1.0}, "lift_height_m: expected a non-negative number, got -1.0"),
    ({"samples_per_edge": 0}, "samples_per_edge: expected a positive integer, got 0"),
])
def test_execution_config_rejects_bad_values(kw, match):
    with pytest.raises(ValueError, match=match):
        ExecutionConfig(**kw)


@pytest.mark.slow
def test_a_plan_at_a_true_corner_lifts_the_towel_by_that_corner():
    pytest.importorskip("pybullet")
    from sim.grasp_execution import execute_grasp
    from sim.laundry import LaundryScene, laundry_spec

    with LaundryScene(laundry_spec(2, state="flat", cloth_kind="towel")) as scene:
        corner_cam = scene.cloth_vertices_cam()[scene.corner_vertices()[0]]
        T_cam_world = np.linalg.inv(scene.T_world_cam)
        R_cam_gripper = T_cam_world[:3, :3] @ DOWN  # straight down onto the table
        phases = []
        result = execute_grasp(scene, plan(corner_cam, R_cam_gripper), on_phase=phases.append)
        assert phases == ["closed", "lifted"]
        assert result.held_nodes.size >= 1 and result.failure == ""
        assert np.linalg.norm(result.grasped_uv - scene.spec.corners_uv[0]) < 0.005
        assert result.lifted_clear and result.lowest_clearance_m > 0.1
        # Hanging from the corner: that corner is now the cloth's highest point.
        assert np.argmax(scene.cloth_vertices_world()[:, 2]) in set(result.held_nodes.tolist())


@pytest.mark.slow
def test_a_held_cloth_is_taken_at_its_lowest_point_from_the_side_above_the_table():
    pytest.importorskip("pybullet")
    from grasping import from_the_side, lowest_point_grasp
    from sim.grasp_execution import execute_grasp
    from sim.laundry import LaundryScene, cloth_points, laundry_spec, mask_from_reference

    with LaundryScene(laundry_spec(6, state="held", cloth_kind="towel"), noise=False) as scene:
        frame, reference = scene.render(), scene.render_empty()
        below = lowest_point_grasp(cloth_points(frame, mask_from_reference(frame, reference), reference),
                                   scene.T_world_cam)
        top = scene.spec.table_top_z
        assert plan_to_world(below, scene.T_world_cam).approach[2] > 0.99  # up from under the cloth
        # From the side the hand comes in level, above the table, and takes the corner hanging lowest.
        side = from_the_side(below, scene.T_world_cam)
        pose = plan_to_world(side, scene.T_world_cam)
        assert abs(pose.approach[2]) < 1e-9 and (pose.position - CONFIG.pregrasp_distance_m * pose.approach)[2] > top
        result = execute_grasp(scene, side)
        assert result.failure == "" and result.lifted_clear
        assert np.linalg.norm(scene.spec.corners_uv - result.grasped_uv, axis=1).min() < 0.03
