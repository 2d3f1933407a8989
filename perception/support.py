"""The surface the object rests on or stands in front of, seen around it in the first frame.

A cloth lies on a table, or hangs in front of a wall. Once a corner is lifted, the table
shows where the cloth was, nearer the camera than a mesh that lags behind the lift: to a
test that looks for objects in front of the cloth (``perception.occluders``) the bared
table looks like one. Knowing the table tells the two apart. Without a picture of the
empty workspace (``perception.background``), the tracker fits a plane to the depth
measured in a ring around the object as it is laid; the plane carries on under the object,
so table pixels the cloth covered then are known to be table once bared.

Only a plane that most of the ring lies on, and that reaches well beyond the object, is
kept: around a foam tube held by two hands the ring is mostly the hands, which hold it in a
plane of their own but one no larger than the tube, and no support is claimed. A camera
that moves after the first frame (on a wrist) takes the plane along wrongly; a fixed camera
is assumed.

Arrays: depth (H, W) float32 metres, 0 or NaN where unmeasured; masks (H, W) bool; K (3, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from perception.geometry import backproject
from perception.raster import disc
from perception.segmentation import fit_plane_ransac, valid_depth

#: The ring's inner edge lies this far outside the object's mask (pixels): the outline's
#: own pixels mix the object's depth with what is behind it.
RING_GAP_PX = 4
#: The ring's width, pixels.
RING_PX = 30
#: A point within this distance of the plane lies on it, metres: above a depth sensor's noise
#: at a metre or two, below the height of a hand resting on the table.
ON_PLANE_M = 0.012
#: Share of the ring's measured points that must lie on the plane for it to be kept.
MIN_SHARE = 0.6
#: The plane's pixels outside the object must cover this many times the object's area: a
#: table or a wall is larger than what lies on or hangs in front of it.
MIN_EXTENT = 2.0
#: Measured ring points, at least, for a plane to be fitted.
MIN_POINTS = 200
#: Ring points a fit uses, at most (sampled evenly), and the random planes tried.
MAX_POINTS, TRIALS = 3000, 200


@dataclass(frozen=True)
class SupportPlane:
    """A plane in the camera frame: unit ``normal`` (3,) towards the camera, and ``offset``
    metres, so that a point p lies at signed height ``normal @ p + offset`` above it."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """(P,) metres above the plane (towards the camera) of ``points`` (P, 3)."""
        return points @ self.normal + self.offset

    def on_plane(self, depth_m: np.ndarray, K: np.ndarray, x0: int = 0, y0: int = 0, step: int = 1,
                 tol_m: float = ON_PLANE_M) -> np.ndarray:
        """(h, w) bool: the pixels of ``depth_m`` (h, w) whose measured point lies within
        ``tol_m`` of the plane. ``depth_m`` may be a box of the image, read on every
        ``step``-th pixel from column ``x0``, row ``y0``, as ``depth[y0::step, x0::step]``."""
        h, w = depth_m.shape
        rows, cols = np.indices((h, w))
        uv = np.column_stack([(x0 + step * cols).ravel(), (y0 + step * rows).ravel()])
        points = backproject(uv, np.where(valid_depth(depth_m), depth_m, np.nan).ravel(), K)
        with np.errstate(invalid="ignore"):
            return (np.abs(self.height(points)) <= tol_m).reshape(h, w)


def _grown(mask: np.ndarray, radius: int) -> np.ndarray:
    return cv2.dilate(mask.view(np.uint8), disc(radius)).view(bool)


def fit_support(depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray, seed: int = 0) -> SupportPlane | None:
    """The plane most of a ring around ``mask`` (H, W) bool (the object) lies on, or None
    when none does (see the module docstring). The object must not lie behind it: a plane
    through a frame or an arm in front of the object is not its support. ``seed`` seeds the
    random planes tried (the fit is the same every time for the same frame)."""
    mask = np.ascontiguousarray(mask, dtype=bool)
    ring = _grown(mask, RING_GAP_PX + RING_PX) & ~_grown(mask, RING_GAP_PX)
    ring &= valid_depth(depth_m)
    rows, cols = np.nonzero(ring)
    if len(rows) < MIN_POINTS:
        return None
    pick = np.linspace(0, len(rows) - 1, min(len(rows), MAX_POINTS)).astype(int)
    points = backproject(np.column_stack([cols[pick], rows[pick]]), depth_m[rows[pick], cols[pick]], K)
    normal, offset, count = fit_plane_ransac(points, ON_PLANE_M, np.random.default_rng(seed), TRIALS)
    if normal is None or count < MIN_SHARE * len(points):
        return None
    if offset < 0:  # the normal towards the camera, at the origin
        normal, offset = -normal, -offset
    plane = SupportPlane(np.asarray(normal, np.float64), float(offset))
    obj_rows, obj_cols = np.nonzero(mask & valid_depth(depth_m))
    if not len(obj_rows):
        return None
    obj = backproject(np.column_stack([obj_cols, obj_rows]), depth_m[obj_rows, obj_cols], K)
    if np.median(plane.height(obj)) < -ON_PLANE_M:
        return None
    if np.count_nonzero(plane.on_plane(depth_m, K) & ~mask) < MIN_EXTENT * np.count_nonzero(mask):
        return None
    return plane
