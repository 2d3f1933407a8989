"""How high a cloth's outline stands above the surface just beyond it: one layer or more.

Where a cloth lying on a surface ends at a true corner, one layer lies there: its tip
rises one cloth thickness above the surface beyond the outline. Where the outline turns
at a fold's end, the cloth bends back over itself, and two layers lie there. The
outline alone cannot tell the two apart (both make the same angle, and the fold's end
lies as flat), but the height of the measured cloth just inside the outline above the
measured surface just outside it can, when the cloth is thick enough for the sensor.

Data form: points on the outline (K, 3) float64 metres in the camera's optical frame,
unit directions (K, 3) pointing out of the cloth, the up direction in the camera frame,
and the ``RGBDFrame`` they were seen in. Each height is the difference of the medians of
two patches of measured points (back-projected depth pixels), so that the sensor's
noise and disparity steps average out.
"""

from __future__ import annotations

import numpy as np

from ipc.messages import RGBDFrame
from perception.geometry import backproject, project


def step_above_beyond(points_cam: np.ndarray, outward_cam: np.ndarray, up_cam: np.ndarray, frame: RGBDFrame,
                      inside_m: tuple[float, float] = (0.005, 0.02), beyond_m: tuple[float, float] = (0.02, 0.04),
                      half_width_m: float = 0.007, sample_m: float = 0.002, min_pixels: int = 8) -> np.ndarray:
    """Height of the cloth just inside each outline point above the surface just beyond it.

    points_cam : (K, 3) float64 metres, camera frame, points on the cloth's outline
    outward_cam : (K, 3) float64, unit, camera frame: out of the cloth at each point,
        across its outline (horizontal, for a cloth lying on a surface)
    up_cam : (3,) float64, unit, camera frame
    frame : RGBDFrame the points were seen in (its ``depth_m`` and pinhole ``camera.K``)
    inside_m, beyond_m : (near, far) metres along ``outward_cam``: the inside patch spans
        ``-far .. -near``, the beyond patch ``near .. far``
    half_width_m : half-width of both patches across ``outward_cam``
    sample_m : spacing of the points that pick a patch's pixels (under a pixel's footprint)
    min_pixels : fewer valid depth pixels in a patch leave the height unmeasured

    Returns (K,) float64 metres, median height (along ``up_cam``) of the measured points
    in the inside patch minus that in the beyond patch; NaN where a patch leaves the
    image or has fewer than ``min_pixels`` pixels with depth.
    """
    points = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    outward = np.asarray(outward_cam, dtype=np.float64).reshape(-1, 3)
    up = np.asarray(up_cam, dtype=np.float64)
    lateral = np.cross(up[None], outward)
    across = np.arange(-half_width_m, half_width_m + 1e-12, sample_m)
    depth = frame.depth_m
    height, width = depth.shape
    steps = np.full(len(points), np.nan)

    def patch_height(k: int, near: float, far: float, sign: float) -> float:
        along = sign * np.arange(near, far + 1e-12, sample_m)
        a, b = np.meshgrid(along, across, indexing="ij")
        samples = points[k] + a.reshape(-1, 1) * outward[k] + b.reshape(-1, 1) * lateral[k]
        uv = project(samples, frame.camera.K, frame.camera.D)
        uv = uv[np.all(np.isfinite(uv), axis=1)]
        px = np.unique(np.rint(uv).astype(np.int64), axis=0)
        px = px[(px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)]
        z = depth[px[:, 1], px[:, 0]].astype(np.float64)
        ok = np.isfinite(z) & (z > 0)
        if np.count_nonzero(ok) < min_pixels:
            return np.nan
        return float(np.median(backproject(px[ok].astype(np.float64), z[ok], frame.camera.K) @ up))

    for k in range(len(points)):
        steps[k] = patch_height(k, *inside_m, -1.0) - patch_height(k, *beyond_m, 1.0)
    return steps
