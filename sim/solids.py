"""Rigid bodies drawn by ``sim.raster``: flat-coloured triangle meshes of boxes, cylinders, spheres.

Why: PyBullet's TinyRenderer redraws the whole room whenever a visible rigid body moves
(~70-150 ms at 640x480), so a moving occluder drawn by PyBullet would make every frame that
slow. A ``SolidMesh`` is drawn with the cloth's rasteriser instead, over PyBullet's cached
picture of the room (``sim.camera.VirtualCamera.render``), in a few milliseconds.

A ``SolidMesh`` holds points (V, 3) float64 metres in one frame (a body frame, or the world
once posed with ``transformed``), faces (F, 3) int64 and one colour per vertex (V, 3) uint8
RGB. Each flat face has its own vertices, so shading stays flat across box edges; a
cylinder's side shares its vertices around the ring, so it shades round. Meshes are closed;
the rasteriser draws both sides and its z-buffer keeps the near one.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from ipc.messages import CameraInfo
from perception.geometry import (
    check_ids,
    check_points,
    check_positive,
    check_transform,
    crop_intrinsics,
    face_normals,
    frame_along,
    project,
    transform_points,
)
from sim.raster import MeshRaster, Shading, rasterise_mesh

log = logging.getLogger(__name__)

# each palette colour fills a square of this many texels, so bilinear sampling at its
# centre returns the colour exactly
_PATCH_PX = 4


def _check_colour(colour) -> np.ndarray:
    c = np.asarray(colour, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.all(np.isfinite(c)) or c.min() < 0 or c.max() > 255:
        raise ValueError(f"colour: expected 3 numbers in [0, 255] (RGB), got {np.asarray(colour).tolist()}")
    return np.rint(c).astype(np.uint8)


@dataclass(frozen=True)
class SolidMesh:
    """A flat-coloured triangle mesh.

    points : (V, 3) float64 metres
    faces : (F, 3) int64 vertex ids
    colours : (V, 3) uint8 RGB, one per vertex
    """

    points: np.ndarray
    faces: np.ndarray
    colours: np.ndarray

    def __post_init__(self):
        points = check_points("SolidMesh.points", self.points, allow_empty=True)
        faces = check_ids("SolidMesh.faces", self.faces, len(points), ndim=2, allow_empty=True)
        colours = np.asarray(self.colours)
        if colours.shape != (len(points), 3):
            raise ValueError(f"SolidMesh.colours: expected shape ({len(points)}, 3), got {colours.shape}")
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "colours", colours.astype(np.uint8))

    def transformed(self, T_a_b: np.ndarray) -> SolidMesh:
        """The mesh with its points mapped from frame b to frame a by the (4, 4) rigid transform ``T_a_b``."""
        return SolidMesh(transform_points(check_transform("T_a_b", T_a_b), self.points),
                         self.faces, self.colours)


def merge(meshes) -> SolidMesh:
    """One SolidMesh holding all of ``meshes`` (an iterable of SolidMesh in one frame)."""
    meshes = list(meshes)
    if not meshes:
        return SolidMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3), np.uint8))
    offsets = np.cumsum([0] + [len(m.points) for m in meshes[:-1]])
    return SolidMesh(np.concatenate([m.points for m in meshes]),
                     np.concatenate([m.faces + k for m, k in zip(meshes, offsets)]),
                     np.concatenate([m.colours for m in meshes]))


def _painted(points: np.ndarray, faces: np.ndarray, colour) -> SolidMesh:
    return SolidMesh(points, faces, np.tile(_check_colour(colour), (len(points), 1)))


def box(half_extents_m, colour, T_frame_box: np.ndarray | None = None) -> SolidMesh:
    """A box centred on the origin of its own frame, axes along its edges.

    half_extents_m : (3,) positive, metres; colour : RGB in [0, 255]
    T_frame_box : (4, 4) pose of the box in the frame of the returned points (default identity)
    returns SolidMesh, 24 vertices (four per face) and 12 faces, wound outwards
    """
    half = np.asarray(half_extents_m, dtype=np.float64).reshape(-1)
    if half.shape != (3,) or not np.all(half > 0):
        raise ValueError(f"box: expected 3 positive half extents, got {np.asarray(half_extents_m).tolist()}")
    points, faces = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(normal, u)  # (u, v, normal) right-handed: corners counter-clockwise seen from outside
            base = len(points)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                points.append((normal + a * u + b * v) * half)
            faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    mesh = _painted(np.array(points), np.array(faces), colour)
    return mesh if T_frame_box is None else mesh.transformed(T_frame_box)


@functools.lru_cache(maxsize=16)
def _unit_cylinder(segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and faces of a closed cylinder of radius 1 from z = 0 to z = 1 (side, then caps)."""
    n = segments
    angle = 2.0 * np.pi * np.arange(n) / n
    ring = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(n)])
    k = np.arange(n)
    nxt = (k + 1) % n
    top = ring + [0.0, 0.0, 1.0]
    points = np.concatenate([ring, top, [[0.0, 0.0, 0.0]], ring, [[0.0, 0.0, 1.0]], top])
    c0, c1 = 2 * n, 3 * n + 1  # cap centres after the side's 2n points
    faces = np.concatenate([np.column_stack([k, nxt, n + nxt]), np.column_stack([k, n + nxt, n + k]),
                            np.column_stack([np.full(n, c0), c0 + 1 + nxt, c0 + 1 + k]),
                            np.column_stack([np.full(n, c1), c1 + 1 + k, c1 + 1 + nxt])])
    points.setflags(write=False)
    faces.setflags(write=False)
    return points, faces


def cylinder(start, end, radius_m: float, colour, segments: int = 16) -> SolidMesh:
    """A closed cylinder from ``start`` to ``end`` (each (3,), metres) of ``radius_m``.

    The side's vertices are shared around each ring (smooth shading); each cap has its own.
    """
    p0, p1 = np.asarray(start, dtype=np.float64).reshape(3), np.asarray(end, dtype=np.float64).reshape(3)
    radius = check_positive("radius_m", radius_m)
    length = float(np.linalg.norm(p1 - p0))
    if length < 1e-9:
        raise ValueError("cylinder: start and end coincide")
    if int(segments) < 3:
        raise ValueError(f"cylinder: expected at least 3 segments, got {segments}")
    points, faces = _unit_cylinder(int(segments))
    R = frame_along(p1 - p0)
    return _painted((points * [radius, radius, length]) @ R.T + p0, faces, colour)


@functools.lru_cache(maxsize=16)
def _unit_sphere(rings: int, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and faces of a UV sphere of radius 1 around the origin, poles on z."""
    r, s = rings, segments
    theta = np.pi * np.arange(1, r) / r  # the rings between the poles
    phi = 2.0 * np.pi * np.arange(s) / s
    ring_points = np.stack([np.outer(np.sin(theta), np.cos(phi)), np.outer(np.sin(theta), np.sin(phi)),
                            np.repeat(np.cos(theta)[:, None], s, axis=1)], axis=-1).reshape(-1, 3)
    points = np.concatenate([[[0.0, 0.0, 1.0]], ring_points, [[0.0, 0.0, -1.0]]])
    top, bottom = 0, len(points) - 1
    k = np.arange(s)
    nxt = (k + 1) % s
    faces = [np.column_stack([np.full(s, top), 1 + k, 1 + nxt])]
    for i in range(r - 2):
        a, b = 1 + i * s, 1 + (i + 1) * s
        faces += [np.column_stack([a + k, b + k, b + nxt]), np.column_stack([a + k, b + nxt, a + nxt])]
    last = 1 + (r - 2) * s
    faces.append(np.column_stack([np.full(s, bottom), last + nxt, last + k]))
    faces = np.concatenate(faces)
    points.setflags(write=False)
    faces.setflags(write=False)
    return points, faces


def sphere(centre, radius_m: float, colour, rings: int = 8, segments: int = 16) -> SolidMesh:
    """A UV sphere of ``radius_m`` around ``centre`` (3,), metres."""
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    radius = check_positive("radius_m", radius_m)
    if int(rings) < 2 or int(segments) < 3:
        raise ValueError(f"sphere: expected at least 2 rings and 3 segments, got {rings} and {segments}")
    points, faces = _unit_sphere(int(rings), int(segments))
    return _painted(points * radius + c, faces, colour)


def capsule(start, end, radius_m: float, colour, segments: int = 16) -> SolidMesh:
    """A cylinder from ``start`` to ``end`` with a hemisphere (a whole sphere) on each end."""
    return merge([cylinder(start, end, radius_m, colour, segments),
                  sphere(start, radius_m, colour, segments=segments), sphere(end, radius_m, colour, segments=segments)])


def rasterise_solid(mesh_cam: SolidMesh, camera: CameraInfo, shading: Shading, near_m: float = 0.05) -> MeshRaster:
    """Draw a SolidMesh whose points are in the camera's optical frame (z-buffered, shaded).

    The vertex colours become a small palette texture that ``sim.raster.rasterise_mesh``
    samples at each colour's centre, so a face comes out in its colour times the shading.
    Only the image window around the mesh's projection is rasterised (a camera cropped to
    it: the same pixel centres), and only the faces turned towards the camera: the meshes
    are closed and wound outwards, so a face turned away is always behind another.
    returns MeshRaster (rgb, depth_m, mask) of the whole image, as ``rasterise_mesh``
    """
    H, W = camera.height, camera.width
    rgb, depth, mask = np.zeros((H, W, 3), np.uint8), np.zeros((H, W), np.float32), np.zeros((H, W), bool)
    window = _window(mesh_cam.points, camera, near_m)
    if len(mesh_cam.faces) == 0 or window is None:
        return MeshRaster(rgb, depth, mask)
    x0, y0, x1, y1 = window
    p, f = mesh_cam.points, mesh_cam.faces
    normal = face_normals(p, f)
    facing = f[np.einsum("ij,ij->i", normal, p[f[:, 0]]) < 0]  # the camera is at the origin
    crop = CameraInfo(width=x1 - x0 + 1, height=y1 - y0 + 1, K=crop_intrinsics(camera.K, x0, y0))
    palette, index = np.unique(mesh_cam.colours, axis=0, return_inverse=True)
    index = index.reshape(-1)
    n = len(palette)
    texture = np.repeat(np.repeat(palette[None, :, :], _PATCH_PX, axis=0), _PATCH_PX, axis=1)  # (P, n*P, 3)
    tex_coords = np.column_stack([(index + 0.5) / n, np.full(len(index), 0.5)])
    drawn = rasterise_mesh(p, facing, tex_coords, np.ascontiguousarray(texture), crop, shading,
                           near_m=near_m)
    rgb[y0:y1 + 1, x0:x1 + 1] = drawn.rgb
    depth[y0:y1 + 1, x0:x1 + 1] = drawn.depth_m
    mask[y0:y1 + 1, x0:x1 + 1] = drawn.mask
    return MeshRaster(rgb, depth, mask)


def _window(points_cam: np.ndarray, camera: CameraInfo, near_m: float) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) inclusive pixel window holding the projection of the points in front of
    ``near_m`` (triangles with a nearer vertex are not drawn), None when it misses the image."""
    z = points_cam[:, 2]
    ahead = points_cam[z > near_m]
    if len(ahead) == 0:
        return None
    u, v = project(ahead, camera.K).T
    x0, x1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())), camera.width - 1)
    y0, y1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())), camera.height - 1)
    if x1 < x0 or y1 < y0:
        return None
    return x0, y0, x1, y1
