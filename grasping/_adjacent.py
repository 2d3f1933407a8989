"""The corners adjacent to a held material point: where a second grasp stretches an edge.

A robot unfolding a cloth holds it by one corner and must grasp next a corner that
shares an edge of the cloth with the held one. Which corners those are is a property of
the material, not of the hanging cloth's current shape: they are the corners next to the
held point along the outline of the canonical (rest) mesh. Where they are now is where
the tracked estimate has carried those material points.

Data form: a ``MeshEstimate`` (vertices (N, 3) float64 metres in the camera's OpenCV
optical frame; ``canonical`` (N, 3) float64 metres, the flat rest mesh; faces; boundary
ids; optional per-vertex ``visible`` flags), a held vertex id of the canonical mesh, and
optionally the ``RGBDFrame`` the estimate was made from. Output: ``AdjacentCorner``
messages (``ipc.messages``), each a corner ``GraspPlan`` placed exactly as the planner's
corner grasps are (``grasping._planner``), in the estimate's camera frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import dijkstra

from grasping._outline import Outline
from grasping._planner import (
    GraspPlannerConfig,
    _build_model,
    _CanonicalModel,
    _check_inputs,
    _clearance,
    _clearance_term,
    _grasp_plans,
    _inside_workspace,
    _outline_candidates,
)
from grasping._tip import measured_tip
from grasping._visibility import depth_agrees
from ipc.messages import AdjacentCorner, MeshEstimate, RGBDFrame
from perception.geometry import project

log = logging.getLogger(__name__)

#: A held vertex off the outline is taken to the outline vertex nearest to it along the
#: canonical mesh's edges; farther than this many grid spacings it holds no edge.
HELD_MAX_OFFSET_SPACINGS = 3.0
#: A corner within this fraction of the loop's chord half-length L (``Outline.loop_window_m``)
#: of the held point, along the outline, is the held corner itself. Two corners are at least
#: L apart, so at most one can be this near; with the default L of four spacings this is
#: two spacings, which covers a held vertex taken one row inside the corner.
HELD_CORNER_FRACTION = 0.5


@dataclass(frozen=True)
class AdjacentCornersResult:
    """The corners adjacent to a held point, on one estimate.

    candidates : tuple of ``ipc.messages.AdjacentCorner``, best first (score non-increasing;
        ties: the nearer along the outline first), at most one per side of the held point
    held_outline_vertex : int, the outline vertex of the canonical mesh taken as the held
        point (the held vertex itself when it lies on the outline); -1 when the mesh has no
        boundary
    reason : why ``candidates`` is empty, one line; "" when there are candidates
    """

    candidates: tuple = ()
    held_outline_vertex: int = -1
    reason: str = ""

    def __bool__(self) -> bool:
        return bool(self.candidates)


def _check_held_vertex(held_vertex, n_vertices: int) -> int:
    if isinstance(held_vertex, (bool, np.bool_)) or not isinstance(held_vertex, (int, np.integer)):
        raise ValueError(f"Expected held_vertex an integer vertex id, got {held_vertex!r}")
    if not 0 <= held_vertex < n_vertices:
        raise ValueError(f"Expected held_vertex in [0, {n_vertices}) (a vertex of the canonical mesh), got {held_vertex}")
    return int(held_vertex)


def _held_row(outline: Outline, model: _CanonicalModel, held_vertex: int) -> int:
    """The outline row of the held point: the held vertex's own row if it is on the outline,
    else the row nearest to it along the canonical mesh's edges.

    Raises ValueError when the nearest row is farther than ``HELD_MAX_OFFSET_SPACINGS``.
    """
    own = np.flatnonzero(outline.vertex_ids == held_vertex)
    if own.size:
        return int(own[0])  # a pinch vertex has two rows: either is on the outline
    limit_m = HELD_MAX_OFFSET_SPACINGS * outline.spacing_m
    distance = dijkstra(model.graph, directed=False, indices=held_vertex)[outline.vertex_ids]
    row = int(np.argmin(distance))  # ties: the first row in outline order, to be repeatable
    if not distance[row] <= limit_m:
        got = "not connected to it" if not np.isfinite(distance[row]) else f"{distance[row]:.3f} m away"
        raise ValueError(f"Expected held_vertex within {HELD_MAX_OFFSET_SPACINGS:g} grid spacings ({limit_m:.3f} m) "
                         f"of the canonical outline, got vertex {held_vertex}, {got}")
    return row


def _neighbour_rows(outline: Outline, held_row: int) -> tuple[list[tuple[int, int]], str]:
    """The nearest corner on each side of the held row along its loop, without the held corner.

    Returns ([(corner row, side), ...], reason): one entry per side, or one entry when
    both sides reach the same corner (the side it is nearer on); none, with a one-line
    reason, when the loop has no other corner.
    """
    loop = int(outline.loop_ids[held_row])
    perimeter = float(outline.perimeters_m[loop])
    corners = outline.corner_rows[outline.loop_ids[outline.corner_rows] == loop]
    if corners.size == 0:
        return [], "no corners on the outline of the held point"
    forward = np.mod(outline.arclength_m[corners] - outline.arclength_m[held_row], perimeter)
    backward = np.mod(perimeter - forward, perimeter)
    nearest = int(np.argmin(np.minimum(forward, backward)))
    if min(forward[nearest], backward[nearest]) <= HELD_CORNER_FRACTION * outline.loop_window_m(loop):
        keep = np.arange(len(corners)) != nearest
        corners, forward, backward = corners[keep], forward[keep], backward[keep]
    if corners.size == 0:
        return [], "no other corner on the outline of the held point"
    ahead, behind = int(np.argmin(forward)), int(np.argmin(backward))
    if ahead == behind:  # one other corner: both ways lead to it
        return [(int(corners[ahead]), 1 if forward[ahead] <= backward[behind] else -1)], ""
    return [(int(corners[ahead]), 1), (int(corners[behind]), -1)], ""


def _outline_length_m(outline: Outline, canonical: np.ndarray, start: int, end: int, side: int) -> float:
    """Length of the cloth's edge from outline row ``start`` to row ``end`` going ``side``
    (+1 forward, -1 backward along the outline), metres, on the canonical mesh (N, 3).

    The path runs from the start vertex through the outline averaged over two grid spacings
    on each side (``Outline.middle``) to the end vertex. The averaging evens out the hex grid's zigzag,
    whose own length exceeds a straight side's by up to 15 %; rows within the averaging
    width of either end are left out, so the corners at the ends are not rounded off.
    """
    rows = np.flatnonzero(outline.loop_ids == outline.loop_ids[start])  # one loop's rows are consecutive
    i, j, n = start - rows[0], end - rows[0], len(rows)
    steps = (j - i) % n if side > 0 else (i - j) % n
    path = rows[(i + side * np.arange(steps + 1)) % n]
    ends = canonical[outline.vertex_ids[path]]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ends, axis=0), axis=1))])
    width = outline.middle_half_width_m
    inner = path[(arc >= width) & (arc[-1] - arc >= width)]
    points = np.vstack([ends[:1], outline.middle[inner] @ canonical, ends[-1:]])
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def _seen_around(estimate: MeshEstimate, model: _CanonicalModel, vid: np.ndarray, config: GraspPlannerConfig,
                 frame: RGBDFrame | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Which material around each corner was seen: (near (K, N) bool, seen (N,) bool), or
    (near, None) when nothing is known (no per-vertex flags, no frame).

    Around a corner means the vertices within ``config.opening_width_m`` of it along the
    canonical mesh: the cloth the open fingers straddle. A vertex counts as seen when the
    estimate flags it visible (if it carries flags) and, with a frame, the measured depth
    around its pixel agrees with it (the planner's visibility test).
    """
    near = np.isfinite(dijkstra(model.graph, directed=False, indices=vid, limit=config.opening_width_m))
    if estimate.visible is None and frame is None:
        return near, None
    seen = np.ones(len(estimate.vertices), bool) if estimate.visible is None else estimate.visible.copy()
    if frame is not None:
        around = np.flatnonzero(near.any(axis=0))
        points = estimate.vertices[around]
        uv = project(points, frame.camera.K, frame.camera.D)
        seen[around] &= depth_agrees(points, frame.depth_m, uv, config.visibility_tol_m, config.visibility_window_px)
    return near, seen


def _at_measured_tips(estimate: MeshEstimate, vid: np.ndarray, positions: np.ndarray, inward: np.ndarray,
                      near: np.ndarray, seen: np.ndarray, config: GraspPlannerConfig,
                      frame: RGBDFrame) -> tuple[np.ndarray, np.ndarray]:
    """(placed (K, 3), offsets (K,)): the corner grasp positions moved to the tip of the
    measured surface where the frame shows one within ``config.tip_search_radius_m``
    (``grasping._tip.measured_tip``, seeded by the seen material around each corner),
    ``config.pinch_inset_m`` inside it as every corner grasp, and unchanged elsewhere; and
    the distance in metres from the estimate's corner vertex to that tip, NaN where there
    was none."""
    placed = positions.copy()
    offsets = np.full(len(vid), np.nan)
    for k, corner in enumerate(vid):
        seeds = estimate.vertices[near[k] & seen]
        tip = measured_tip(frame, estimate.vertices[corner], -inward[k], seeds, config.tip_search_radius_m,
                           config.tip_max_step_m)
        if tip is not None:
            offsets[k] = float(np.linalg.norm(tip - estimate.vertices[corner]))
            log.debug("adjacent corner %d placed at the measured tip, %.3f m from the estimate's", corner, offsets[k])
            placed[k] = tip + config.pinch_inset_m * inward[k]
    return placed, offsets


def _none(held_vertex: int, held_outline_vertex: int, reason: str) -> AdjacentCornersResult:
    log.debug("no corner adjacent to vertex %d: %s", held_vertex, reason)
    return AdjacentCornersResult(candidates=(), held_outline_vertex=held_outline_vertex, reason=reason)


def _adjacent_on_model(estimate: MeshEstimate, model: _CanonicalModel, config: GraspPlannerConfig,
                       frame: RGBDFrame | None, held_vertex, max_candidates,
                       even_if_lost: bool = False) -> AdjacentCornersResult:
    held_vertex = _check_held_vertex(held_vertex, len(estimate.canonical))
    if isinstance(max_candidates, (bool, np.bool_)) or not isinstance(max_candidates, (int, np.integer)) \
            or max_candidates < 1:
        raise ValueError(f"Expected max_candidates an integer >= 1, got {max_candidates!r}")
    outline = model.outline
    if outline is None:
        return _none(held_vertex, -1, "estimate has no boundary vertices")
    row = _held_row(outline, model, held_vertex)
    held_outline_vertex = int(outline.vertex_ids[row])
    if estimate.lost and not even_if_lost:
        return _none(held_vertex, held_outline_vertex, f"estimate lost (seq {estimate.seq})")
    if estimate.confidence < config.min_confidence and not even_if_lost:
        return _none(held_vertex, held_outline_vertex, f"estimate confidence {estimate.confidence:.3g} below "
                                                       f"min_confidence {config.min_confidence:.3g}")
    neighbours, reason = _neighbour_rows(outline, row)
    if not neighbours:
        return _none(held_vertex, held_outline_vertex, reason)

    rows = np.array([r for r, _ in neighbours], np.int64)
    sides = np.array([side for _, side in neighbours], np.int64)
    distance_m = np.array([_outline_length_m(outline, estimate.canonical, row, r, side) for r, side in neighbours])
    found = _outline_candidates(estimate, outline, rows, outline.interior_angle_rad[rows], config)
    if not np.all(found.valid):
        log.info("adjacent corner(s) at vertex %s dropped: degenerate geometry on estimate %d",
                 found.vertex_ids[~found.valid].tolist(), estimate.seq)
        if not np.any(found.valid):
            return _none(held_vertex, held_outline_vertex, f"the adjacent corner(s) at vertex "
                                                           f"{found.vertex_ids.tolist()} have degenerate geometry")
    keep = found.valid
    vid, positions = found.vertex_ids[keep], found.positions[keep]
    approach, closing = found.approach[keep], found.closing[keep]
    sides, distance_m = sides[keep], distance_m[keep]

    near, seen = _seen_around(estimate, model, vid, config, frame)
    visibility_known = seen is not None
    visible = np.array([seen[around].mean() for around in near]) if visibility_known else np.ones(len(vid))
    tip_offsets = np.full(len(vid), np.nan)
    if frame is not None and config.tip_search_radius_m > 0:
        positions, tip_offsets = _at_measured_tips(estimate, vid, positions, found.inward[keep], near, seen, config,
                                                   frame)
    reachable = _inside_workspace(positions, config)
    clearance = _clearance_term(_clearance(estimate, model.graph, vid, config), config)
    score = config.weight_clearance * clearance + config.weight_confidence * float(estimate.confidence)
    total_weight = config.weight_clearance + config.weight_confidence
    if visibility_known:
        score = score + config.weight_visibility * visible
        total_weight += config.weight_visibility
    score = np.where(reachable, score / total_weight, 0.0)

    order = np.lexsort((-sides, distance_m, -score))[:max_candidates]
    plans = _grasp_plans(estimate, vid[order], positions[order], approach[order], closing[order], score[order],
                         "corner", config)
    candidates = tuple(
        AdjacentCorner(plan=plan, side=int(sides[k]), material_distance_m=float(distance_m[k]),
                       visible=float(visible[k]), reachable=bool(reachable[k]),
                       tip_offset_m=None if np.isnan(tip_offsets[k]) else float(tip_offsets[k]))
        for plan, k in zip(plans, order)
    )
    log.debug("held vertex %d (outline vertex %d): adjacent corners %s", held_vertex, held_outline_vertex,
              ", ".join(f"{c.plan.vertex_id} (side {c.side:+d}, {c.material_distance_m:.3f} m, score "
                        f"{c.plan.score:.3f})" for c in candidates))
    return AdjacentCornersResult(candidates=candidates, held_outline_vertex=held_outline_vertex, reason="")


def adjacent_corners(estimate: MeshEstimate, held_vertex: int, config: GraspPlannerConfig | None = None,
                     frame: RGBDFrame | None = None, max_candidates: int = 2,
                     even_if_lost: bool = False) -> AdjacentCornersResult:
    """The outline corners next to a held material point, placed on the current estimate.

    The held point is ``held_vertex``'s row of the canonical outline, or, for a vertex off
    the outline, the outline vertex nearest to it along the canonical mesh's edges (at most
    ``HELD_MAX_OFFSET_SPACINGS`` grid spacings away). From there the outline loop is walked
    both ways to the nearest corner (``find_corners``) on each side, passing over the held
    corner itself (a corner within ``HELD_CORNER_FRACTION`` of the loop's chord half-length
    of the held point). Which corners these are depends on the canonical mesh only; each is
    then placed on the estimate exactly as ``plan_grasps`` places a corner grasp (position
    ``pinch_inset_m`` inside the outline, approach and closing by ``edge_approach``); with
    a frame and ``config.tip_search_radius_m`` > 0, at the tip of the measured surface
    beyond it where the frame shows one within that radius (``grasping._tip``).

    Each candidate is scored by the weighted mean (``config``'s weights) of its clearance
    from other layers, the estimate's confidence and, when anything is known of it, its
    visibility; a corner outside the workspace scores 0 but is still returned, with
    ``reachable`` False. The single-layer term of corner grasps (a cloth lying on a surface)
    is left out, and ``min_score`` drops nothing: the caller chooses.

    Parameters
    ----------
    estimate : MeshEstimate; vertices (N, 3) float64 metres, camera frame; canonical (N, 3)
        float64 metres, the flat rest mesh; ``visible`` (N,) bool or None
    held_vertex : int in [0, N), the canonical mesh's vertex held (``GraspPlan.vertex_id``
        of the executed grasp)
    config : GraspPlannerConfig, default settings when None (``kind`` is ignored)
    frame : RGBDFrame the estimate came from, or None; its ``depth_m`` (H, W) float32
        metres and ``camera`` give the depth-visibility test
    max_candidates : int >= 1, most candidates returned (there are at most two)
    even_if_lost : bool, also plan on an estimate flagged lost or below ``min_confidence``:
        for a caller that checks each corner against the measured surface itself
        (``tip_offset_m``), since the estimate may be wrong elsewhere and right there

    Returns
    -------
    AdjacentCornersResult; each candidate's ``plan`` is a GraspPlan of kind "corner" in
    ``estimate.frame_id`` (``vertex_id`` the canonical corner vertex, ``position`` (3,)
    metres, unit ``approach``, ``quat_xyzw`` of ``R_cam_gripper`` as for every plan,
    ``score`` in [0, 1]), with ``side`` (+1 forward along the outline's order, -1 backward),
    ``material_distance_m`` (arc length of the canonical outline from the held point,
    metres), ``visible`` in [0, 1] (``_seen_around``: 1 when no flags and no frame),
    ``reachable`` and ``tip_offset_m`` (metres from the estimate's corner vertex to the
    measured tip the position was moved to; None when it was not moved). Empty with a
    one-line ``reason`` when the mesh has no boundary, the estimate is lost or below
    ``min_confidence`` (unless ``even_if_lost``), or the held point's outline loop has no
    other corner.

    Raises
    ------
    ValueError : ``held_vertex`` not a vertex of the canonical mesh or farther than
        ``HELD_MAX_OFFSET_SPACINGS`` from its outline, bad ``max_candidates``, ``estimate``
        not a MeshEstimate or without faces, ``frame`` not an RGBDFrame or in another camera
        frame, or a malformed canonical mesh
    """
    config = GraspPlannerConfig() if config is None else config
    _check_inputs(estimate, frame)
    return _adjacent_on_model(estimate, _build_model(estimate, config, with_outline=True), config, frame, held_vertex,
                              max_candidates, even_if_lost)
