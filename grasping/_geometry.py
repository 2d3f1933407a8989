"""Small geometric kernels for grasp planning: normals, gripper frames, projection.

Data form: vertex positions (N, 3) float64 metres in the camera frame (OpenCV
optical: x right, y down, z forward), faces (M, 3) int vertex ids, pixel
coordinates (u, v) with the centre of pixel ``[row, col]`` at ``(col, row)``.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation

from ipc.messages import CameraInfo

log = logging.getLogger(__name__)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals, following the faces' winding (not normalised).

    Parameters
    ----------
    vertices : (N, 3) float64, metres
    faces : (M, 3) int vertex ids

    Returns
    -------
    (N, 3) float64: for each vertex the sum over its faces of the face normal times
    twice the face area (m^2); zero for a vertex without faces
    """
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    # The cross product's length is twice the face area, which is the weighting.
    face_normals = np.cross(b - a, c - a)
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    return normals


def gripper_matrices(approach: np.ndarray, closing: np.ndarray) -> np.ndarray:
    """Rotation matrices of a parallel gripper from its approach and closing directions.

    Gripper frame convention: z is the approach direction (the way the gripper
    moves to reach the grasp point, palm to fingertips); x is the finger closing
    direction (the line along which the fingers move); y = z cross x completes a
    right-handed frame. ``closing`` is made orthogonal to ``approach`` first.

    Parameters
    ----------
    approach : (K, 3) float64, unit vectors
    closing : (K, 3) float64, not parallel to ``approach``

    Returns
    -------
    (K, 3, 3) float64, ``R_frame_gripper``: columns x, y, z of the gripper axes in
    the frame of the inputs
    """
    x = closing - np.sum(closing * approach, axis=1, keepdims=True) * approach
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(approach, x)
    return np.stack([x, y, approach], axis=-1)


def quaternion_xyzw_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of rotation matrices, with w >= 0.

    Parameters
    ----------
    R : (K, 3, 3) float64 rotation matrices

    Returns
    -------
    (K, 4) float64, scalar last (PyBullet and ROS order); the sign is fixed so that
    w >= 0, which makes the result unique except for half-turns
    """
    q = Rotation.from_matrix(R).as_quat()
    # q and -q are the same rotation; one sign makes plans comparable and testable.
    q[q[:, 3] < 0] *= -1.0
    return q


def project_points(points_cam: np.ndarray, camera: CameraInfo) -> np.ndarray:
    """Pixel coordinates of camera-frame points, with the camera's distortion.

    Distortion follows OpenCV (and ROS CameraInfo): ``D`` holds k1, k2, p1, p2
    [, k3 [, k4, k5, k6]]; 4 or 5 coefficients are plumb_bob, 8 the rational model.

    Parameters
    ----------
    points_cam : (K, 3) float64, metres, camera optical frame
    camera : CameraInfo

    Returns
    -------
    (K, 2) float64 (u, v) pixels; NaN for points not in front of the camera (z <= 0)
    """
    z = points_cam[:, 2]
    in_front = z > 0
    safe_z = np.where(in_front, z, 1.0)
    x = points_cam[:, 0] / safe_z
    y = points_cam[:, 1] / safe_z
    D = np.zeros(8)
    D[: camera.D.size] = camera.D
    k1, k2, p1, p2, k3, k4, k5, k6 = D
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    uv = np.stack([camera.fx * xd + camera.cx, camera.fy * yd + camera.cy], axis=1)
    uv[~in_front] = np.nan
    return uv


def depth_agrees(points_cam: np.ndarray, depth_m: np.ndarray, uv: np.ndarray, tol_m: float, window_px: int) -> np.ndarray:
    """Whether the measured depth around each point's pixel agrees with the point.

    A point agrees when some valid depth in the (2 w + 1)^2 pixel window around its
    pixel is within ``tol_m`` of its z. "Some" rather than the median, because a
    cloth corner's window is mostly background; a corner under another layer has
    only that layer's (nearer) depth around it and so does not agree.

    Parameters
    ----------
    points_cam : (K, 3) float64, metres, camera frame
    depth_m : (H, W) float32, metres along the optical axis; 0 or NaN = missing
    uv : (K, 2) float64, pixel coordinates of the points (NaN = not projectable)
    tol_m : float, metres
    window_px : int >= 0, half-size of the window

    Returns
    -------
    (K,) bool; False outside the image
    """
    height, width = depth_m.shape
    agrees = np.zeros(len(points_cam), bool)
    finite = np.all(np.isfinite(uv), axis=1)
    cols = np.full(len(uv), -1, np.int64)
    rows = np.full(len(uv), -1, np.int64)
    cols[finite] = np.rint(uv[finite, 0]).astype(np.int64)
    rows[finite] = np.rint(uv[finite, 1]).astype(np.int64)
    for k in np.flatnonzero(finite & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)):
        patch = depth_m[
            max(rows[k] - window_px, 0) : rows[k] + window_px + 1,
            max(cols[k] - window_px, 0) : cols[k] + window_px + 1,
        ]
        valid = patch[np.isfinite(patch) & (patch > 0)]
        agrees[k] = valid.size > 0 and np.min(np.abs(valid - points_cam[k, 2])) <= tol_m
    return agrees
