"""What a frame must be for the tracker to work on it, checked before it gets there.

A frame that decodes (``ipc.RGBDFrame``: shapes agree, depth finite and >= 0) can still
describe no real camera: a principal point a million pixels away, a focal length of
1e-9 pixels, depth of 1e30 m or 1e-30 m (a wrong ``depth_scale`` gives such values). The
tracker's numbers overflow on such frames, or it builds a mesh of billions of vertices.
These checks name the problem instead, as a kind the perception service counts:

- ``no_depth``: no pixel with a depth measurement;
- ``bad_depth``: a measured depth outside [``MIN_DEPTH_M``, ``MAX_DEPTH_M``];
- ``bad_camera``: intrinsics no pinhole camera has (field of view outside
  [``MIN_FOV_DEG``, ``MAX_FOV_DEG``], pixels more than ``MAX_PIXEL_ASPECT`` times longer
  than wide, principal point more than an image size outside the image, distortion
  coefficients beyond ``MAX_DISTORTION``);
- ``bad_hold``: a held point (``RGBDFrame.held_points_m``) farther than ``MAX_DEPTH_M`` from
  the camera, which the hold term would drag the mesh to;

and, before a mesh is built, ``object_lattice_bound`` bounds the lattice the tracker lays
over an object and ``spacing_px`` the size of its image windows, so that an object too
large (or too small) for the mesh spacing is refused before any memory or time is spent.
"""

from __future__ import annotations

import math

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.initial_mesh import InitialisationError, object_plane
from perception.mesh import SQRT3_2

#: Depth range of every RGB-D sensor with margin, metres: structured light and time of
#: flight measure from a few centimetres to a few tens of metres (65.535 m is the largest
#: depth of 16-bit millimetres).
MIN_DEPTH_M = 1e-3
MAX_DEPTH_M = 100.0
#: Fields of view a pinhole model can describe, degrees, each axis.
MIN_FOV_DEG = 0.1
MAX_FOV_DEG = 179.0
#: Largest ratio of fx to fy (or fy to fx).
MAX_PIXEL_ASPECT = 10.0
#: Largest magnitude of a distortion coefficient; real lenses stay well below 10.
MAX_DISTORTION = 100.0

def check_camera(camera: CameraInfo) -> str | None:
    """One line naming what no pinhole camera has in ``camera``, or None if it is plausible."""
    w, h = camera.width, camera.height
    for axis, f, size in (("horizontal", camera.fx, w), ("vertical", camera.fy, h)):
        fov = math.degrees(2.0 * math.atan2(size, 2.0 * f))
        if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
            return (f"camera: {axis} field of view {fov:.3g} deg (f = {f:.6g} px over {size} px) outside "
                    f"[{MIN_FOV_DEG:g}, {MAX_FOV_DEG:g}] deg")
    aspect = camera.fx / camera.fy
    if not 1.0 / MAX_PIXEL_ASPECT <= aspect <= MAX_PIXEL_ASPECT:
        return f"camera: fx / fy = {aspect:.6g}, pixels more than {MAX_PIXEL_ASPECT:g} times longer than wide"
    if not (-w <= camera.cx <= 2 * w and -h <= camera.cy <= 2 * h):
        return f"camera: principal point ({camera.cx:.6g}, {camera.cy:.6g}) more than an image size outside the {w}x{h} image"
    if camera.D.size and float(np.abs(camera.D).max()) > MAX_DISTORTION:
        return f"camera: distortion coefficient of magnitude {float(np.abs(camera.D).max()):.6g} over {MAX_DISTORTION:g}"
    return None


def check_frame(frame: RGBDFrame) -> tuple[str, str] | None:
    """``(kind, one line)`` for the first reason ``frame`` cannot be tracked, or None.

    kind : "no_depth", "bad_depth", "bad_camera" or "bad_hold" (see the module docstring)
    """
    depth = frame.depth_m
    measured = depth > 0  # NaN compares false: not measured
    if not measured.any():
        return "no_depth", f"frame {frame.seq}: no valid depth pixel (all 0 or NaN)"
    nearest = float(depth.min(where=measured, initial=np.inf))
    farthest = float(np.fmax.reduce(depth, axis=None))
    if nearest < MIN_DEPTH_M or farthest > MAX_DEPTH_M:
        return "bad_depth", (f"frame {frame.seq}: depth from {nearest:.6g} m to {farthest:.6g} m, outside the "
                             f"[{MIN_DEPTH_M:g}, {MAX_DEPTH_M:g}] m of any RGB-D sensor (a wrong depth_scale?)")
    problem = check_camera(frame.camera)
    if problem is not None:
        return "bad_camera", f"frame {frame.seq}: {problem}"
    if frame.held_points_m is not None and frame.held_points_m.size:
        reach = np.linalg.norm(frame.held_points_m, axis=1)
        k = int(np.argmax(reach))
        if reach[k] > MAX_DEPTH_M:
            return "bad_hold", (f"frame {frame.seq}: held point {k} is {reach[k]:.6g} m from the camera, beyond the "
                                f"{MAX_DEPTH_M:g} m of any RGB-D sensor")
    return None


def seen_area_m2(frame: RGBDFrame, mask: np.ndarray | None = None) -> float:
    """Area in square metres of the surface seen in the pixels of ``mask`` ((H, W) bool; None:
    every pixel) that have depth, as if it faced the camera: a pixel at depth z covers
    (z / fx) x (z / fy). A tilted surface has more area than this."""
    measured = frame.depth_m > 0
    z = frame.depth_m[measured if mask is None else measured & mask].astype(np.float64)
    return float(np.sum(z * z)) / (frame.camera.fx * frame.camera.fy)


def spacing_px(frame: RGBDFrame, mask: np.ndarray, spacing_m: float) -> float:
    """Length in pixels of a mesh edge of ``spacing_m`` at the object's median depth (0 when no
    pixel of ``mask`` ((H, W) bool) has depth). The tracker's image operations on the object
    work in windows of this size."""
    z = frame.depth_m[mask & (frame.depth_m > 0)]
    if z.size == 0:
        return 0.0
    return frame.camera.fx * spacing_m / float(np.median(z))


def object_lattice_bound(frame: RGBDFrame, mask: np.ndarray, spacing_m: float) -> int:
    """About how many lattice points the tracker lays over the object under ``mask`` at
    ``spacing_m``: those covering the object's extent in the plane fitted to its points, as
    the tracker covers it (camera frame, lens distortion ignored: it moves points far less
    than a mesh spacing). The mesh keeps those that land on the object, so its vertices are
    fewer; a compact object fills most of the lattice.

    frame : a frame that passed ``check_frame``
    mask : (H, W) bool, the object's pixels
    returns an int >= 0 (0 when fewer than 30 pixels of the mask have depth: too few for a mesh)
    """
    try:
        _, (centre, u, v, _), points = object_plane(frame.depth_m, mask, frame.camera.K)  # as the tracker lays it
    except InitialisationError:  # under the 30 pixels a mesh needs: the object is tiny
        return 0
    extent_u, extent_v = np.ptp((points - centre) @ u), np.ptp((points - centre) @ v)
    # lattice_covering: rows SQRT3_2 * spacing apart, points spacing apart, one spacing of margin.
    return math.ceil((extent_u / spacing_m + 3.0) * (extent_v / (SQRT3_2 * spacing_m) + 3.0))
