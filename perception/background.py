"""The object against a picture of the empty workspace: what differs from the background.

A robot with a fixed camera knows its workspace empty (a table, a floor, a wall). Depth
alone cannot tell a cloth lying on a table from the table (it is a few millimetres thick,
under the sensor's noise), and a tracked mesh whose object continues in depth into the
table is pulled onto the table as the cloth is lifted off it. Against the empty
workspace the object is what differs from it in colour, or lies nearer the camera than
the empty surface by more than the noise. A shadow the object casts differs in colour
too; the tracker only looks near where it predicts the object, which keeps such
stretches small. Pure OpenCV on arrays.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ipc.messages import RGBDFrame
from perception.geometry import pixel_index, project

log = logging.getLogger(__name__)

#: Euclidean RGB distance (8-bit levels) of a differing pixel, after a 3x3 Gaussian blur:
#: well above a sensor's colour noise (sigma 2 levels per channel), well below the contrast
#: of a pale print on a grey table (a threshold of 30 lost whole strips of such prints).
COLOUR_TOL = 12.0
#: A pixel nearer than the background by more than this differs, metres.
DEPTH_TOL_M = 0.02
#: Pixels this close to a differing one are not taken for the empty workspace: an outline
#: blurs over a pixel or two, and ``differs_from_background`` opens and closes with 5x5.
EDGE_PX = 3


def check_background(background: RGBDFrame, frame: RGBDFrame) -> None:
    """Raise ValueError (one line) unless ``background`` is an RGBDFrame of ``frame``'s size."""
    if not isinstance(background, RGBDFrame):
        raise ValueError(f"background: expected an RGBDFrame of the empty workspace, got {type(background).__name__}")
    if background.rgb.shape != frame.rgb.shape:
        raise ValueError(f"background: expected a {frame.camera.width}x{frame.camera.height} frame like the "
                         f"tracked ones, got {background.camera.width}x{background.camera.height}")


def differs_from_background(frame: RGBDFrame, background: RGBDFrame, colour_tol: float = COLOUR_TOL,
                            depth_tol_m: float = DEPTH_TOL_M) -> np.ndarray:
    """(H, W) bool: pixels of ``frame`` that are not the empty workspace ``background``.

    frame, background : RGBDFrame of the same camera, with and without the object
    A pixel differs when its colour is more than ``colour_tol`` from the background's (both
    blurred 3x3) or its depth is nearer than the background's by more than ``depth_tol_m``
    (both measured). Specks are opened away and small gaps closed (5x5).
    """
    if frame.rgb.shape != background.rgb.shape:
        raise ValueError(f"differs_from_background: frame {frame.rgb.shape} and background {background.rgb.shape} "
                         "differ in size")
    # Squared distances summed by OpenCV over the channels: the same test as the norm's,
    # at a tenth of NumPy's time on a VGA frame (it runs on every tracked frame).
    a = cv2.GaussianBlur(frame.rgb, (3, 3), 0)
    b = cv2.GaussianBlur(background.rgb, (3, 3), 0)
    diff = cv2.absdiff(a, b).astype(np.float32)
    squared = cv2.transform(cv2.multiply(diff, diff), np.ones((1, diff.shape[2]), np.float32))
    differs = squared > colour_tol ** 2
    d, r = frame.depth_m, background.depth_m
    with np.errstate(invalid="ignore"):
        nearer = (d > 0) & (r > 0) & (d < r - depth_tol_m)
    kernel = np.ones((5, 5), np.uint8)
    m = cv2.morphologyEx((differs | nearer).astype(np.uint8), cv2.MORPH_OPEN, kernel)
    return cv2.morphologyEx(m, cv2.MORPH_CLOSE, kernel).astype(bool)


def seen_through(vertices: np.ndarray, K: np.ndarray, differs: np.ndarray, depth_m: np.ndarray,
                 tol_m: float) -> np.ndarray:
    """(N,) bool: the vertices (N, 3) the camera sees the empty workspace through.

    Such a vertex projects into the image onto a pixel that shows the empty workspace (it does
    not differ from it, ``differs`` (H, W) bool, nor lies within ``EDGE_PX`` of a pixel that
    does), and lies nearer than the surface measured there by more than ``tol_m``, or the
    pixel has no depth. Nothing stands in front of the workspace at such a pixel, so the
    vertex is in the air. A vertex farther than the surface seen may be hidden by the
    workspace itself (a cloth hanging behind a table's edge) and is not counted; nor is one
    on it (a cloth of the table's colour lying on the table).
    """
    h, w = differs.shape
    near_object = cv2.dilate(differs.astype(np.uint8), np.ones((2 * EDGE_PX + 1,) * 2, np.uint8)).astype(bool)
    cols, rows, inside = pixel_index(project(vertices, K), w, h)
    d = depth_m[rows, cols]
    with np.errstate(invalid="ignore"):
        in_front = ~(np.isfinite(d) & (d > 0)) | (vertices[:, 2] < d - tol_m)
    return inside & ~near_object[rows, cols] & in_front
