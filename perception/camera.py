"""Pinhole camera maths on NumPy arrays (OpenCV optical frame: x right, y down, z forward).

Pixel coordinates are (u, v) = (column, row) with the centre of the top-left pixel at
(0, 0), as OpenCV. Intrinsics are the row-major ``K`` of ``ipc.CameraInfo``.
"""

from __future__ import annotations

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame


def project(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Project camera-frame points to pixels.

    points_cam : (N, 3) float, metres; points with z <= 0 project to NaN
    K : (3, 3) float intrinsics
    returns (N, 2) float64 pixel coordinates (u, v)
    """
    p = np.asarray(points_cam, dtype=np.float64)
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.where(z > 0, 1.0 / z, np.nan)
    u = K[0, 0] * p[:, 0] * inv_z + K[0, 2]
    v = K[1, 1] * p[:, 1] * inv_z + K[1, 2]
    return np.stack([u, v], axis=1)


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
    """3D points at ``depth_m`` (metres along z) through pixels ``uv`` (N, 2); returns (N, 3)."""
    return rays(uv, K) * np.asarray(depth_m, dtype=np.float64)[:, None]


def pixel_index(uv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest integer pixel of each (u, v) and whether it lies in the image.

    returns (cols (N,) int, rows (N,) int, inside (N,) bool); cols and rows are clipped
    into the image so they can index it directly, check ``inside`` before trusting them.
    """
    finite = np.all(np.isfinite(uv), axis=1)
    uvr = np.where(finite[:, None], np.rint(uv), -1.0)
    cols = uvr[:, 0].astype(np.int64)
    rows = uvr[:, 1].astype(np.int64)
    inside = finite & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    return np.clip(cols, 0, width - 1), np.clip(rows, 0, height - 1), inside


class Undistorter:
    """Removes lens distortion from frames of one camera, so the tracker can use a pure pinhole model.

    The maps are computed once per CameraInfo. Colour is resampled bilinearly, depth with the
    nearest neighbour (interpolating across a depth edge would invent surfaces).
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
        return RGBDFrame(rgb, depth, self.pinhole, frame.timestamp_s, frame.seq, occluder_mask=occluder)
