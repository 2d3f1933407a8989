"""Grasping a cloth that hangs from one point: at its lowest point.

A cloth held up by one point hangs with a corner lowest: gravity pulls the material
farthest below the hand straight down, and that is where the cloth ends (a towel held
by a corner hangs along its diagonal, the opposite corner lowest; a shirt held by a hem
corner or a cuff hangs with another hem corner or cuff lowest). Laundry robots grasp a
hanging garment there (Osawa et al. 2007; Maitin-Shepard et al. 2010).

Data form: the observed points of the cloth, (N, 3) float64 metres in the camera's
optical frame (e.g. the depth pixels inside the cloth's mask, back-projected), and
``T_world_cam`` (4, 4), camera frame to a world frame in which ``up_world`` is up. The
points, not a tracked mesh: a mesh laid over a hanging cloth from one view covers what
was seen at its first frame, and the lowest point is often at its ragged edge.

Output: a ``GraspPlan`` of kind "corner" in the camera frame, following the gripper
convention of ``grasping`` (z = approach, x = closing): the gripper comes up from
below, its fingers closing across the cloth (along the horizontal part of the cloth's
normal at the tip), the fingertips ``inset_m`` above the lowest point so that they
close on cloth. A robot arm cannot bring its hand up under a cloth that hangs a few
centimetres above a table; ``from_the_side`` turns the same grasp to come in horizontally.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
from scipy.spatial.transform import Rotation

from ipc.messages import GraspPlan
from perception.geometry import (
    check_points,
    check_positive,
    check_transform,
    check_vector,
    frames_from_z_and_x,
    quaternion_xyzw_from_matrix,
)
from perception.hanging import lowest_point

log = logging.getLogger(__name__)


def lowest_point_grasp(points_cam, T_world_cam, up_world=(0.0, 0.0, 1.0), min_neighbours: int = 5,
                       support_radius_m: float = 0.01, inset_m: float = 0.005, neighbourhood_m: float = 0.04,
                       opening_width_m: float = 0.04, frame_id: str = "camera_color_optical_frame",
                       timestamp_s: float = 0.0) -> GraspPlan:
    """A grasp at the lowest point of a hanging cloth (see the module docstring).

    Parameters
    ----------
    points_cam : (N, 3) float, metres, camera frame: observed points of the cloth, N >= 3
    T_world_cam : (4, 4) float, rigid transform, camera frame to world frame
    up_world : (3,) float, the up direction in the world frame (normalised here)
    min_neighbours : int >= 0, the lowest point is the lowest one with at least this many
        other points within ``support_radius_m`` (metres, > 0), so that a few stray points
        below the cloth do not count
    inset_m : float > 0, metres: the fingertips close this far above the lowest point (a
        depth sensor loses the last centimetre or so of a thin edge seen from above, so
        the lowest measured point is already that far inside the cloth)
    neighbourhood_m : float > 0, metres: the cloth's plane at the tip is fitted to the
        points this close to the lowest point; it sets the closing direction
    opening_width_m : float > 0, finger opening before closing, metres
    frame_id, timestamp_s : copied into the plan

    Returns
    -------
    GraspPlan, kind "corner", camera frame: ``position`` (3,) metres, ``approach`` =
    up (in the camera frame), ``quat_xyzw`` of ``R_cam_gripper`` with x (closing) the
    horizontal part of the tip's normal, or the horizontal viewing direction where the
    cloth at the tip lies flat; ``score`` 1, ``vertex_id`` -1 (no mesh vertex)

    Raises
    ------
    ValueError : malformed points or transform, fewer than 3 points, no point with
        ``min_neighbours`` neighbours, bad parameters
    """
    points = check_points("points_cam", points_cam)
    if len(points) < 3:
        raise ValueError(f"Expected points_cam with at least 3 points, got {len(points)}")
    T = check_transform("T_world_cam", T_world_cam)
    up_cam = T[:3, :3].T @ check_vector("up_world", up_world, unit=True)
    inset_m = check_positive("inset_m", inset_m)
    neighbourhood_m = check_positive("neighbourhood_m", neighbourhood_m)
    opening_width_m = check_positive("opening_width_m", opening_width_m)
    tip = lowest_point(points, up_cam, min_neighbours, support_radius_m)

    # Closing direction: across the cloth at its tip, i.e. the horizontal part of the
    # normal of the plane through the nearby points; where that is too short (the cloth
    # lies flat there, or too few points), across the line of sight.
    near = points[np.linalg.norm(points - tip, axis=1) <= neighbourhood_m]
    closing = np.zeros(3)
    if len(near) >= 3:
        _, singular, vt = np.linalg.svd(near - near.mean(axis=0), full_matrices=False)
        if singular[1] > 1e-9:
            closing = vt[2] - (vt[2] @ up_cam) * up_cam
    if np.linalg.norm(closing) < 0.3:
        closing = tip - (tip @ up_cam) * up_cam  # the ray to the tip (camera at the origin), made horizontal
    if np.linalg.norm(closing) < 1e-9:  # looking straight down at the tip
        closing = np.array([1.0, 0.0, 0.0]) - up_cam[0] * up_cam
    closing = closing / np.linalg.norm(closing)

    R = frames_from_z_and_x(up_cam[None], closing[None])
    log.debug("lowest point of %d cloth points at %s (camera frame)", len(points), np.round(tip, 3).tolist())
    return GraspPlan(position=tip + inset_m * up_cam, approach=R[0][:, 2], quat_xyzw=quaternion_xyzw_from_matrix(R)[0],
                     opening_width_m=opening_width_m, score=1.0, vertex_id=-1, kind="corner", frame_id=frame_id,
                     timestamp_s=timestamp_s)


def from_the_side(plan: GraspPlan, T_world_cam, side: float = 1.0, up_world=(0.0, 0.0, 1.0),
                  rise_m: float = 0.0, reach_m: float = 0.01) -> GraspPlan:
    """A lowest-point grasp (``lowest_point_grasp``) turned to approach horizontally.

    The gripper comes in level, along the cloth's plane at the tip (across the closing
    direction, which stays the tip's normal), so that its fingers straddle the hanging
    corner from the side: a hand coming up from below would have to pass under a cloth
    that hangs a few centimetres above the table. The fingertips close ``rise_m`` higher
    than the plan's and ``reach_m`` past it along the approach. The pads, level now, span
    the tip's height: closing higher holds more of the narrow corner but takes the cloth
    farther from its tip. On 4 held development scenes the material point held lay 2.1-5.4
    cm from a corner closing 1.5 cm higher, 0.8-4.1 cm closing level with the tip and
    0.7-3.6 cm from below; on 8 more, 1.2-5.0 cm level and 0.8-4.1 cm from below.

    plan : the lowest-point GraspPlan, camera frame (approach up, x closing)
    T_world_cam : (4, 4) float, camera frame to world; up_world : (3,) the world's up
    side : +1 or -1, which of the two horizontal directions the gripper comes from
        (+1: along up x closing, -1 the opposite)
    rise_m, reach_m : float >= 0, metres
    returns GraspPlan, camera frame, otherwise as ``plan``
    """
    if not isinstance(plan, GraspPlan):
        raise ValueError(f"plan: expected a GraspPlan, got {type(plan).__name__}")
    if side not in (1, -1):
        raise ValueError(f"side: expected +1 or -1, got {side!r}")
    T = check_transform("T_world_cam", T_world_cam)
    up_cam = T[:3, :3].T @ check_vector("up_world", up_world, unit=True)
    for name, value in (("rise_m", rise_m), ("reach_m", reach_m)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name}: expected a non-negative number, got {value!r}")
    closing = Rotation.from_quat(plan.quat_xyzw).as_matrix()[:, 0]
    closing = closing - (closing @ up_cam) * up_cam
    if np.linalg.norm(closing) < 1e-9:
        raise ValueError("from_the_side: the plan closes along the vertical; it has no side to come from")
    closing /= np.linalg.norm(closing)
    approach = float(side) * np.cross(up_cam, closing)
    R = frames_from_z_and_x(approach[None], closing[None])
    position = plan.position + rise_m * up_cam + reach_m * approach
    return dataclasses.replace(plan, position=position, approach=R[0][:, 2], quat_xyzw=quaternion_xyzw_from_matrix(R)[0])
