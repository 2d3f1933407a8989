"""Whether a grasp point is seen: the measured depth around its pixel agrees with it.

Data form: points (K, 3) float64 metres in the camera's optical frame, their pixel
coordinates (K, 2) float64 (``perception.geometry.project``, NaN where not projectable),
and the depth image (H, W) float32 metres they are judged against.
"""

from __future__ import annotations

import numpy as np

from perception.geometry import pixel_index


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
    points_cam, depth_m, uv = np.asarray(points_cam, np.float64), np.asarray(depth_m), np.asarray(uv, np.float64)
    if depth_m.ndim != 2:
        raise ValueError(f"depth_m: expected (H, W) metres, got shape {depth_m.shape}")
    if points_cam.ndim != 2 or points_cam.shape[1] != 3 or uv.shape != (len(points_cam), 2):
        raise ValueError(f"points_cam and uv: expected (K, 3) and (K, 2), got {points_cam.shape} and {uv.shape}")
    if isinstance(window_px, bool) or not isinstance(window_px, (int, np.integer)) or window_px < 0:
        raise ValueError(f"window_px: expected an integer >= 0, got {window_px!r}")
    if not (np.isfinite(tol_m) and tol_m >= 0):
        raise ValueError(f"tol_m: expected a non-negative number of metres, got {tol_m!r}")
    height, width = depth_m.shape
    agrees = np.zeros(len(points_cam), bool)
    cols, rows, inside = pixel_index(uv, width, height)
    for k in np.flatnonzero(inside):
        patch = depth_m[
            max(rows[k] - window_px, 0) : rows[k] + window_px + 1,
            max(cols[k] - window_px, 0) : cols[k] + window_px + 1,
        ]
        valid = patch[np.isfinite(patch) & (patch > 0)]
        agrees[k] = valid.size > 0 and np.min(np.abs(valid - points_cam[k, 2])) <= tol_m
    return agrees
