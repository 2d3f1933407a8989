"""The trial robot's controller policy: which grasp it executes, given the planner's reply and what it sees.

A policy is a callable ``(reply, scene, view) -> GraspPlan | None``: the planner's
``GraspPlanReply``, the ``LaundryScene`` (for what a robot knows of its own workspace: the
holder it controls, its camera pose) and a ``View`` of the last frame. Pure apart from the
extra looks ``lowest_point_when_held`` renders through ``scene.render_turned``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from grasping import corner_angles, lowest_point_grasp
from ipc.messages import AdjacentCorner, GraspPlan, GraspPlanReply
from perception.geometry import invert_transform, transform_points
from sim.laundry.segment import cloth_points, mask_from_reference

#: Turns of a held cloth, after the first look, before its lowest point is chosen: every
#: 30 degrees of a full turn. Measured on 32 held scenes (even seeds 0-62, state forced,
#: integrated at 1/240 s; the cloth vertex nearest the chosen point against the true
#: corners, material distance): 4 looks left it 4-9 cm from every corner in 5 scenes and
#: on a corner's vertex in 13; 8 looks at most 3.1 cm, on a corner's vertex in 18; 12
#: looks at most 3.1 cm, on a corner's vertex in 25; 16 looks no better.
TURNS_RAD = tuple(np.radians(np.arange(30.0, 360.0, 30.0)))


@dataclass(frozen=True)
class View:
    """What the controller sees when it chooses a plan.

    frame : RGBDFrame, the last frame shown to the perception service (the plan's)
    reference : RGBDFrame, the robot's picture of its empty workspace (same camera)
    cloth_mask : (H, W) bool, the cloth in ``frame``, found against ``reference``
    """

    frame: object
    reference: object
    cloth_mask: np.ndarray


def best_candidate(reply: GraspPlanReply, scene, view: View) -> GraspPlan | None:
    """The planner's best candidate (None when it has none)."""
    return reply.candidates[0] if reply.candidates else None


def lowest_point_when_held(reply: GraspPlanReply, scene, view: View) -> GraspPlan | None:
    """The controller's choice (default): the planner's best, but the lowest point of the
    cloth when the robot holds it up (``grasping.lowest_point_grasp``).

    A cloth hanging from one point has a corner at its lowest point (the opposite corner
    of a towel; a hem corner or sleeve end of a shirt); a robot that holds the cloth knows
    it does. The lowest point is taken from the cloth's measured points, not from the
    mesh: the mesh, laid over the first frame, covers a hanging cloth unevenly and often
    stops short of its tip. From one view the tip is often hidden, behind a nearer layer
    or seen edge-on where the sensor loses depth, so the robot turns the held cloth a
    twelfth of a turn at a time and looks again (``TURNS_RAD``, ``scene.render_turned``),
    pooling the points of the last frame and of the turned views in the world frame
    (``scene.T_world_cam``, z up).
    """
    if getattr(scene, "holder", None) is None:
        return best_candidate(reply, scene, view)
    world = [scene.to_world(cloth_points(view.frame, view.cloth_mask, view.reference))]
    for angle in TURNS_RAD:
        frame, reference, T_world_turned = scene.render_turned(angle)
        points = cloth_points(frame, mask_from_reference(frame, reference), reference)
        world.append(transform_points(T_world_turned, points))
    # back to the camera the plan is given in
    points_cam = transform_points(invert_transform(scene.T_world_cam), np.concatenate(world))
    if len(points_cam) < 3:
        return best_candidate(reply, scene, view)
    return lowest_point_grasp(points_cam, scene.T_world_cam, frame_id=view.frame.camera.frame_id,
                              timestamp_s=view.frame.timestamp_s)


#: An edge a robot can stretch straight: the straight line between its two corners on the
#: canonical mesh is at least this fraction of the outline's length between them. Measured
#: on the trials' meshes (seeds 0, 4, 6, 10, 12): a towel's sides 0.98-1.00, a T-shirt's
#: straight edges (hem, cuffs, shoulders) 0.97-1.00; the path from a hem corner up the side
#: seam, past the armpit, to a cuff, and the neckline 0.78-0.88.
MIN_EDGE_STRAIGHTNESS = 0.95


def edge_straightness(corner: AdjacentCorner, canonical: np.ndarray, held_vertex: int) -> float:
    """Straight-line distance over outline length between a held point and an adjacent
    corner, on the canonical mesh (N, 3) metres: 1 for a straight edge, less for an outline
    that turns on the way (past a shirt's armpit, round a curve)."""
    chord = float(np.linalg.norm(canonical[corner.plan.vertex_id] - canonical[held_vertex]))
    return chord / corner.material_distance_m if corner.material_distance_m > 0 else 0.0


#: The least part of the material around a corner that the camera must have seen
#: (``AdjacentCorner.visible``) for the robot to send a gripper there, unless the measured
#: surface confirms the corner closely (``closely_confirmed``). Below it, seen alone, nothing in
#: the frame confirms the estimate's corner: on three runs of 50 held-out unfold trials, 51 of the
#: 105 second grasps went to a corner seen less than this, one of them succeeded, and 39 of
#: the 41 second grippers that closed on nothing had been sent to such a corner.
MIN_CORNER_VISIBLE = 0.25
#: A corner seen less than ``MIN_CORNER_VISIBLE`` is still taken where the measured surface
#: ends within this distance of the estimate's corner (``AdjacentCorner.tip_offset_m``), its tip
#: found from the part of it that was seen. The distance is the 3 cm by which a grasp may miss
#: a corner and still hold it (the trials' judge, ``sim.laundry.judge.TOLERANCE_M``, counts the
#: same), not a figure fitted to the data below, where 2.5 cm did as well;
#: and a corner so closely confirmed comes before one confirmed only within
#: ``MAX_TIP_OFFSET_M``. Measured on the last hanging frames of 48 development trials (even
#: seeds 0-98 whose first grasp held a corner; the planner replayed on each trial's frame and
#: estimate, development script outside the repository): of the corners taken, 18 lay within
#: 3 cm of a true corner sharing an edge with the held one and 10 did not (20 declined);
#: with this rule 23 and 9 (16 declined). Limits of 2.5 and 3.5 cm gave 23 and 8, 23 and 9.
#: The trials themselves: 17/50 -> 22/50 on those seeds, 26/50 -> 26/50 on 50 held-out ones.
CLOSE_TIP_M = 0.03


#: How far from the estimate's corner the measured surface may end for the frame to confirm
#: the corner (``AdjacentCorner.tip_offset_m``, the planner searching 10 cm round it): twice
#: the 3 cm by which a grasp may miss a corner. Measured on the last hanging frame of 40
#: recorded lifts (unfold seeds 941-1019, the unfold trials' tracker, a development script
#: planning on each estimate whether flagged lost or not): of the 21 corners whose tip lay
#: within 6 cm, and not beyond ``MAX_REACH_OVER_MATERIAL``, 17 were planned within 3 cm of a
#: true corner sharing an edge with the held one; of the 19 others, 3 (tips 8.8 and 9.8 cm
#: away, and one without a tip). Any limit from 5 to 7 cm gave the same split.
MAX_TIP_OFFSET_M = 0.06
#: A cloth does not stretch: the corner next to the held one hangs no farther from the
#: gripper than the edge between them is long (``AdjacentCorner.material_distance_m``,
#: measured between outline vertices, so up to a grid spacing short at each end), with 20 %
#: to spare for that and for the cloth's own give.
MAX_REACH_OVER_MATERIAL = 1.2


def closely_confirmed(corner: AdjacentCorner) -> bool:
    """Whether some of the material around ``corner`` was seen and the measured surface
    ends within ``CLOSE_TIP_M`` of the estimate's corner."""
    return corner.visible > 0 and corner.tip_offset_m is not None and corner.tip_offset_m <= CLOSE_TIP_M


def why_not_seen(corner: AdjacentCorner) -> str:
    """Why the camera did not see enough of ``corner`` to send a gripper there, one line; ""
    when it did: at least ``MIN_CORNER_VISIBLE`` of the material around it, or less but
    ``closely_confirmed``."""
    if corner.visible >= MIN_CORNER_VISIBLE or closely_confirmed(corner):
        return ""
    if corner.visible == 0:
        return "nothing around it seen"
    if corner.tip_offset_m is None:
        return f"visibility {corner.visible:.2f} < {MIN_CORNER_VISIBLE:g}, no measured tip"
    return (f"visibility {corner.visible:.2f} < {MIN_CORNER_VISIBLE:g}, its measured tip "
            f"{100 * corner.tip_offset_m:.1f} cm away, over {100 * CLOSE_TIP_M:g} cm")


def seen_enough(corner: AdjacentCorner) -> bool:
    """Whether the camera saw enough of ``corner`` to send a gripper there (``why_not_seen``)."""
    return not why_not_seen(corner)


def why_not_confirmed(corner: AdjacentCorner, held_point_cam: np.ndarray) -> str:
    """Why the frame does not confirm ``corner`` as the planner placed it, one line; "" when
    it does: the measured surface ends within ``MAX_TIP_OFFSET_M`` of the estimate's corner
    (``tip_offset_m``), and the grasp lies within ``MAX_REACH_OVER_MATERIAL`` times the
    edge's rest length of the held point ``held_point_cam`` (3,) metres, in the plan's
    camera frame. Asked of every corner, since a tracked estimate can be wrong at the
    corner while confident overall, and right there while flagged lost."""
    if corner.tip_offset_m is None:
        return "no measured tip (no tip search, no frame, or no tip within the search)"
    if corner.tip_offset_m > MAX_TIP_OFFSET_M:
        return f"the measured tip lies {100 * corner.tip_offset_m:.1f} cm from the estimate's corner"
    reach = float(np.linalg.norm(np.asarray(corner.plan.position) - np.asarray(held_point_cam, np.float64)))
    if reach > MAX_REACH_OVER_MATERIAL * corner.material_distance_m:
        return (f"{100 * reach:.0f} cm from the held corner, along an edge {100 * corner.material_distance_m:.0f} cm "
                f"long")
    return ""


#: An adjacent outline corner blunter than this (interior angle, degrees) at the end of an edge
#: long enough for the angle to be its own (``why_not_a_corner``) is where two edges meet, not
#: a corner an edge of the cloth ends at: a T-shirt's neck corner, at the end of the straight
#: run of its sleeve's top and its shoulder. On the latest unfold trial of each of 300 seeds
#: run in the twentieth session and the three before (development and held-out), none of the
#: 21 second grasps at such a corner (121-135 degrees, edges 19-27 cm) held a corner sharing an
#: edge with the held one; of those at 112-120 degrees on long edges (a towel's side, a
#: shirt's hem) 4 of 7 did, and of those above 120 degrees on edges too short for the angle to
#: be their own (8-11 cm, a shirt's cuff) 5 of 8.
BLUNT_CORNER_MIN_ANGLE_DEG = 120.0


def why_not_a_corner(corner: AdjacentCorner, angles_deg: dict, window_m: float) -> str:
    """Why the outline corner ``corner`` is no corner of the cloth, one line; "" when it may
    be one. It is not when its interior angle (``angles_deg``, ``corner_angles_deg``) is
    blunter than ``BLUNT_CORNER_MIN_ANGLE_DEG`` and the edge from the held point to it is at
    least twice ``window_m`` long (the chords' half-length, ``corner_angles_deg``): then the
    chords that measured the angle lie on that edge and the angle is its own. On a shorter
    edge they reach past the corner at its other end and read a square corner blunt (a
    T-shirt's cuff, 8-11 cm: its corners measure 88-130 degrees on the 1.5 cm meshes of the
    unfold trials)."""
    angle = angles_deg.get(int(corner.plan.vertex_id))
    if angle is None or angle <= BLUNT_CORNER_MIN_ANGLE_DEG or corner.material_distance_m < 2.0 * window_m:
        return ""
    return (f"the outline turns by only {180.0 - angle:.0f} degrees there, at the end of an edge "
            f"{100 * corner.material_distance_m:.0f} cm long: where two edges meet, not a corner")


def corner_angles_deg(estimate) -> tuple[dict[int, float], float]:
    """{vertex id: interior angle in degrees} of the corners of ``estimate``'s canonical
    outline, and the half-length in metres of the chords that measured them
    (``grasping.corner_angles``)."""
    ids, angles, window_m = corner_angles(estimate.canonical, estimate.faces, estimate.boundary)
    return dict(zip(ids.tolist(), np.degrees(angles).tolist())), window_m


def stretchable_corner(candidates, canonical: np.ndarray, held_vertex: int,
                       held_point_cam: np.ndarray | None = None,
                       angles_deg: dict | None = None, window_m: float | None = None) -> AdjacentCorner | None:
    """The adjacent corner to grasp second, of the planner's ``AdjacentCorner`` candidates
    (best first): a reachable one first, among those one joined to the held point by a
    straight edge (``MIN_EDGE_STRAIGHTNESS``), which pulling the two corners apart stretches
    (a T-shirt's hem, not the side seam that bends under the sleeve), among those, given the
    canonical outline's corner angles (``angles_deg``, ``corner_angles_deg``), one that may be a
    corner of the cloth (``why_not_a_corner``, with the chords' ``window_m``), among those a
    sharp one (``SURE_CORNER_MAX_ANGLE_DEG``: a cuff's other corner, not the blunt corner where a
    shirt's shoulder meets its neckline, which no edge of the shirt ends at), among those one
    the camera saw enough of (``seen_enough``) and, given where the held point is
    (``held_point_cam`` (3,), metres, the plans' camera frame), among those one the frame
    confirms (``why_not_confirmed``), among those one it confirms closely
    (``closely_confirmed``); the planner's order decides among equals. None when there are
    no candidates. The caller still checks what it got: the best may be unseen or
    unconfirmed.
    """
    if not candidates:
        return None
    return min(candidates, key=lambda c: (not c.reachable,
                                          edge_straightness(c, canonical, held_vertex) < MIN_EDGE_STRAIGHTNESS,
                                          angles_deg is not None and window_m is not None
                                          and bool(why_not_a_corner(c, angles_deg, window_m)),
                                          angles_deg is not None
                                          and angles_deg.get(int(c.plan.vertex_id), 180.0) > SURE_CORNER_MAX_ANGLE_DEG,
                                          not seen_enough(c),
                                          held_point_cam is not None and bool(why_not_confirmed(c, held_point_cam)),
                                          held_point_cam is not None and not closely_confirmed(c)))


#: Corner plans scoring within this of the planner's best are equally good grasps (a cloth
#: lying flat and in view scores 1 at every corner).
NEAR_BEST_SCORE = 0.05

#: Largest interior angle, degrees, of a canonical outline corner a cloth on the table is
#: lifted by first (``corner_to_lift_first``), and of one the second gripper takes before a
#: blunter one (``stretchable_corner``). On the first plans of 19 development trials
#: (even seeds 0-70: 7 towels and 12 T-shirts, flat, crumpled and folded) the outline corners
#: within 3 cm of a true corner measured 82-111 degrees on a towel and 84-132 on a shirt;
#: those 8-28 cm from every true corner that scored within ``NEAR_BEST_SCORE`` of the best
#: (a shirt's shoulders and neck, the corners a fold makes) 113-132.
SURE_CORNER_MAX_ANGLE_DEG = 112.0


def corner_to_lift_first(candidates, estimate, T_world_cam: np.ndarray) -> GraspPlan | None:
    """The corner plan a cloth on the table is lifted by first: among the planner's corner
    plans (``candidates``, best first, made on ``estimate``) that score within
    ``NEAR_BEST_SCORE`` of the best and are sharp (``SURE_CORNER_MAX_ANGLE_DEG``), the one
    the cloth lies beyond, seen from the camera: its horizontal direction from the camera
    and from it to the cloth's centre agree best. Lifted by that corner, a cloth hangs with
    its face to the camera, and the corners next to the held one in sight. Measured on 12
    flat development towels lifted by each corner (48 lifts, no tracking): with the angle
    between those directions under 45 degrees both adjacent corners hung in the camera's
    sight in 10 of 11 lifts, and one of them in the 11th; beyond 135 degrees in none of 11.
    The planner's best when no plan qualifies; None when there are no candidates.
    """
    if not candidates:
        return None
    angle_deg, _ = corner_angles_deg(estimate)
    best = candidates[0].score
    sure = [c for c in candidates if c.score >= best - NEAR_BEST_SCORE
            and angle_deg.get(int(c.vertex_id), 180.0) <= SURE_CORNER_MAX_ANGLE_DEG]
    if not sure:
        return candidates[0]
    camera = T_world_cam[:3, 3]
    centre = transform_points(T_world_cam, estimate.vertices).mean(axis=0)

    def agreement(plan: GraspPlan) -> float:
        corner = transform_points(T_world_cam, np.asarray(plan.position, np.float64)[None])[0]
        out, beyond = (corner - camera)[:2], (centre - corner)[:2]
        size = np.linalg.norm(out) * np.linalg.norm(beyond)
        return float(out @ beyond / size) if size > 0 else -1.0

    return max(sure, key=agreement)  # the first of equals: the planner's order


def default_controller(kind: str) -> Callable[[GraspPlanReply, object, View], GraspPlan | None]:
    """The controller's choice for a grasp kind: ``lowest_point_when_held`` for corner and
    boundary grasps, ``best_candidate`` for the highest-point baseline, which takes the
    planner's highest point whatever the cloth's state."""
    return best_candidate if kind == "highest" else lowest_point_when_held
