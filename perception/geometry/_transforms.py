"""Rigid transforms and rotations on NumPy arrays.

Frames are named in the variables: ``T_a_b`` (4, 4) float64 maps points of frame b to
frame a (``p_a = T_a_b @ [p_b, 1]``); ``R_a_b`` (3, 3) likewise for directions. The camera
frame is the OpenCV optical frame (x right, y down, z forward); quaternions are
(x, y, z, w), scalar last, as PyBullet and ROS.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from perception.geometry._checks import check_transform


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (N, 3) points, metres, from frame b to frame a with the (4, 4) transform ``T_a_b``;
    returns (N, 3) float64 (N may be 0)."""
    T = np.asarray(T_a_b, dtype=np.float64)
    p = np.asarray(points_b, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"Expected points_b with shape (N, 3), got {p.shape}")
    return p @ T[:3, :3].T + T[:3, 3]


def rigid_transform(R_a_b, t_a_b) -> np.ndarray:
    """``T_a_b`` (4, 4) float64 of a rotation ``R_a_b`` (3, 3) and a translation ``t_a_b`` (3,)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_a_b, t_a_b
    return T


def invert_transform(T_a_b: np.ndarray) -> np.ndarray:
    """``T_b_a`` (4, 4) float64 of a rigid (4, 4) transform ``T_a_b``."""
    T = check_transform("T_a_b", T_a_b)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of a camera at ``eye`` looking at ``target``, image up along ``up``.

    eye, target : (3,) float, metres, world frame; up : (3,) world direction, not parallel
    to the viewing direction
    returns (4, 4) float64, optical camera frame (x right, y down, z forward) to world
    """
    eye = np.asarray(eye, dtype=np.float64).reshape(3)
    forward = np.asarray(target, dtype=np.float64).reshape(3) - eye
    if np.linalg.norm(forward) < 1e-9:
        raise ValueError("look_at: eye and target coincide")
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, np.asarray(up, dtype=np.float64).reshape(3))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: up is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


def rotation_about_axis(axis, angle_rad: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``angle_rad`` about ``axis`` (3,), any length (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1.0 - np.cos(angle_rad)) * (k @ k)


def frames_from_z_and_x(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Rotation matrices whose z axis is ``z`` and whose x axis is ``x_hint`` made orthogonal to it.

    The gripper convention of ``grasping`` and ``sim``: z is the approach direction, x the
    direction the fingers close along, y = z x x completes a right-handed frame.

    Parameters
    ----------
    z : (K, 3) float64, unit vectors
    x_hint : (K, 3) float64, not parallel to ``z``

    Returns
    -------
    (K, 3, 3) float64, ``R_frame_axes``: columns x, y, z in the frame of the inputs
    """
    x = x_hint - np.sum(x_hint * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def frame_along(axis: np.ndarray) -> np.ndarray:
    """(3, 3) float64 rotation whose z axis (third column) is ``axis`` (3,) normalised; x and y
    are any perpendicular pair (x from a fixed helper direction, so the result is repeatable)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def quaternion_xyzw_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of rotation matrices, with w >= 0.

    R : (K, 3, 3) float64 rotation matrices
    returns (K, 4) float64, scalar last; the sign is fixed so that w >= 0, which makes
    the result unique except for half-turns
    """
    q = Rotation.from_matrix(R).as_quat()
    # q and -q are the same rotation; one sign makes results comparable and testable.
    q[q[:, 3] < 0] *= -1.0
    return q
