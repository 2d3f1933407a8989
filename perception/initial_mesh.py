"""Laying the canonical mesh over the object in the first frame (paper, section III-A).

The object's 3D points are fitted with a plane; a hexagonal grid with the requested
spacing is laid in that plane, oriented with the image axes; the grid vertices whose
image falls on the object mask are kept, and each is lifted onto the measured surface
along its camera ray. A mesh built off-line (e.g. ``rectangle_mesh`` of a known size)
is placed the same way, centred on the object and aligned with its principal axes.

A real sensor mixes the object and what lies behind it at the object's edge: a few pixels of
the mask then read the wall a metre behind ("flying pixels"). A handful of them outweighs
the whole object in a least-squares plane and tilts it edge-on to the camera, and a vertex
lifted onto one is a spike; so depths far outside the object's own range count as missing
(``object_depth``).
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.geometry import pixel_index, project, rays
from perception.mesh import CanonicalMesh, lattice_covering, lattice_to_xy, mesh_from_lattice
from perception.observation import Observation
from perception.raster import disc

#: A depth further from the median of the object's than this many robust standard deviations
#: (from the median absolute deviation), and than ``FLYING_MIN_M``, is not the object's. On the
#: simulated scenes' first frames (hanging, lifted and table-top cloths) the object's depths
#: span at most 0.6 of that band; flying pixels lie metres off.
FLYING_SIGMAS = 6.0
FLYING_MIN_M = 0.15


class InitialisationError(ValueError):
    """The first frame cannot carry a mesh (empty mask, no depth, object too small)."""


def object_depth(depth_m: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``depth_m`` (H, W) metres with 0 where none was measured and where the depth lies
    outside the range of the object under ``mask`` (H, W) bool (``FLYING_SIGMAS``,
    ``FLYING_MIN_M``: flying pixels)."""
    depth = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0)
    z = depth[mask & (depth > 0)]
    if len(z) == 0:
        return depth
    median = float(np.median(z))
    band = max(FLYING_SIGMAS * 1.4826 * float(np.median(np.abs(z - median))), FLYING_MIN_M)
    return np.where(np.abs(depth - median) <= band, depth, 0.0)


def object_points(depth: np.ndarray, mask: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(P, 3) camera-frame points of the object: the pixels of ``mask`` (H, W) bool where
    ``depth`` (``object_depth``) has the object's depth, at most about 20000 of them."""
    ys, xs = np.nonzero(mask & (depth > 0))
    if len(xs) < 30:
        raise InitialisationError(f"the object mask has {len(xs)} pixels with depth; at least 30 are needed")
    step = max(1, len(xs) // 20000)
    uv = np.column_stack([xs[::step], ys[::step]]).astype(np.float64)
    return rays(uv, K) * depth[ys[::step], xs[::step], None]


def object_plane(depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, tuple, np.ndarray]:
    """What a mesh is laid from, for the object under ``mask`` (H, W) bool in ``depth_m`` (H, W):
    its depth (``object_depth``), the frame of the plane fitted to its points (``object_frame``:
    centre, u, v, normal) and the points giving its extent in that plane (``_extent_points``).
    Raises InitialisationError when fewer than 30 of its pixels have the object's depth."""
    depth = object_depth(depth_m, mask)
    c, u, v, n = object_frame(object_points(depth, mask, K))
    return depth, (c, u, v, n), _extent_points(depth_m, depth, mask, K, c, n)


def _extent_points(depth_m: np.ndarray, depth: np.ndarray, mask: np.ndarray, K: np.ndarray, centre: np.ndarray,
                   normal: np.ndarray) -> np.ndarray:
    """(P, 3) points giving the object's extent in its plane (``centre``, ``normal``): the
    pixels of ``mask`` where the sensor measured a depth (``depth_m`` > 0), at the object's
    depth (``depth``, ``object_depth``) where it has it, else where their ray meets the plane.
    A flying pixel is still the object's pixel; only its depth is not."""
    ys, xs = np.nonzero(mask & np.isfinite(depth_m) & (depth_m > 0))
    step = max(1, len(xs) // 20000)
    ys, xs = ys[::step], xs[::step]
    r = rays(np.column_stack([xs, ys]).astype(np.float64), K)
    z = depth[ys, xs].astype(np.float64)
    facing = r @ normal
    flying = (z <= 0) & (np.abs(facing) > 1e-9)
    z[flying] = (normal @ centre) / facing[flying]
    keep = z > 0  # a ray that meets the plane behind the camera gives no extent
    return r[keep] * z[keep, None]


def object_frame(points: np.ndarray):
    """Plane frame of an object's points (P, 3): centroid (3,), in-plane axes u, v (3,), normal (3,).

    The normal faces the camera; u follows the image x axis as closely as the plane allows,
    v completes a right-handed frame (so v follows the image y axis).
    """
    c = points.mean(axis=0)
    n = np.linalg.svd(points - c, full_matrices=False)[2][2]
    if n @ c > 0:  # face the camera at the origin
        n = -n
    x = np.array([1.0, 0.0, 0.0])
    u = x - (x @ n) * n
    if np.linalg.norm(u) < 1e-6:  # plane seen edge-on along x
        y = np.array([0.0, 1.0, 0.0])
        u = y - (y @ n) * n
    u /= np.linalg.norm(u)
    v = np.cross(-n, u)  # -n points away from the camera, like +z: (u, v, -n) right-handed as (x, y, z)
    return c, u, v, n


def lift(points_plane: np.ndarray, obs: Observation, depth: np.ndarray,
         mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Move points onto the measured surface along their camera rays.

    points_plane : (N, 3) camera-frame points (on the fitted plane)
    depth : (H, W) the object's depth (``object_depth``), 0 where none
    mask : (H, W) bool deciding which points are on the object (default: the observation's)
    returns (lifted (N, 3), on_object (N,) bool); points without depth stay where they were
    """
    uv = project(points_plane, obs.K)
    h, w = obs.mask.shape
    cols, rows, inside = pixel_index(uv, w, h)
    d = np.where(inside, depth[rows, cols], 0.0).astype(np.float64)
    on = inside & (obs.mask if mask is None else mask)[rows, cols]
    has = on & (d > 0)
    lifted = points_plane.copy()
    lifted[has] = rays(uv[has], obs.K) * d[has, None]
    return lifted, on


def solid_mask(mask: np.ndarray, close_px: int) -> np.ndarray:
    """The object mask without the gaps that missing depth leaves in it.

    Enclosed holes are filled and notches narrower than ``close_px`` closed: in a first
    frame they are almost always depth dropouts, and a mesh with holes there would keep
    them for the whole sequence.
    """
    m = mask.astype(np.uint8)
    if close_px >= 3:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, disc(close_px // 2))  # close_px wide, made odd
    padded = np.pad(m, 1)
    cv2.floodFill(padded, None, (0, 0), 2)  # everything reachable from outside
    return (padded[1:-1, 1:-1] != 2)


def object_area_m2(obs: Observation) -> float:
    """The object's area in square metres: the sum of its pixels' footprints on its fitted
    plane (a pixel at depth z covers (z / fx)(z / fy) square metres facing the camera, more
    on a tilted plane)."""
    depth = object_depth(obs.depth_m, obs.mask)
    ys, xs = np.nonzero(obs.mask & (depth > 0))
    if len(xs) < 30:
        raise InitialisationError(f"the object mask has {len(xs)} pixels with depth; at least 30 are needed")
    z = depth[ys, xs].astype(np.float64)
    r = rays(np.column_stack([xs, ys]).astype(np.float64), obs.K)
    _, _, _, n = object_frame(object_points(depth, obs.mask, obs.K))
    facing = np.abs(r @ n) / np.linalg.norm(r, axis=1)  # cosine between each pixel's ray and the plane's normal
    return float(np.sum(z * z / (obs.K[0, 0] * obs.K[1, 1]) / np.maximum(facing, 0.2)))


#: Lattice points of the hexagonal grid per square of the spacing (two equilateral triangles).
_POINTS_PER_SPACING_SQUARED = 2.0 / np.sqrt(3.0)

#: A mesh spacing chosen from ``target_vertices`` is never shorter than this many pixels at the
#: object's median depth: finer than that, the image has nothing to say about each triangle
MIN_SPACING_PX = 4.0


def mesh_vertices(area_m2: float, spacing_m: float) -> int:
    """About how many vertices a hexagonal mesh of ``spacing_m`` has over ``area_m2``."""
    return int(np.ceil(area_m2 * _POINTS_PER_SPACING_SQUARED / spacing_m**2))


def spacing_for_area(area_m2: float, vertices: int) -> float:
    """The spacing, metres, of a hexagonal mesh with about ``vertices`` vertices over
    ``area_m2`` (``mesh_vertices`` inverted); 0 for no area."""
    return float(np.sqrt(area_m2 * _POINTS_PER_SPACING_SQUARED / vertices))


def automatic_spacing(area_m2: float, target_vertices: int, median_depth_m: float, fx: float,
                      min_px: float = MIN_SPACING_PX) -> float:
    """The spacing, metres, of about ``target_vertices`` vertices over ``area_m2``
    (``spacing_for_area``), kept at ``min_px`` pixels or more at ``median_depth_m`` for a
    camera of focal length ``fx`` pixels: finer than that, the image has nothing to say about
    each triangle."""
    return float(max(spacing_for_area(area_m2, target_vertices), min_px * median_depth_m / fx))


def spacing_for(obs: Observation, target_vertices: int, min_px: float = MIN_SPACING_PX) -> float:
    """The mesh spacing, metres, that gives the object of ``obs`` about ``target_vertices`` vertices
    (``automatic_spacing`` over the object's area, ``object_area_m2``, and its median depth)."""
    depth = object_depth(obs.depth_m, obs.mask)
    z = depth[obs.mask & (depth > 0)]
    return automatic_spacing(object_area_m2(obs), target_vertices, float(np.median(z)), obs.K[0, 0], min_px)


def mesh_from_mask(obs: Observation, spacing_m: float) -> tuple[CanonicalMesh, np.ndarray]:
    """Build the canonical mesh over the object of ``obs``.

    returns (mesh, vertices (N, 3) float64 metres in the camera frame)
    """
    depth, (c, u, v, _), pts = object_plane(obs.depth_m, obs.mask, obs.K)
    pu, pv = (pts - c) @ u, (pts - c) @ v
    lat = lattice_covering((pu.min(), pu.max()), (pv.min(), pv.max()), spacing_m)
    xy = lattice_to_xy(lat, spacing_m)
    on_plane = c + xy[:, :1] * u + xy[:, 1:] * v
    spacing_px = obs.K[0, 0] * spacing_m / float(np.median(pts[:, 2]))
    _, on = lift(on_plane, obs, depth, solid_mask(obs.mask, int(round(spacing_px))))
    try:
        mesh = mesh_from_lattice(lat[on], spacing_m)
    except ValueError as e:
        raise InitialisationError(str(e)) from None
    xy = mesh.material_xy
    lifted, _ = lift(c + xy[:, :1] * u + xy[:, 1:] * v, obs, depth)
    return mesh, lifted


def place_mesh(mesh: CanonicalMesh, obs: Observation) -> np.ndarray:
    """Place an off-line mesh on the object: centred, longest side along the object's longest axis.

    returns (N, 3) float64 vertices in the camera frame, lifted onto the surface where seen
    """
    depth = object_depth(obs.depth_m, obs.mask)
    pts = object_points(depth, obs.mask, obs.K)
    c, u, v, _ = object_frame(pts)
    xy = mesh.material_xy - mesh.material_xy.mean(axis=0)
    obj_uv = np.column_stack([(pts - c) @ u, (pts - c) @ v])
    ou = np.linalg.svd(obj_uv - obj_uv.mean(axis=0), full_matrices=False)[2][0]
    mu = np.linalg.svd(xy, full_matrices=False)[2][0]
    ang = np.arctan2(ou[1], ou[0]) - np.arctan2(mu[1], mu[0])
    R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    xy = xy @ R.T + obj_uv.mean(axis=0)
    lifted, _ = lift(c + xy[:, :1] * u + xy[:, 1:] * v, obs, depth)
    return lifted
