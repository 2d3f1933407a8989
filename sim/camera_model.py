"""Pinhole camera maths shared by the virtual camera (pure NumPy, no PyBullet).

Frames: the camera frame is the OpenCV optical frame (x right, y down, z forward);
``T_world_cam`` (4, 4) maps camera-frame points to the world (z up). PyBullet's
renderer wants OpenGL matrices instead (eye frame x right, y up, z backward; column-
major flat lists), built here so that the rendered pixels agree with ``CameraInfo.K``.

Pixel convention: OpenCV's, the centre of pixel (col, row) is (u, v) = (col, row). The
PyBullet TinyRenderer shades column ``c`` at window x = c and row ``r`` at window
y = H - 1 - r (measured: an edge at u = 32.25 first covers column 33, one at v = 24.25
first covers row 24 with a symmetric frustum of a 48-row image). ``projection_matrix``
folds that sampling into the matrix, so any K (also an off-centre principal point)
renders where K projects.
"""

from __future__ import annotations

import numpy as np

from ipc.messages import CameraInfo

# OpenCV optical axes expressed in OpenGL eye axes (y and z flipped)
_OPTICAL_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def check_transform(T, name: str = "T") -> np.ndarray:
    """Return ``T`` as a (4, 4) float64 rigid transform or raise ValueError naming the shape."""
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise ValueError(f"{name}: expected a (4, 4) transform, got shape {arr.shape}")
    R = arr[:3, :3]
    if not np.all(np.isfinite(arr)) or np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6:
        raise ValueError(f"{name}: expected a rotation in the upper-left 3x3, got determinant {np.linalg.det(R):.6g}")
    if np.any(arr[3] != [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{name}: expected last row [0, 0, 0, 1], got {arr[3].tolist()}")
    return arr


def check_points_3d(points, name: str = "points") -> np.ndarray:
    """Return ``points`` as an (N, 3) float64 array or raise ValueError naming the shape."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3), got {arr.shape}")
    return arr


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam of a camera at ``eye`` looking at ``target``, image up along ``up``.

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


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (N, 3) points from frame b to frame a with the (4, 4) transform ``T_a_b``."""
    T = np.asarray(T_a_b, dtype=np.float64)
    p = check_points_3d(points_b, "transform_points: points_b")
    return p @ T[:3, :3].T + T[:3, 3]


def invert_transform(T_a_b: np.ndarray) -> np.ndarray:
    """T_b_a of a rigid (4, 4) transform."""
    T = check_transform(T_a_b, "invert_transform: T_a_b")
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def view_matrix(T_world_cam: np.ndarray) -> list[float]:
    """PyBullet view matrix (16 floats, column-major, world to OpenGL eye frame)."""
    T = check_transform(T_world_cam, "view_matrix: T_world_cam")
    world_to_gl = _OPTICAL_TO_GL @ invert_transform(T)
    return world_to_gl.T.ravel().tolist()


def projection_matrix(camera: CameraInfo, near_m: float, far_m: float) -> list[float]:
    """PyBullet projection matrix (16 floats, column-major) that renders as ``camera.K``.

    For a centred camera (cx = W/2, cy = H/2 - 1 under the TinyRenderer's sampling) it
    equals ``pybullet.computeProjectionMatrixFOV``; other principal points shift the
    frustum. near_m, far_m : clipping distances along the optical axis, metres.
    """
    if not 0 < near_m < far_m:
        raise ValueError(f"projection_matrix: expected 0 < near_m < far_m, got {near_m}, {far_m}")
    W, H = camera.width, camera.height
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * camera.fx / W
    P[0, 2] = 1.0 - 2.0 * camera.cx / W
    P[1, 1] = 2.0 * camera.fy / H
    P[1, 2] = 2.0 * (camera.cy + 1.0) / H - 1.0
    P[2, 2] = -(far_m + near_m) / (far_m - near_m)
    P[2, 3] = -2.0 * far_m * near_m / (far_m - near_m)
    P[3, 2] = -1.0
    return P.T.ravel().tolist()


def depth_from_zbuffer(zbuffer: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """Metric depth along the optical axis from an OpenGL depth buffer.

    zbuffer : (H, W) float in [0, 1] (PyBullet ``getCameraImage`` depth)
    returns (H, W) float32 metres; pixels at the far plane (nothing drawn) become 0
    """
    zb = np.asarray(zbuffer, dtype=np.float64)
    depth = far_m * near_m / (far_m - (far_m - near_m) * zb)
    depth[zb >= 1.0 - 1e-7] = 0.0
    return depth.astype(np.float32)


def camera_info_from_fov(width: int, height: int, fov_y_rad: float, frame_id: str = "camera_color_optical_frame") -> CameraInfo:
    """Square-pixel CameraInfo whose image the TinyRenderer draws with a symmetric
    frustum of vertical field of view ``fov_y_rad`` (principal point cx = W/2,
    cy = H/2 - 1, see the module docstring)."""
    f = 0.5 * height / np.tan(0.5 * fov_y_rad)
    K = np.array([[f, 0.0, 0.5 * width], [0.0, f, 0.5 * height - 1.0], [0.0, 0.0, 1.0]])
    return CameraInfo(width=width, height=height, K=K, frame_id=frame_id)
