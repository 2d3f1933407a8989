"""The OpenGL matrices of PyBullet's renderer, made to agree with a pinhole ``CameraInfo`` (pure NumPy).

Frames: the camera frame is the OpenCV optical frame (x right, y down, z forward);
``T_world_cam`` (4, 4) maps camera-frame points to the world (z up). PyBullet's
renderer wants OpenGL matrices instead (eye frame x right, y up, z backward; column-
major flat lists), built here so that the rendered pixels agree with ``CameraInfo.K``.
The camera model itself and the rigid transforms are ``perception.geometry``'s.

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
from perception.geometry import check_transform, invert_transform

# OpenCV optical axes expressed in OpenGL eye axes (y and z flipped)
_OPTICAL_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def view_matrix(T_world_cam: np.ndarray) -> list[float]:
    """PyBullet view matrix (16 floats, column-major, world to OpenGL eye frame)."""
    T = check_transform("T_world_cam", T_world_cam)
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
