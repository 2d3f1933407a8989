"""Pinhole camera maths on NumPy arrays (OpenCV optical frame: x right, y down, z forward).

Pixel coordinates are (u, v) = (column, row) with the centre of the top-left pixel at
(0, 0), as OpenCV. Intrinsics are the row-major ``K`` of ``ipc.CameraInfo``; lens
distortion ``D`` (OpenCV's and ROS CameraInfo's coefficients k1, k2, p1, p2 [, k3
[, k4, k5, k6]]) goes through OpenCV.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame


def project(points_cam: np.ndarray, K: np.ndarray, D: np.ndarray | None = None) -> np.ndarray:
    """Project camera-frame points to pixels.

    points_cam : (N, 3) float, metres; points with z <= 0 project to NaN
    K : (3, 3) float intrinsics
    D : distortion coefficients (0, 4, 5 or 8 of them), or None; all zero is a pinhole
    returns (N, 2) float64 pixel coordinates (u, v)
    """
    p = np.asarray(points_cam, dtype=np.float64)
    if D is not None and np.any(D):
        return _project_distorted(p, K, np.asarray(D, dtype=np.float64))
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.where(z > 0, 1.0 / z, np.nan)
    u = K[0, 0] * p[:, 0] * inv_z + K[0, 2]
    v = K[1, 1] * p[:, 1] * inv_z + K[1, 2]
    return np.stack([u, v], axis=1)


def _project_distorted(p: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    uv = np.full((len(p), 2), np.nan)
    in_front = p[:, 2] > 0
    if np.any(in_front):
        projected, _ = cv2.projectPoints(p[in_front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                         np.asarray(K, dtype=np.float64), D)
        uv[in_front] = projected.reshape(-1, 2)
    return uv


def rays(uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera rays through pixels, scaled so that z = 1.

    uv : (N, 2) float pixel coordinates
    returns (N, 3) float64; multiply by a depth (metres along z) to get the 3D point
    """
    uv = np.asarray(uv, dtype=np.float64)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=1)


def backproject(uv: np.ndarray, depth_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """3D points at ``depth_m`` (N,) (metres along z) through pixels ``uv`` (N, 2); returns (N, 3) float64."""
    return rays(uv, K) * np.asarray(depth_m, dtype=np.float64)[:, None]


def ray_lengths(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) float32 length of the z = 1 ray through each pixel centre: a pixel's range
    (distance from the camera) is its depth times this. Cached per camera."""
    return _ray_lengths(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))


@lru_cache(maxsize=4)
def _ray_lengths(fx: float, fy: float, cx: float, cy: float, w: int, h: int) -> np.ndarray:
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    lengths = np.sqrt(((uu - cx) / fx) ** 2 + ((vv - cy) / fy) ** 2 + 1.0).astype(np.float32)
    lengths.flags.writeable = False  # shared between callers
    return lengths


def pixel_index(uv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest integer pixel of each (u, v) and whether it lies in the image.

    uv : (N, 2) float pixel coordinates, NaN for none
    returns (cols (N,) int64, rows (N,) int64, inside (N,) bool); cols and rows are clipped
    into the image so they can index it directly, check ``inside`` before trusting them.
    """
    # Column by column: (N, 2) temporaries cost more than the arithmetic on them. A NaN
    # compares False, so a point without coordinates is never inside.
    u, v = np.rint(uv[:, 0]), np.rint(uv[:, 1])
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    finite = np.isfinite(u) & np.isfinite(v)
    cols = np.clip(np.where(finite, u, -1.0), 0, width - 1).astype(np.int64)
    rows = np.clip(np.where(finite, v, -1.0), 0, height - 1).astype(np.int64)
    return cols, rows, inside


def lens_coefficients(D: np.ndarray) -> np.ndarray:
    """(8,) float64: distortion coefficients ``D`` (0, 4, 5 or 8 of them, OpenCV's order) padded
    with zeros, so that two descriptions of one lens compare equal (none and all zero alike)."""
    D = np.asarray(D, np.float64).ravel()[:8]
    return np.pad(D, (0, 8 - D.size))


def same_optics(a: CameraInfo, b: CameraInfo) -> bool:
    """Whether cameras ``a`` and ``b`` name the same optical frame and lens distortion
    (``lens_coefficients``; size and intrinsics are not compared)."""
    return a.frame_id == b.frame_id and bool(np.allclose(lens_coefficients(a.D), lens_coefficients(b.D)))


def crop_intrinsics(K: np.ndarray, x0: float, y0: float) -> np.ndarray:
    """(3, 3) float64 intrinsics of the image window whose top-left pixel is (x0, y0) of the image of ``K``."""
    cropped = np.array(K, dtype=np.float64)
    cropped[0, 2] -= x0
    cropped[1, 2] -= y0
    return cropped


class Undistorter:
    """Removes lens distortion from frames of one camera, so that a pure pinhole model holds.

    The maps are computed once per CameraInfo. Colour is resampled bilinearly, depth and
    the occluder mask with the nearest neighbour (interpolating across a depth edge would
    invent surfaces).
    """

    def __init__(self, camera: CameraInfo):
        self.camera = camera
        self.active = camera.D.size > 0 and bool(np.any(camera.D != 0))
        if self.active:
            size = (camera.width, camera.height)
            self._maps = cv2.initUndistortRectifyMap(camera.K, camera.D, None, camera.K, size, cv2.CV_32FC1)
            self.pinhole = CameraInfo(camera.width, camera.height, camera.K, np.zeros(0), camera.frame_id)
        else:
            self.pinhole = camera

    def __call__(self, frame: RGBDFrame) -> RGBDFrame:
        if not self.active:
            return frame
        mx, my = self._maps
        rgb = cv2.remap(frame.rgb, mx, my, cv2.INTER_LINEAR)
        depth = cv2.remap(np.nan_to_num(frame.depth_m, nan=0.0), mx, my, cv2.INTER_NEAREST)
        occluder = None
        if frame.occluder_mask is not None:
            occluder = cv2.remap(frame.occluder_mask.view(np.uint8), mx, my, cv2.INTER_NEAREST) > 0
        # Everything else (what the robot holds and where, in 3D) does not depend on the lens.
        return replace(frame, rgb=rgb, depth_m=depth, camera=self.pinhole, occluder_mask=occluder)
