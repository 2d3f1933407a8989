"""Judging a trial's grasp by ground truth (pure NumPy).

Material coordinates throughout: ``uv`` points are metres on the flat cloth (u right,
v down from the top-left of its bounding box, ``sim.cloth_mesh``), so a distance is
measured along the cloth, whatever its pose when it was grasped.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from grasping import depth_agrees
from ipc.messages import GraspPlan, RGBDFrame
from perception.geometry import pixel_index, project
from sim.laundry.truth import distance_to_segments, nearest_corner, share_an_edge

log = logging.getLogger(__name__)

#: A true point counts as seen (``seen_by_camera``) when some measured depth within this
#: many pixels of its own pixel lies within ``SEEN_TOLERANCE_M`` of it: the sensor's noise
#: and a point on a cloth's very edge, where half the window is background.
SEEN_WINDOW_PX = 2
SEEN_TOLERANCE_M = 0.015

#: A grasp counts as a corner (boundary) grasp when its material point is at most this
#: far from a true corner (the true outline), metres.
TOLERANCE_M = 0.03


@dataclass(frozen=True)
class Judgement:
    """The verdict on one executed grasp.

    success : the grasp did what its kind asks (see ``judge``)
    corner_success : within the tolerance of a true corner and lifted clear, whatever the kind
    corner_error_m : material distance from the grasped point to the nearest true corner (inf: nothing held)
    nearest_corner : index of that corner, -1 when nothing was held
    boundary_error_m : material distance from the grasped point to the true outline (inf: nothing held)
    reason : "" on success, else one line saying why not
    """

    success: bool
    corner_success: bool
    corner_error_m: float
    nearest_corner: int
    boundary_error_m: float
    reason: str


def judge(kind: str, grasped_uv, lifted_clear: bool, corners_uv: np.ndarray, outline_uv: np.ndarray,
          tolerance_m: float = TOLERANCE_M) -> Judgement:
    """Judge a grasp against the true corners and outline of the cloth.

    kind : the grasp kind asked for (``GraspPlan.KINDS``): "corner" (success: the grasped
        point within ``tolerance_m`` of a true corner and the cloth lifted clear),
        "boundary" (within ``tolerance_m`` of the true outline and lifted clear) or
        "highest" (the baseline: success when the cloth is lifted clear; its corner
        distance is judged too, as ``corner_success``)
    grasped_uv : (2,) float metres, material point held; None when nothing was held
    lifted_clear : bool, no node of the cloth near the surface under it after the lift
    corners_uv : (C, 2) float metres, C >= 1; outline_uv : (E, 2, 2) float metres, the
        outline's segments (``LaundrySpec.outline_uv``)
    """
    if kind not in GraspPlan.KINDS:
        raise ValueError(f"Expected kind in {GraspPlan.KINDS}, got {kind!r}")
    if grasped_uv is None:
        return Judgement(False, False, math.inf, -1, math.inf, "missed: no cloth between the fingers")
    uv = np.asarray(grasped_uv, dtype=np.float64).reshape(2)
    k, corner_error = nearest_corner(uv, corners_uv)
    boundary_error = float(distance_to_segments(uv[None], outline_uv)[0])
    at_corner = corner_error <= tolerance_m
    at_boundary = boundary_error <= tolerance_m
    corner_success = at_corner and lifted_clear
    if kind == "corner":
        ok, miss = at_corner, f"grasped {100 * corner_error:.1f} cm from the nearest corner"
    elif kind == "boundary":
        ok, miss = at_boundary, f"grasped {100 * boundary_error:.1f} cm from the outline"
    else:
        ok, miss = True, ""
    reasons = [] if ok else [miss]
    if not lifted_clear:
        reasons.append("not lifted clear")
    return Judgement(success=not reasons, corner_success=corner_success, corner_error_m=corner_error,
                     nearest_corner=k, boundary_error_m=boundary_error, reason="; ".join(reasons))


#: An unfolded edge must be held stretched to at least this fraction of its material length.
MIN_STRETCH = 0.9


@dataclass(frozen=True)
class UnfoldJudgement:
    """The verdict on an unfolding: two grippers holding a cloth by two corners.

    success : both held points within the tolerance of true corners that share an edge
        (``sim.laundry.truth.CORNER_EDGES``), held apart by at least ``MIN_STRETCH`` of
        their material distance, and the cloth clear of the table
    first_corner, second_corner : index of the true corner nearest each held point (-1: nothing held)
    first_error_m, second_error_m : material distance from each held point to that corner (inf: nothing held)
    adjacent : the two nearest corners share an edge
    stretch : distance between the held points in space over their material distance (0: not both held)
    reason : "" on success, else one line saying why not
    """

    success: bool
    first_corner: int
    second_corner: int
    first_error_m: float
    second_error_m: float
    adjacent: bool
    stretch: float
    reason: str


def judge_unfold(cloth_kind: str, first_uv, second_uv, held_apart_m: float, lifted_clear: bool,
                 corners_uv: np.ndarray, tolerance_m: float = TOLERANCE_M) -> UnfoldJudgement:
    """Judge an unfolding by ground truth (material coordinates, metres).

    cloth_kind : "towel" or "tshirt" (which corner pairs share an edge)
    first_uv, second_uv : (2,) float metres, the material points the two grippers hold;
        None for a gripper that holds nothing
    held_apart_m : distance between those two points in space now, metres
    lifted_clear : no node of the cloth near the surface under it
    corners_uv : (C, 2) float metres, the true corners
    """
    if first_uv is None or second_uv is None:
        which = "first" if first_uv is None else "second"
        k1, e1 = nearest_corner(np.asarray(first_uv), corners_uv) if first_uv is not None else (-1, math.inf)
        k2, e2 = nearest_corner(np.asarray(second_uv), corners_uv) if second_uv is not None else (-1, math.inf)
        return UnfoldJudgement(False, k1, k2, e1, e2, False, 0.0, f"missed: the {which} gripper holds no cloth")
    a, b = np.asarray(first_uv, dtype=np.float64).reshape(2), np.asarray(second_uv, dtype=np.float64).reshape(2)
    k1, e1 = nearest_corner(a, corners_uv)
    k2, e2 = nearest_corner(b, corners_uv)
    adjacent = k1 != k2 and share_an_edge(cloth_kind, k1, k2)
    material = float(np.linalg.norm(a - b))
    stretch = float(held_apart_m) / material if material > 0 else 0.0
    reasons = []
    if e1 > tolerance_m:
        reasons.append(f"first grasp {100 * e1:.1f} cm from the nearest corner")
    if e2 > tolerance_m:
        reasons.append(f"second grasp {100 * e2:.1f} cm from the nearest corner")
    if not adjacent:
        reasons.append("the held corners do not share an edge" if k1 != k2 else "both grippers hold the same corner")
    if stretch < MIN_STRETCH:
        reasons.append(f"edge held at {100 * stretch:.0f} % of its length")
    if not lifted_clear:
        reasons.append("not clear of the table")
    return UnfoldJudgement(not reasons, k1, k2, e1, e2, adjacent, stretch, "; ".join(reasons))


def seen_by_camera(points_cam: np.ndarray, frame: RGBDFrame, tol_m: float = SEEN_TOLERANCE_M,
                   window_px: int = SEEN_WINDOW_PX) -> np.ndarray:
    """(K,) bool: which true points (K, 3), metres in ``frame``'s camera frame, the camera saw.

    Seen: inside the image, off the frame's known occluder (the robot's hands), and some
    measured depth around the pixel agrees with the point (``grasping.depth_agrees``); a
    point behind another layer of cloth, or behind a hand, has only nearer depth around it.
    Judges what the robot could have grasped in sight, e.g. whether a corner it declined to
    grasp blind was truly hidden.
    """
    points = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    uv = project(points, frame.camera.K, frame.camera.D)
    seen = depth_agrees(points, frame.depth_m, uv, tol_m, window_px)
    if frame.occluder_mask is not None:
        height, width = frame.depth_m.shape
        cols, rows, inside = pixel_index(uv, width, height)
        seen[inside] &= ~frame.occluder_mask[rows[inside], cols[inside]].astype(bool)
    return seen
