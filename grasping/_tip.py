"""Where a corner's tip lies on the measured surface: the last centimetres of a corner grasp.

A tracked estimate says which material point is a corner and about where it is. On a cloth
that hangs and folds, the estimate's material points can lie several centimetres from
where they are along the cloth, while the depth image shows where the cloth ends. So a
corner grasp can be placed at the tip of the measured surface that continues the
estimate's corner outward, when that tip lies within reach of the estimate's corner;
where the surface runs on past the search, nothing is changed.

Data form: an ``RGBDFrame`` (depth (H, W) float32 metres, 0 or NaN missing; optional
``occluder_mask`` (H, W), non-zero on the robot's own hands), points (3,) or (K, 3)
float64 metres in the frame's camera frame, directions (3,) unit vectors in that frame.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ipc.messages import RGBDFrame
from perception.geometry import backproject, pixel_index, project

#: The tip must lie this fraction of the search radius short of it, outward: a measured
#: surface that reaches farther runs on past the search (an edge or the middle of the
#: cloth, not a tip).
TIP_MARGIN_FRACTION = 0.2
#: Points within this distance (metres, outward) of the farthest one are averaged into the
#: tip: a single pixel is noise.
TIP_BAND_M = 0.005
#: Fewest pixels of measured surface around the corner to look for a tip on.
MIN_SURFACE_PX = 20


def measured_tip(frame: RGBDFrame, position: np.ndarray, outward: np.ndarray, seeds: np.ndarray,
                 radius_m: float, max_step_m: float) -> np.ndarray | None:
    """The tip of the measured surface at a corner, or None where the frame shows none.

    The surface is the frame's measured depth within ``radius_m`` of ``position``, off the
    frame's known occluder, joined to the pixels of ``seeds`` (points of the estimate near
    the corner that the depth confirms) through neighbouring pixels whose depths differ by
    at most ``max_step_m``, so that the background behind a hanging cloth, or a hand in
    front of it, is not part of it. Its tip is where it reaches farthest along
    ``outward``. There is none when it reaches farther than ``1 - TIP_MARGIN_FRACTION`` of
    the radius (it runs on past the search), or covers fewer than ``MIN_SURFACE_PX``
    pixels, or no seed lies on it.

    Parameters
    ----------
    frame : RGBDFrame the estimate was made from
    position : (3,) float64 metres, camera frame: the estimate's corner
    outward : (3,) float64 unit vector: out of the cloth at the corner (away from the
        cloth, across the outline)
    seeds : (S, 3) float64 metres: estimate vertices around the corner that ``frame`` saw
    radius_m : float > 0, how far from ``position`` the tip may lie, metres
    max_step_m : float > 0, largest depth difference between neighbouring pixels of one
        surface, metres

    Returns
    -------
    (3,) float64 metres, camera frame: the mean of the surface's points within
    ``TIP_BAND_M`` of its farthest along ``outward``; or None
    """
    position = np.asarray(position, dtype=np.float64).reshape(3)
    outward = np.asarray(outward, dtype=np.float64).reshape(3)
    seeds = np.asarray(seeds, dtype=np.float64).reshape(-1, 3)
    if len(seeds) == 0 or not position[2] > 0:
        return None
    K = frame.camera.K
    height, width = frame.depth_m.shape
    centre = project(position[None], K, frame.camera.D)[0]
    if not np.all(np.isfinite(centre)):
        return None
    reach_px = int(np.ceil(radius_m * max(K[0, 0], K[1, 1]) / max(position[2] - radius_m, 0.05))) + 2
    c0, r0 = (int(max(np.floor(v) - reach_px, 0)) for v in centre)
    c1, r1 = int(min(np.ceil(centre[0]) + reach_px + 1, width)), int(min(np.ceil(centre[1]) + reach_px + 1, height))
    if c0 >= c1 or r0 >= r1:  # the corner projects outside the image
        return None
    depth = np.asarray(frame.depth_m[r0:r1, c0:c1], dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    if frame.occluder_mask is not None:
        valid &= ~np.asarray(frame.occluder_mask[r0:r1, c0:c1], dtype=bool)
    rows, cols = np.mgrid[r0:r1, c0:c1]
    points = backproject(np.column_stack([cols.ravel(), rows.ravel()]), np.where(valid, depth, 0.0).ravel(), K)
    points = points.reshape(*depth.shape, 3)
    near = valid & (np.linalg.norm(points - position, axis=2) <= radius_m)
    # A depth jump between neighbours starts another surface: cut the surface there.
    step = np.zeros(depth.shape, bool)
    filled = np.where(near, depth, np.nan)
    with np.errstate(invalid="ignore"):
        jump_down = np.abs(np.diff(filled, axis=0)) > max_step_m
        jump_right = np.abs(np.diff(filled, axis=1)) > max_step_m
    step[:-1] |= jump_down
    step[1:] |= jump_down
    step[:, :-1] |= jump_right
    step[:, 1:] |= jump_right
    labels, _ = ndimage.label(near & ~step)
    seed_cols, seed_rows, inside = pixel_index(project(seeds, K, frame.camera.D), width, height)
    seed_cols, seed_rows = seed_cols[inside] - c0, seed_rows[inside] - r0
    in_window = (seed_cols >= 0) & (seed_cols < c1 - c0) & (seed_rows >= 0) & (seed_rows < r1 - r0)
    seed_labels = np.unique(labels[seed_rows[in_window], seed_cols[in_window]])
    seed_labels = seed_labels[seed_labels > 0]
    surface = np.isin(labels, seed_labels)
    if seed_labels.size == 0 or np.count_nonzero(surface) < MIN_SURFACE_PX:
        return None
    on_surface = points[surface]
    reach = (on_surface - position) @ outward
    farthest = float(reach.max())
    if farthest > (1.0 - TIP_MARGIN_FRACTION) * radius_m:
        return None
    return on_surface[reach >= farthest - TIP_BAND_M].mean(axis=0)
