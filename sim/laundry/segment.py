"""The cloth in the first frame, found against a reference picture of the empty table.

Depth cannot separate a cloth lying on a table from the table (it is a few millimetres
thick, under the sensor's noise), so the tracker's depth segmentation finds nothing
there. A robot that knows its workspace has a picture of it empty; the cloth is what
differs from it (``perception.background``). ``cloth_points`` turns the mask into the
cloth's measured 3D points.
Pure OpenCV on arrays.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ipc.messages import RGBDFrame
from perception.background import COLOUR_TOL, DEPTH_TOL_M, differs_from_background
from perception.geometry import backproject

log = logging.getLogger(__name__)


def mask_from_reference(frame: RGBDFrame, reference: RGBDFrame, colour_tol: float = COLOUR_TOL,
                        depth_tol_m: float = DEPTH_TOL_M, min_area_px: int = 200,
                        exclude: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool mask of the largest region that differs from the empty reference.

    frame, reference : RGBDFrame of the same camera, with and without the cloth
    colour_tol, depth_tol_m : what differs (``perception.background.differs_from_background``)
    min_area_px : regions smaller than this are noise; the result is empty if none is larger
    exclude : (H, W) bool, pixels that are no cloth whatever they show (the robot's own
        hands and arms), left out before the regions are found: a robot's arm differs
        from the empty workspace too, and is often the larger region
    Holes inside the region (dropouts, a print in the table's colour) are filled.
    """
    if frame.rgb.shape != reference.rgb.shape:
        raise ValueError(f"mask_from_reference: frame {frame.rgb.shape} and reference {reference.rgb.shape} differ in size")
    differs = differs_from_background(frame, reference, colour_tol, depth_tol_m)
    if exclude is not None:
        differs &= ~np.asarray(exclude, dtype=bool)
    m = differs.astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1 or stats[1:, cv2.CC_STAT_AREA].max() < min_area_px:
        return np.zeros(m.shape, bool)
    region = (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    padded = np.pad(region, 1)
    cv2.floodFill(padded, None, (0, 0), 2)  # everything reachable from outside the region
    return padded[1:-1, 1:-1] != 2


def cloth_points(frame: RGBDFrame, mask: np.ndarray, reference: RGBDFrame, depth_tol_m: float = 0.02) -> np.ndarray:
    """(N, 3) float64 metres, camera frame: the measured points of the cloth in ``mask``.

    frame, reference : RGBDFrame of the same pinhole camera (its distortion, if any, is
        not undone), with and without the cloth
    mask : (H, W) bool, the cloth (``mask_from_reference``)
    depth_tol_m : only pixels nearer than the reference by more than this are kept: the
        mask is found by colour and its holes are filled, so it also holds the table seen
        through a gap between two layers or beside a thin edge, and a pixel whose depth is
        the table's is no point of the cloth. So this is for a cloth off the table (held
        up); on the table it leaves only the cloth's folds and layers.
    Pixels without depth (0 or NaN) here or in the reference are skipped; N may be 0.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != frame.depth_m.shape or reference.depth_m.shape != frame.depth_m.shape:
        raise ValueError(f"cloth_points: mask {mask.shape}, depth {frame.depth_m.shape} and reference depth "
                         f"{reference.depth_m.shape} differ in size")
    d, r = frame.depth_m, reference.depth_m
    with np.errstate(invalid="ignore"):
        nearer = np.isfinite(d) & (d > 0) & np.isfinite(r) & (r > 0) & (d < r - depth_tol_m)
    rows, cols = np.nonzero(mask & nearer)
    return backproject(np.column_stack([cols, rows]), d[rows, cols], frame.camera.K)


def cloth_seen(frame: RGBDFrame, reference: RGBDFrame) -> np.ndarray:
    """(H, W) bool: the cloth against the empty workspace, less the robot's own hands and arms
    (the frame's known occluder, if it has one)."""
    excluded = None if frame.occluder_mask is None else frame.occluder_mask.astype(bool)
    mask = mask_from_reference(frame, reference, exclude=excluded)
    if excluded is not None:  # the filled holes may hold some of it
        mask &= ~excluded
    return mask


def seen_cloth_points(frame: RGBDFrame, reference: RGBDFrame) -> np.ndarray:
    """(N, 3) float64 metres, camera frame: the measured points of the cloth off the table,
    less what the robot's hands cover (``cloth_points`` of ``cloth_seen``)."""
    return cloth_points(frame, cloth_seen(frame, reference), reference)
