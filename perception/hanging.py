"""What a robot knows about a cloth hanging from one of its grippers: which material point is lowest, and where.

A cloth held up by one point, clear of everything else, hangs with the material farthest
from the hand (along the cloth) lowest: gravity pulls every point as far down as the
cloth between it and the hand lets it. A towel held by a corner hangs along its diagonal
with the opposite corner lowest; a T-shirt held by a hem corner hangs with its farthest
sleeve or shoulder lowest. The depth camera sees where the cloth's lowest point is; the
canonical (rest) mesh says which material point that is. Together they are a
correspondence like the robot's grip: the robot sends it with each frame while the cloth
hangs at rest from one gripper (``HangingCue``; ``RGBDFrame.held_vertices`` and
``held_points_m``, beside the gripper's own), and the tracker keeps that vertex there.

Why: depth pulls a mesh vertex only towards the measured surface, so on a cloth without
print the tracked material can slide along the hanging surface unseen; on 6 of 13 recorded
lifts the tracker put the farthest material point 12-29 cm too high. One point held at each
end of the hanging cloth takes away part of that slide (docs/results.md, "Unfolding").

Data form: the observed points of the cloth, (M, 3) float64 metres in the camera's optical
frame (depth pixels of the cloth's mask, back-projected), the gripper's position (3,) in the
same frame, ``T_world_cam`` (4, 4), and the tracked mesh's canonical vertices (N, 3) metres
and faces (F, 3).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from perception.geometry import check_points, check_positive, check_transform, check_vector, edge_length_graph


def lowest_point(points_cam, up_cam, min_neighbours: int = 5, support_radius_m: float = 0.01) -> np.ndarray:
    """(3,) float64: the lowest of ``points_cam`` (N, 3) along ``up_cam`` (3,) with at least
    ``min_neighbours`` other points within ``support_radius_m`` metres, so that a few stray
    points below the cloth do not count.

    Raises ValueError when no point has that many neighbours.
    """
    points = check_points("points_cam", points_cam)
    up = check_vector("up_cam", up_cam, unit=True)
    if isinstance(min_neighbours, bool) or int(min_neighbours) != min_neighbours or min_neighbours < 0:
        raise ValueError(f"Expected min_neighbours an integer >= 0, got {min_neighbours}")
    support_radius_m = check_positive("support_radius_m", support_radius_m)
    tree = cKDTree(points)
    for k in np.argsort(points @ up, kind="stable"):
        if len(tree.query_ball_point(points[k], support_radius_m)) > min_neighbours:  # the point itself counts too
            return points[k]
    raise ValueError(f"Expected a cloth: no point of {len(points)} has {min_neighbours} others within "
                     f"{support_radius_m} m")


def farthest_vertex(canonical, faces, held_vertex: int) -> tuple[int, float]:
    """The vertex of the mesh farthest from ``held_vertex`` along its edges, in the canonical
    (rest) shape: the material point that hangs lowest when the cloth is held there.

    canonical : (N, 3) float metres; faces : (F, 3) int; held_vertex : int in [0, N)
    returns (vertex id, its distance from the held vertex along the mesh in metres)
    Raises ValueError for a held vertex outside the mesh or one touching no face.
    """
    rest = check_points("canonical", canonical)
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"Expected faces (F, 3) int, got {f.dtype} {f.shape}")
    n = len(rest)
    if isinstance(held_vertex, (bool, np.bool_)) or not isinstance(held_vertex, (int, np.integer)) \
            or not 0 <= held_vertex < n:
        raise ValueError(f"Expected held_vertex a vertex id in [0, {n}), got {held_vertex!r}")
    distance = dijkstra(edge_length_graph(rest, f), directed=False, indices=int(held_vertex))
    distance[~np.isfinite(distance)] = -1.0  # another piece of the mesh: not carried by this hand
    far = int(np.argmax(distance))
    if distance[far] <= 0:
        raise ValueError(f"Expected held_vertex on a face of the mesh, got vertex {held_vertex}, joined to no other")
    return far, float(distance[far])


def lowest_tip(points_cam, up_cam, tip_band_m: float = 0.015, min_points: int = 20) -> np.ndarray | None:
    """(3,) float64, camera frame: the tip of a hanging cloth seen as ``points_cam`` (M, 3)
    metres, or None when fewer than ``min_points`` points, or only scattered specks, are seen.

    The tip is the mean of the points within ``tip_band_m`` in height of the lowest point
    (``lowest_point``, which passes over stray points below the cloth) and within three
    times that sideways of it: less noisy than one pixel.
    """
    points = check_points("points_cam", points_cam, allow_empty=True)
    up = check_vector("up_cam", up_cam, unit=True)
    tip_band_m = check_positive("tip_band_m", tip_band_m)
    if len(points) < min_points:
        return None
    try:
        tip = lowest_point(points, up)
    except ValueError:
        return None
    height = (points - tip) @ up
    sideways = (points - tip) - np.outer(height, up)
    near = (np.abs(height) <= tip_band_m) & (np.linalg.norm(sideways, axis=1) <= 3.0 * tip_band_m)
    return points[near].mean(axis=0)


class HangingCue:
    """Frame after frame, while one gripper holds the cloth: once it hangs at rest, the
    material point it has lowest and where the camera sees it.

    The cloth hangs at rest, for this purpose, when three things hold:

    - its lowest point has been seen on the support (``support_height_m``, world height,
      e.g. the table top) since the cue was made, and is now more than ``clearance_m``
      above it: this gripper lifted it off. A cloth that came into the gripper's hold
      otherwise (a holder above let go of it once the robot held its lowest corner) falls
      over first, and the tracked mesh followed that fall too loosely for one pulled vertex
      to set right (without this rule, half of such unfold trials tracked two to four times
      worse); with ``support_height_m`` None, any cloth counts;
    - it lies at least ``min_drop_fraction`` of the farthest material point's distance
      (along the cloth) below the gripper: a cloth held near its lowest point does not hang
      from it;
    - it has kept its place relative to the gripper within ``still_m`` over the last
      ``still_frames`` frames: carried up at a steady speed or hanging still, not falling
      or swinging.

    canonical : (N, 3) float metres, faces : (F, 3) int: the tracked mesh
        (``MeshEstimate.canonical`` and ``faces``); held_vertex : the vertex held
    T_world_cam : (4, 4) float, camera frame to a world frame in which ``up_world`` is up
    """

    def __init__(self, canonical, faces, held_vertex: int, T_world_cam, support_height_m: float | None = None,
                 clearance_m: float = 0.03, min_drop_fraction: float = 0.5, still_frames: int = 3,
                 still_m: float = 0.02, up_world=(0.0, 0.0, 1.0)):
        self.vertex, self.reach_m = farthest_vertex(canonical, faces, held_vertex)
        T = check_transform("T_world_cam", T_world_cam)
        up_world = check_vector("up_world", up_world, unit=True)
        self._up_cam = T[:3, :3].T @ up_world
        self._camera_height = float(up_world @ T[:3, 3])  # world height of the camera frame's origin
        self.support_height_m = None if support_height_m is None else float(support_height_m)
        self.lifted = support_height_m is None  # seen on the support, then clear of it
        self.clearance_m = check_positive("clearance_m", clearance_m, allow_zero=True)
        self.min_drop_fraction = check_positive("min_drop_fraction", min_drop_fraction, allow_zero=True)
        if isinstance(still_frames, bool) or int(still_frames) != still_frames or still_frames < 1:
            raise ValueError(f"Expected still_frames an integer >= 1, got {still_frames}")
        self.still_frames = int(still_frames)
        self.still_m = check_positive("still_m", still_m)
        self._offsets: deque[np.ndarray] = deque(maxlen=self.still_frames)  # the tip relative to the gripper

    def update(self, points_cam, gripper_cam) -> tuple[int, np.ndarray] | None:
        """This frame's cue: (vertex id, (3,) float64 point in the camera frame), or None.
        Call it on every frame while the gripper holds the cloth: rest is judged over frames.

        points_cam : (M, 3) float metres, camera frame: the observed points of the cloth
        gripper_cam : (3,) float metres, camera frame: where the gripper holds it
        """
        grip = check_vector("gripper_cam", gripper_cam)
        tip = lowest_tip(points_cam, self._up_cam)
        if tip is None or not self._hangs_clear(tip, grip):
            self._offsets.clear()
            return None
        self._offsets.append(tip - grip)
        if len(self._offsets) < self.still_frames:
            return None
        offsets = np.stack(self._offsets)
        if np.linalg.norm(offsets - offsets.mean(axis=0), axis=1).max() > self.still_m:
            return None
        return self.vertex, tip

    def _hangs_clear(self, tip: np.ndarray, grip: np.ndarray) -> bool:
        if self.support_height_m is not None and \
                float(self._up_cam @ tip) + self._camera_height <= self.support_height_m + self.clearance_m:
            self.lifted = True  # on the support: from now on, clear of it means lifted off it
            return False
        return self.lifted and float(self._up_cam @ (grip - tip)) >= self.min_drop_fraction * self.reach_m
