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
