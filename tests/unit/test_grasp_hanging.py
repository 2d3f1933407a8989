"""Grasping a hanging cloth at its lowest point (grasping.lowest_point_grasp)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grasping import from_the_side, lowest_point_grasp

UP = np.array([0.0, 0.0, 1.0])


def camera_looking_at(eye, target) -> np.ndarray:
    """T_world_cam of an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``, z up."""
    forward = np.asarray(target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, UP)
    right /= np.linalg.norm(right)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([right, np.cross(forward, right), forward])
    T[:3, 3] = eye
    return T


def to_cam(T_world_cam, points_world):
    return (np.asarray(points_world) - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]


def hanging_triangle(tip=(0.1, 0.2, 1.0), height=0.3, spacing=0.004) -> np.ndarray:
    """(N, 3) world points of a triangle hanging tip down in the vertical plane y = tip y."""
    pts = []
    for z in np.arange(0.0, height, spacing):
        half = 0.5 * z  # 0.3 m high, 0.3 m wide at the top
        for x in np.arange(-half, half + 1e-9, spacing):
            pts.append((x, 0.0, z))
    return np.asarray(pts) + tip


def gripper_axes_world(plan, T_world_cam):
    R_cam_gripper = Rotation.from_quat(plan.quat_xyzw).as_matrix()
    return T_world_cam[:3, :3] @ R_cam_gripper  # columns: closing x, y, approach z


@pytest.mark.parametrize("eye", [(0.0, -1.5, 1.9), (0.8, -1.0, 1.2), (-0.3, -1.2, 2.3)])
def test_plan_comes_up_from_below_to_just_above_the_tip_and_closes_across_the_cloth(eye):
    T = camera_looking_at(np.array(eye), (0.1, 0.2, 1.15))
    plan = lowest_point_grasp(to_cam(T, hanging_triangle()), T, inset_m=0.01)
    position_world = T[:3, :3] @ plan.position + T[:3, 3]
    np.testing.assert_allclose(position_world, [0.1, 0.2, 1.01], atol=0.004)
    axes = gripper_axes_world(plan, T)
    np.testing.assert_allclose(axes[:, 2], UP, atol=1e-9)  # approach: straight up
    np.testing.assert_allclose(T[:3, :3] @ plan.approach, UP, atol=1e-9)
    assert abs(axes[:, 0] @ [0.0, 1.0, 0.0]) == pytest.approx(1.0, abs=1e-6)  # closing along the sheet's normal
    assert plan.kind == "corner" and plan.vertex_id == -1 and plan.opening_width_m == 0.04 and plan.score == 1.0


def test_a_few_stray_points_below_the_cloth_do_not_move_the_grasp():
    T = camera_looking_at(np.array([0.0, -1.5, 1.9]), (0.1, 0.2, 1.15))
    points = np.concatenate([hanging_triangle(), [[0.1, 0.2, 0.5], [0.3, 0.2, 0.7], [0.0, 0.1, 0.6]]])
    plan = lowest_point_grasp(to_cam(T, points), T, inset_m=0.01)
    np.testing.assert_allclose(T[:3, :3] @ plan.position + T[:3, 3], [0.1, 0.2, 1.01], atol=0.004)


def test_where_the_cloth_lies_flat_the_fingers_close_across_the_line_of_sight():
    T = camera_looking_at(np.array([0.0, -1.0, 1.0]), (0.0, 0.0, 0.0))
    x, y = np.meshgrid(np.linspace(-0.1, 0.1, 41), np.linspace(-0.1, 0.1, 41))
    flat = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])  # a horizontal patch
    plan = lowest_point_grasp(to_cam(T, flat), T, inset_m=0.01)
    tip = T[:3, :3] @ plan.position + T[:3, 3] - [0.0, 0.0, 0.01]
    sight = tip - T[:3, 3]
    sight[2] = 0.0
    closing = gripper_axes_world(plan, T)[:, 0]
    assert abs(closing @ sight) / np.linalg.norm(sight) == pytest.approx(1.0, abs=1e-6)


def test_up_can_be_any_direction():
    T = camera_looking_at(np.array([0.0, -1.5, 1.9]), (0.1, 0.2, 1.15))
    points = to_cam(T, hanging_triangle())
    plan = lowest_point_grasp(points, T, up_world=(0.0, 0.0, -2.0), inset_m=0.01)  # "up" is down: the top edge is lowest
    position_world = T[:3, :3] @ plan.position + T[:3, 3]
    assert position_world[2] == pytest.approx(1.0 + 0.3 - 0.004 - 0.01, abs=0.006)
    np.testing.assert_allclose(T[:3, :3] @ plan.approach, [0.0, 0.0, -1.0], atol=1e-9)


@pytest.mark.parametrize("kwargs, match", [
    ({"points_cam": np.zeros((2, 3))}, "at least 3 points"),
    ({"points_cam": np.zeros((5, 2))}, r"points_cam with shape \(N, 3\)"),
    ({"T_world_cam": np.diag([1.0, 1.0, -1.0, 1.0])}, "determinant"),
    ({"up_world": (0.0, 0.0, 0.0)}, "non-zero direction"),
    ({"min_neighbours": -1}, "min_neighbours an integer >= 0"),
    ({"support_radius_m": 0.0}, "support_radius_m > 0"),
    ({"min_neighbours": 25}, "no point of 20 has 25 others"),
    ({"inset_m": -0.01}, "inset_m > 0"),
    ({"neighbourhood_m": 0.0}, "neighbourhood_m > 0"),
])
def test_bad_input_raises_with_a_clear_message(kwargs, match):
    args = {"points_cam": np.random.default_rng(0).normal(size=(20, 3)) + [0, 0, 2], "T_world_cam": np.eye(4), **kwargs}
    with pytest.raises(ValueError, match=match):
        lowest_point_grasp(**args)


@pytest.mark.parametrize("side", [1, -1])
def test_from_the_side_comes_in_level_along_the_sheet_and_keeps_closing_across_it(side):
    T = camera_looking_at(np.array([0.0, -1.5, 1.9]), (0.1, 0.2, 1.15))
    below = lowest_point_grasp(to_cam(T, hanging_triangle()), T, inset_m=0.01)
    plan = from_the_side(below, T, side=side, rise_m=0.015, reach_m=0.01)
    axes = gripper_axes_world(plan, T)
    np.testing.assert_allclose(T[:3, :3] @ plan.approach, axes[:, 2], atol=1e-9)
    assert abs(axes[:, 2] @ UP) < 1e-9  # level
    assert abs(abs(axes[:, 2] @ [1.0, 0.0, 0.0]) - 1.0) < 1e-6  # along the sheet (the plane y = 0.2)
    assert abs(abs(axes[:, 0] @ [0.0, 1.0, 0.0]) - 1.0) < 1e-6  # closing across it, as from below
    position_world = T[:3, :3] @ plan.position + T[:3, 3]
    np.testing.assert_allclose(position_world, [0.1, 0.2, 1.025] + 0.01 * axes[:, 2], atol=0.004)
    other = from_the_side(below, T, side=-side)
    np.testing.assert_allclose(T[:3, :3] @ other.approach, -axes[:, 2], atol=1e-9)  # the two sides are opposite


def test_from_the_side_refuses_a_side_that_is_not_one():
    T = camera_looking_at(np.array([0.0, -1.5, 1.9]), (0.1, 0.2, 1.15))
    below = lowest_point_grasp(to_cam(T, hanging_triangle()), T)
    with pytest.raises(ValueError, match="side"):
        from_the_side(below, T, side=0)
    with pytest.raises(ValueError, match="plan: expected a GraspPlan, got str"):
        from_the_side("plan", T)
