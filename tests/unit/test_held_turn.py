"""The turn of the gripper holding a cloth, from the orientations the robot sends with its frames."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ipc.messages import CameraInfo, RGBDFrame
from perception.held_turn import HeldTurns, Turn

CAM = CameraInfo.from_fov(8, 6, 1.0)
BASE = Rotation.from_rotvec([0.3, -0.2, 0.1])


def frame(held, points, quats) -> RGBDFrame:
    return RGBDFrame(np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32), CAM, held_vertices=np.array(held),
                     held_points_m=np.asarray(points, float), held_quats_xyzw=None if quats is None else np.asarray(quats))


def about_y(deg: float) -> np.ndarray:
    return (Rotation.from_rotvec([0.0, np.radians(deg), 0.0]) * BASE).as_quat()


def test_one_gripper_turning_turns_what_it_holds_about_the_held_point():
    turns = HeldTurns()
    assert turns.turn(frame([7], [[0.0, 0.0, 1.0]], [about_y(0.0)])) is None  # nothing to compare with yet
    turn = turns.turn(frame([7], [[0.1, 0.0, 1.0]], [about_y(30.0)]))
    np.testing.assert_allclose(turn.pivot_m, [0.1, 0.0, 1.0])
    np.testing.assert_allclose(turn.R, Rotation.from_rotvec([0.0, np.radians(30.0), 0.0]).as_matrix(), atol=1e-12)
    # a point 10 cm below the held one (camera y points down) stays 10 cm below: a vertical axis
    np.testing.assert_allclose(turn.apply([[0.1, 0.1, 1.0]]), [[0.1, 0.1, 1.0]], atol=1e-12)
    # a point 10 cm to its right swings about it, round towards the camera
    np.testing.assert_allclose(turn.apply([[0.2, 0.0, 1.0]]),
                               [[0.1 + 0.1 * np.cos(np.radians(30.0)), 0.0, 1.0 - 0.1 * np.sin(np.radians(30.0))]],
                               atol=1e-12)


def test_a_point_no_gripper_holds_is_left_out_and_a_still_gripper_is_no_turn():
    turns = HeldTurns()
    unknown = np.full(4, np.nan)
    turns.turn(frame([7, 3], [[0, 0, 1.0], [0, 0.3, 1.0]], [about_y(0.0), unknown]))
    assert turns.turn(frame([7, 3], [[0, 0, 1.0], [0, 0.3, 1.0]], [about_y(0.0), unknown])) is None
    turn = turns.turn(frame([7, 3], [[0, 0, 1.0], [0, 0.3, 1.0]], [about_y(10.0), unknown]))
    np.testing.assert_allclose(np.degrees(Rotation.from_matrix(turn.R).magnitude()), 10.0)


@pytest.mark.parametrize("second", [
    ([[7], [[0, 0, 1.0]], None]),  # no orientation now
    ([[8], [[0, 0, 1.0]], [about_y(20.0)]]),  # another vertex held: the mesh or the grip changed
    ([[7, 9], [[0, 0, 1.0], [0.3, 0, 1.0]], [about_y(20.0), about_y(0.0)]]),  # two grippers
])
def test_no_turn_without_one_gripper_holding_the_same_point_in_both_frames(second):
    turns = HeldTurns()
    turns.turn(frame([7, 9], [[0, 0, 1.0], [0.3, 0, 1.0]], [about_y(0.0), about_y(0.0)]))
    assert turns.turn(frame(*second)) is None
    turns = HeldTurns()
    turns.turn(frame([7], [[0, 0, 1.0]], [about_y(0.0)]))
    turns.forget()
    assert turns.turn(frame([7], [[0, 0, 1.0]], [about_y(20.0)])) is None


def test_turn_apply_is_a_rigid_motion_keeping_the_pivot():
    turn = Turn(Rotation.from_rotvec([0.2, 0.5, -0.3]).as_matrix(), np.array([0.1, -0.2, 1.1]))
    pts = np.random.default_rng(0).normal(size=(20, 3))
    out = turn.apply(pts)
    np.testing.assert_allclose(turn.apply(turn.pivot_m[None]), turn.pivot_m[None], atol=1e-12)
    d_in = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    np.testing.assert_allclose(np.linalg.norm(out[:, None] - out[None], axis=2), d_in, atol=1e-12)


@pytest.mark.parametrize("quats, match", [
    (np.zeros((1, 4)), "held_quats_xyzw: expected unit quaternions"),
    (np.array([[0.0, 0.0, np.nan, 1.0]]), "held_quats_xyzw: expected unit quaternions"),
    (np.array([[0.0, 0.0, np.inf, 1.0]]), "held_quats_xyzw: expected unit quaternions"),
    (np.zeros((2, 4)), "held_quats_xyzw: expected \\(1, 4\\)"),
    (np.zeros((1, 3)), "held_quats_xyzw: expected \\(1, 4\\)"),
    (np.zeros((1, 4), np.int64), "held_quats_xyzw: expected \\(1, 4\\) float"),
])
def test_frames_refuse_orientations_that_are_not_unit_quaternions_one_per_held_point(quats, match):
    with pytest.raises(ValueError, match=match):
        frame([7], [[0, 0, 1.0]], quats)


def test_frames_refuse_orientations_without_held_points_and_normalise_the_rest():
    f = frame([7], [[0, 0, 1.0]], None)
    with pytest.raises(ValueError, match="held_quats_xyzw: expected only with held_vertices"):
        dataclasses.replace(f, held_vertices=None, held_points_m=None, held_quats_xyzw=np.array([[0, 0, 0, 1.0]]))
    g = frame([7, 3], [[0, 0, 1.0], [0, 0.3, 1.0]], np.array([[0, 0, 0, 1.0005], [np.nan] * 4], np.float32))
    assert g.held_quats_xyzw.dtype == np.float64
    np.testing.assert_allclose(g.held_quats_xyzw[0], [0, 0, 0, 1.0])
    assert np.isnan(g.held_quats_xyzw[1]).all()
