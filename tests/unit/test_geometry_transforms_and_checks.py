"""Rigid transforms and input checks of perception.geometry: known answers and one-line errors."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perception.geometry import (
    check_ids,
    check_points,
    check_positive,
    check_transform,
    check_vector,
    frame_along,
    frames_from_z_and_x,
    invert_transform,
    look_at,
    quaternion_xyzw_from_matrix,
    rigid_transform,
    rotation_about_axis,
    transform_points,
)


def rigid(seed=0):
    return rigid_transform(Rotation.random(random_state=seed).as_matrix(), [0.3, -1.2, 2.0])


def test_transform_and_its_inverse_round_trip():
    T = rigid()
    p = np.random.default_rng(1).normal(size=(7, 3))
    np.testing.assert_allclose(transform_points(T, p), p @ T[:3, :3].T + [0.3, -1.2, 2.0], atol=1e-12)
    assert T.shape == (4, 4) and np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(transform_points(invert_transform(T), transform_points(T, p)), p, atol=1e-12)
    np.testing.assert_allclose(invert_transform(T) @ T, np.eye(4), atol=1e-12)
    assert transform_points(T, np.zeros((0, 3))).shape == (0, 3)
    with pytest.raises(ValueError, match=r"points_b with shape \(N, 3\), got \(3,\)"):
        transform_points(T, np.zeros(3))


def test_rotations_with_known_answers():
    R = rotation_about_axis([0.0, 0.0, 2.0], np.pi / 2)  # the axis need not be unit
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    frames = frames_from_z_and_x(np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.5]]))
    np.testing.assert_allclose(frames[0], np.eye(3), atol=1e-12)  # x made orthogonal to z
    axis = np.array([0.2, -0.4, 0.9])
    F = frame_along(axis)
    np.testing.assert_allclose(F[:, 2], axis / np.linalg.norm(axis), atol=1e-12)
    np.testing.assert_allclose(F.T @ F, np.eye(3), atol=1e-12)
    assert np.linalg.det(F) == pytest.approx(1.0)
    q = quaternion_xyzw_from_matrix(np.stack([rotation_about_axis([1, 0, 0], a) for a in (0.5, 3.0, -3.0)]))
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(Rotation.from_quat(q[0]).as_matrix(), rotation_about_axis([1, 0, 0], 0.5), atol=1e-12)


def test_look_at_is_an_optical_frame_and_refuses_degenerate_views():
    T = look_at([0.0, -1.0, 1.0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(T[:3, 2], [0.0, 1.0, 0.0], atol=1e-12)  # z forward
    np.testing.assert_allclose(T[:3, 1], [0.0, 0.0, -1.0], atol=1e-12)  # y down: world up is image up
    with pytest.raises(ValueError, match="eye and target coincide"):
        look_at([1, 2, 3], [1, 2, 3])
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 0], [0, 0, 1])


@pytest.mark.parametrize("call, match", [
    (lambda: check_points("pts", np.zeros((4, 2))), r"^Expected pts with shape \(N, 3\), got \(4, 2\)$"),
    (lambda: check_points("pts", np.zeros((0, 3))), "at least one row"),
    (lambda: check_points("pts", [["a", "b", "c"]]), "numeric dtype"),
    (lambda: check_points("pts", [[0.0, np.nan, 1.0]]), "finite values"),
    (lambda: check_ids("faces", [[0, 1, 5]], 4, ndim=2), r"vertex ids in \[0, 4\), got ids in \[0, 5\]"),
    (lambda: check_ids("ids", [0.5], 4), "integer dtype"),
    (lambda: check_vector("up", [0.0, 0.0, 0.0], unit=True), "non-zero direction"),
    (lambda: check_vector("q", [0.0, 1.0, 0.0], size=4), r"q with shape \(4,\), got \(3,\)"),
    (lambda: check_positive("radius_m", 0.0), r"^Expected radius_m > 0, got 0.0$"),
    (lambda: check_transform("T", np.diag([1.0, 1.0, -1.0, 1.0])), "determinant"),
    (lambda: check_transform("T", np.diag([2.0, 1.0, 1.0, 1.0])), "orthonormal"),
    (lambda: check_transform("T", np.vstack([np.eye(4)[:3], [0, 0, 1, 1]])), "last row"),
])
def test_checks_raise_one_line_naming_the_argument(call, match):
    with pytest.raises(ValueError, match=match) as info:
        call()
    assert "\n" not in str(info.value)


def test_checks_return_the_documented_forms():
    assert check_points("p", [[1, 2, 3]]).dtype == np.float64
    assert check_points("p", np.zeros((0, 2)), dim=2, allow_empty=True).shape == (0, 2)
    assert check_ids("f", np.array([[0, 1, 2]], np.int32), 3, ndim=2).dtype == np.int64
    np.testing.assert_allclose(check_vector("v", [0, 3, 4], unit=True), [0.0, 0.6, 0.8])
    assert check_positive("x", 0, allow_zero=True) == 0.0
    np.testing.assert_array_equal(check_transform("T", rigid()), rigid())
