"""Grasp selection on a tracked cloth mesh: candidates, scores, gripper poses.

Data form: a ``MeshEstimate`` (vertices (N, 3) float64 metres in the camera's
OpenCV optical frame, faces, boundary ids, the flat canonical mesh) and
optionally the ``RGBDFrame`` it was estimated from. Output: ``GraspPlan``
messages in the estimate's frame, best first.

Gripper convention (every plan): ``approach`` is the gripper's z axis, the way
it moves to reach ``position``; the fingers close along the gripper's x axis;
y = z x x. ``quat_xyzw`` is the rotation ``R_cam_gripper`` whose columns are
these axes in the camera frame, scalar last, with w >= 0.
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from grasping._layers import step_above_beyond
from grasping._outline import (
    DEFAULT_CORNER_MAX_ANGLE_RAD,
    DEFAULT_WINDOW_SPACINGS,
    Outline,
    build_outline,
)
from grasping._visibility import depth_agrees
from ipc.messages import GraspPlan, MeshEstimate, RGBDFrame
from perception.geometry import (
    check_positive,
    check_transform,
    check_vector,
    edge_length_graph,
    frames_from_z_and_x,
    project,
    quaternion_xyzw_from_matrix,
    transform_points,
    vertex_normals,
)

log = logging.getLogger(__name__)

EDGE_APPROACHES = ("pinch", "normal")


@dataclass(frozen=True, eq=False)
class GraspPlannerConfig:
    """Settings of the grasp planner. Lengths in metres, angles in radians.

    Frames: "world" is the frame of ``T_world_cam``, or the camera frame itself
    when none is given; the workspace box and the up direction are given in it.
    After construction every field holds its resolved value (arrays, not None).

    Attributes
    ----------
    kind : the grasp kind planned, one of ``GraspPlan.KINDS``: "corner" (corners of
        the canonical outline followed through the estimate), "boundary" (points
        evenly spaced along the outline) or "highest" (the highest reachable vertex
        along ``up_world``)
    edge_approach : for corner and boundary grasps, "pinch" (approach in the
        cloth's tangent plane, perpendicular to the outline, from outside the cloth;
        fingers close across the cloth's thickness) or "normal" (approach against
        the camera-facing surface normal; fingers close across the edge). Highest
        grasps always approach along the normal.
    T_world_cam : (4, 4) float64, rigid transform taking camera-frame points to
        the world frame, ``p_world = T_world_cam @ [p_cam, 1]``; None (default)
        for identity, i.e. world = camera frame
    up_world : (3,) float64, direction of "up" in the world frame (normalised);
        None (default) for (0, 0, 1), z up as in PyBullet, when ``T_world_cam``
        is given, and (0, -1, 0), image up, when it is not
    workspace_min_world, workspace_max_world : (3,) float64, metres, corners of
        the reachable axis-aligned box in the world frame; default unbounded
    visibility_tol_m : float > 0, largest depth disagreement at a vertex's pixel
        for it to count as visible
    visibility_window_px : int >= 0, half-size of the pixel window searched
    clearance_radius_m : float > 0, radius around the grasped vertex that should
        hold no other layer of cloth
    neighbour_geodesic_factor : float >= 1, vertices within this many clearance
        radii of the grasped vertex along the canonical mesh are the same layer
        (the cloth stretches little, so nearby material points stay within the
        radius; the factor leaves room for the tracker compressing the mesh)
    layer_thickness_m : float > 0, thickness of one layer of the cloth as the depth
        sensor sees it: a corner or boundary point whose cloth stands more than one
        such layer above the surface just beyond the outline lies on more than one
        layer, as at a fold's end (``GraspTerms.single_layer``)
    max_support_gap_m : float > 0, a point standing higher than this above the surface
        beyond it does not rest on that surface (it overhangs an edge, or the cloth
        hangs), and its layers are not judged
    weight_visibility, weight_clearance, weight_confidence, weight_single_layer :
        float >= 0, weights of the score terms; visibility and single_layer count only
        when a frame is given (single_layer in corner and boundary kinds), and
        ``weight_clearance + weight_confidence`` must be > 0
    min_score : float in [0, 1], plans scoring lower are dropped
    min_confidence : float in [0, 1], estimates less confident give no plans
    opening_width_m : float > 0, finger opening before closing
    pinch_inset_m : float >= 0, corner and boundary grasps close this far inside
        the outline (along the inward direction) so that the fingertips overlap
        the cloth rather than its very edge
    boundary_spacing_m : float > 0, distance between boundary grasp candidates
        along the canonical outline
    corner_max_angle_rad : float in (0, pi), largest interior angle of a corner
    outline_window_spacings : float > 0, half-length, in grid spacings, of the
        chords that measure the outline's turn and direction
    tip_search_radius_m : float >= 0, adjacent corners only, with a frame: a corner is
        placed at the tip of the measured surface that continues the estimate's corner
        outward, when one lies within this distance of it (``grasping._tip``); 0 (the
        default) places it on the estimate alone
    tip_max_step_m : float > 0, the largest depth step between neighbouring pixels of
        one measured surface in that search
    """

    kind: str = "corner"
    edge_approach: str = "pinch"
    T_world_cam: np.ndarray | None = None
    up_world: np.ndarray | None = None
    workspace_min_world: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    workspace_max_world: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    visibility_tol_m: float = 0.01
    visibility_window_px: int = 1
    clearance_radius_m: float = 0.05
    neighbour_geodesic_factor: float = 2.0
    weight_visibility: float = 1.0
    weight_clearance: float = 1.0
    weight_confidence: float = 1.0
    weight_single_layer: float = 1.0
    layer_thickness_m: float = 0.008
    max_support_gap_m: float = 0.05
    min_score: float = 0.0
    min_confidence: float = 0.0
    opening_width_m: float = 0.04
    pinch_inset_m: float = 0.01
    boundary_spacing_m: float = 0.05
    corner_max_angle_rad: float = DEFAULT_CORNER_MAX_ANGLE_RAD
    outline_window_spacings: float = DEFAULT_WINDOW_SPACINGS
    tip_search_radius_m: float = 0.0
    tip_max_step_m: float = 0.02

    def __post_init__(self):
        if self.kind not in GraspPlan.KINDS:
            raise ValueError(f"Expected kind in {GraspPlan.KINDS}, got {self.kind!r}")
        if self.edge_approach not in EDGE_APPROACHES:
            raise ValueError(f"Expected edge_approach in {EDGE_APPROACHES}, got {self.edge_approach!r}")
        set_ = object.__setattr__
        if self.up_world is None:
            set_(self, "up_world", np.array([0.0, -1.0, 0.0] if self.T_world_cam is None else [0.0, 0.0, 1.0]))
        if self.T_world_cam is None:
            set_(self, "T_world_cam", np.eye(4))
        set_(self, "T_world_cam", check_transform("T_world_cam", self.T_world_cam))
        set_(self, "up_world", check_vector("up_world", self.up_world, unit=True))
        lower = np.asarray(self.workspace_min_world, dtype=np.float64)
        upper = np.asarray(self.workspace_max_world, dtype=np.float64)
        if lower.shape != (3,) or upper.shape != (3,):
            raise ValueError(f"Expected workspace_min_world and workspace_max_world with shape (3,), "
                             f"got {lower.shape} and {upper.shape}")
        if np.any(np.isnan(lower)) or np.any(np.isnan(upper)) or np.any(lower > upper):
            raise ValueError(f"Expected workspace_min_world <= workspace_max_world, got {lower.tolist()} and {upper.tolist()}")
        set_(self, "workspace_min_world", lower)
        set_(self, "workspace_max_world", upper)
        for name in ("visibility_tol_m", "clearance_radius_m", "opening_width_m", "boundary_spacing_m", "outline_window_spacings",
                     "layer_thickness_m", "max_support_gap_m", "tip_max_step_m"):
            set_(self, name, check_positive(name, getattr(self, name)))
        for name in ("weight_visibility", "weight_clearance", "weight_confidence", "weight_single_layer", "pinch_inset_m",
                     "tip_search_radius_m"):
            set_(self, name, check_positive(name, getattr(self, name), allow_zero=True))
        if self.weight_clearance + self.weight_confidence <= 0:
            raise ValueError("Expected weight_clearance + weight_confidence > 0, got 0 "
                             "(the score would be undefined without a frame)")
        if float(self.neighbour_geodesic_factor) < 1:
            raise ValueError(f"Expected neighbour_geodesic_factor >= 1, got {self.neighbour_geodesic_factor}")
        set_(self, "neighbour_geodesic_factor", float(self.neighbour_geodesic_factor))
        if int(self.visibility_window_px) != self.visibility_window_px or self.visibility_window_px < 0:
            raise ValueError(f"Expected visibility_window_px an integer >= 0, got {self.visibility_window_px}")
        set_(self, "visibility_window_px", int(self.visibility_window_px))
        for name in ("min_score", "min_confidence"):
            value = float(getattr(self, name))
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"Expected {name} in [0, 1], got {value}")
            set_(self, name, value)
        if not 0.0 < float(self.corner_max_angle_rad) < math.pi:
            raise ValueError(f"Expected corner_max_angle_rad in (0, pi), got {self.corner_max_angle_rad}")
        set_(self, "corner_max_angle_rad", float(self.corner_max_angle_rad))

    @property
    def up_cam(self) -> np.ndarray:
        """(3,) float64 unit vector: ``up_world`` expressed in the camera frame."""
        return self.T_world_cam[:3, :3].T @ self.up_world


@dataclass(frozen=True)
class GraspTerms:
    """The score terms of one plan, each in [0, 1] (higher is better).

    visibility : 1 if the measured depth around the vertex's pixel agrees with
        the vertex (within ``visibility_tol_m``); 0 if it disagrees (something is
        in front, or the mesh is off), the pixel is outside the image or no depth
        was measured there; None when planning without a frame (term left out)
    clearance : min(1, d / clearance_radius_m), d the distance from the grasped
        vertex to the nearest vertex of another layer (not a neighbour on the
        canonical mesh); 1 when none is within the radius
    confidence : the estimate's confidence
    nearest_layer_m : d in metres, or inf when no other layer is within the radius
    single_layer : for corner and boundary grasps planned with a frame,
        clip(2 - s / layer_thickness_m, 0, 1), s = ``step_m``: 1 where one layer of
        cloth lies at the point, 0 from two layers up (a fold's end, where the cloth
        bends back over itself); 1 where s is unmeasured or above
        ``max_support_gap_m``; None otherwise (term left out)
    step_m : s, metres: the median height of the measured cloth just inside the outline
        above the measured surface just beyond it (``grasping._layers``); NaN when not
        measured
    """

    visibility: float | None
    clearance: float
    confidence: float
    nearest_layer_m: float
    single_layer: float | None = None
    step_m: float = math.nan


@dataclass(frozen=True)
class GraspResult:
    """Outcome of grasp planning on one estimate.

    plans : GraspPlan tuple, best score first (ties: the sharper corner first, then the
        lower vertex id)
    terms : GraspTerms tuple, the score terms of ``plans[i]`` at index i
    reason : why ``plans`` is empty, one line; "" when there are plans
    rejected : candidates dropped, by cause ("outside workspace", "degenerate
        geometry", "below min_score")
    """

    plans: tuple = ()
    terms: tuple = ()
    reason: str = ""
    rejected: dict = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.plans)


@dataclass(frozen=True, eq=False)
class _CanonicalModel:
    """What depends on the canonical mesh only: reused while it does not change.

    graph : (N, N) sparse float64, canonical edge lengths in metres (symmetric)
    outline : Outline, or None when the mesh has no boundary vertices or it
        was not asked for
    """

    graph: csr_matrix
    outline: Outline | None


def _canonical_key(estimate: MeshEstimate) -> bytes:
    """Digest of the canonical mesh (positions, faces, boundary) of an estimate."""
    h = hashlib.blake2b(digest_size=16)
    for arr in (estimate.canonical, estimate.faces, estimate.boundary):
        h.update(str(arr.shape).encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.digest()


def _build_model(estimate: MeshEstimate, config: GraspPlannerConfig, with_outline: bool) -> _CanonicalModel:
    """Precompute what depends on the canonical mesh only; the outline only if asked."""
    faces = estimate.faces.astype(np.int64)
    graph = edge_length_graph(estimate.canonical, faces)
    outline = None
    if with_outline and estimate.boundary.size:
        outline = build_outline(
            estimate.canonical, faces, estimate.boundary, config.corner_max_angle_rad, config.outline_window_spacings
        )
    return _CanonicalModel(graph=graph, outline=outline)


def _check_inputs(estimate, frame) -> None:
    if not isinstance(estimate, MeshEstimate):
        raise ValueError(f"Expected estimate of type MeshEstimate, got {type(estimate).__name__}")
    if estimate.faces.shape[0] == 0:
        raise ValueError(f"Expected estimate with at least one face, got faces of shape {estimate.faces.shape}")
    if frame is not None:
        if not isinstance(frame, RGBDFrame):
            raise ValueError(f"Expected frame of type RGBDFrame or None, got {type(frame).__name__}")
        if frame.camera.frame_id != estimate.frame_id:
            raise ValueError(
                f"Expected frame and estimate in the same camera frame, got {frame.camera.frame_id!r} and {estimate.frame_id!r}"
            )


def _empty(reason: str, rejected: dict | None = None) -> GraspResult:
    log.debug("no grasp: %s", reason)
    return GraspResult(plans=(), terms=(), reason=reason, rejected=dict(rejected or {}))


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-normalised (K, 3) vectors and a (K,) mask of rows long enough to normalise."""
    norm = np.linalg.norm(v, axis=1)
    ok = norm > 1e-12
    return v / np.where(ok, norm, 1.0)[:, None], ok


@dataclass(frozen=True, eq=False)
class _Candidates:
    """Grasp candidates before scoring, camera frame.

    vertex_ids : (K,) int64; positions : (K, 3) float64 metres; approach : (K, 3)
    unit vectors (gripper z); closing : (K, 3) finger closing directions (gripper
    x, not yet orthogonal to approach); valid : (K,) bool, False where the local
    geometry is degenerate (zero-area faces, collapsed outline); angle_rad : (K,)
    interior angle of the canonical outline at a corner, pi for other kinds;
    inward : (K, 3) unit vectors into the cloth across its outline, None for the
    highest-point grasp
    """

    vertex_ids: np.ndarray
    positions: np.ndarray
    approach: np.ndarray
    closing: np.ndarray
    valid: np.ndarray
    angle_rad: np.ndarray
    inward: np.ndarray | None = None


def _surface_normals(estimate: MeshEstimate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vertex normals of the estimate: (N, 3) by face winding, (N, 3) turned toward
    the camera, and (N,) bool where a normal exists (not only zero-area faces around)."""
    V = estimate.vertices
    normals, has_normal = _unit(vertex_normals(V, estimate.faces, unit=False))
    # Orient normals toward the camera (the origin of the camera frame): that is
    # the side the gripper can come from and the side the fingers close onto.
    toward_cam = np.where(np.sum(normals * -V, axis=1, keepdims=True) < 0, -normals, normals)
    return normals, toward_cam, has_normal


def _outline_candidates(estimate: MeshEstimate, outline: Outline, rows: np.ndarray, angle_rad: np.ndarray,
                        config: GraspPlannerConfig) -> _Candidates:
    """Corner or boundary grasps at outline ``rows`` (K,), placed on the estimate.

    The fingertips close ``config.pinch_inset_m`` inside the outline; the approach and
    closing directions follow ``config.edge_approach``. ``angle_rad`` (K,) is carried
    into the candidates (the interior angle for corners, pi for boundary points).
    """
    V = estimate.vertices
    normals, toward_cam, has_normal = _surface_normals(estimate)
    vid = outline.vertex_ids[rows]
    behind, ahead = outline.chord_points(V, rows)
    # The outline runs with the cloth on its left about the winding normal, so
    # winding normal x outline direction points into the cloth, whatever the
    # cloth's pose and whichever side faces the camera.
    inward, has_inward = _unit(np.cross(normals[vid], ahead - behind))
    positions = V[vid] + config.pinch_inset_m * inward
    if config.edge_approach == "pinch":
        approach, closing = inward, toward_cam[vid]
    else:
        approach, closing = -toward_cam[vid], inward
    return _Candidates(vid, positions, approach, closing, has_normal[vid] & has_inward, angle_rad, inward)


def _candidates(
    estimate: MeshEstimate, model: _CanonicalModel, config: GraspPlannerConfig, reachable_vertex: np.ndarray | None
) -> _Candidates | str:
    """Candidate grasps of ``config.kind``, or a one-line reason why there are none.

    ``reachable_vertex`` (N,) bool, used by the "highest" kind only: which
    vertices lie inside the workspace.
    """
    if config.kind == "highest":
        V = estimate.vertices
        _, toward_cam, has_normal = _surface_normals(estimate)
        height = V @ config.up_cam
        choices = np.flatnonzero(reachable_vertex)
        if choices.size == 0:
            return "no vertex inside the workspace"
        vid = choices[np.argmax(height[choices])][None]
        approach = -toward_cam[vid]
        # Any closing direction across the approach works for a point on the
        # surface; take the camera's x axis (y if nearly parallel) to be repeatable.
        ref = np.where(np.abs(approach[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        return _Candidates(vid, V[vid], approach, ref, has_normal[vid], np.full(1, np.pi))

    outline = model.outline
    if outline is None:
        return "estimate has no boundary vertices"
    if config.kind == "corner":
        rows = outline.corner_rows
        if rows.size == 0:
            sharpest = np.rad2deg(outline.interior_angle_rad.min())
            return (
                f"no corners on the canonical outline (sharpest interior angle {sharpest:.0f} deg, "
                f"limit {np.rad2deg(config.corner_max_angle_rad):.0f} deg)"
            )
        angle = outline.interior_angle_rad[rows]
    else:
        rows = outline.sample_rows(config.boundary_spacing_m)
        angle = np.full(len(rows), np.pi)
    return _outline_candidates(estimate, outline, rows, angle, config)


def _inside_workspace(points_cam: np.ndarray, config: GraspPlannerConfig) -> np.ndarray:
    """(K,) bool: camera-frame points (K, 3), metres, inside the workspace box (world frame)."""
    points_world = transform_points(config.T_world_cam, points_cam)
    return np.all((points_world >= config.workspace_min_world) & (points_world <= config.workspace_max_world), axis=1)


def _clearance(estimate: MeshEstimate, graph, vid: np.ndarray, config: GraspPlannerConfig) -> np.ndarray:
    """(K,) float64 metres from each vertex in ``vid`` to the nearest vertex of another layer (inf if none within the radius)."""
    V = estimate.vertices
    radius = config.clearance_radius_m
    geodesic = dijkstra(graph, directed=False, indices=vid, limit=config.neighbour_geodesic_factor * radius)
    tree = cKDTree(V)
    nearest = np.full(len(vid), np.inf)
    for k, near in enumerate(tree.query_ball_point(V[vid], r=radius)):
        near = np.asarray(near, np.int64)
        other = near[~np.isfinite(geodesic[k, near])]
        if other.size:
            nearest[k] = np.min(np.linalg.norm(V[other] - V[vid[k]], axis=1))
    return nearest


def _clearance_term(nearest_m: np.ndarray, config: GraspPlannerConfig) -> np.ndarray:
    """(K,) float64 in [0, 1], the clearance term of ``GraspTerms`` from ``_clearance``'s distances (K,) metres."""
    return np.minimum(1.0, nearest_m / config.clearance_radius_m)


def _grasp_plans(estimate: MeshEstimate, vid: np.ndarray, positions: np.ndarray, approach: np.ndarray,
                 closing: np.ndarray, score: np.ndarray, kind: str, config: GraspPlannerConfig) -> list[GraspPlan]:
    """GraspPlan messages, in the given order, for candidates (K,) in the camera frame.

    approach, closing : (K, 3) gripper z and closing directions (closing need not be
    orthogonal to approach: the gripper frame takes its part across the approach)
    score : (K,) float64 in [0, 1]
    """
    R = frames_from_z_and_x(approach, closing)
    quats = quaternion_xyzw_from_matrix(R)
    return [
        GraspPlan(
            position=positions[k],
            approach=R[k][:, 2],
            quat_xyzw=quats[k],
            opening_width_m=config.opening_width_m,
            score=float(score[k]),
            vertex_id=int(vid[k]),
            kind=kind,
            frame_id=estimate.frame_id,
            timestamp_s=estimate.timestamp_s,
        )
        for k in range(len(vid))
    ]


def _single_layer(points: np.ndarray, inward: np.ndarray, frame: RGBDFrame,
                  config: GraspPlannerConfig) -> tuple[np.ndarray, np.ndarray]:
    """The single_layer term and the measured step (``GraspTerms``) at outline points (K, 3), camera frame."""
    up = config.up_cam
    outward, ok = _unit(-(inward - (inward @ up)[:, None] * up))
    step = np.full(len(points), np.nan)
    if np.any(ok):
        step[ok] = step_above_beyond(points[ok], outward[ok], up, frame)
    judged = np.isfinite(step) & (step <= config.max_support_gap_m)
    term = np.ones(len(points))
    term[judged] = np.clip(2.0 - step[judged] / config.layer_thickness_m, 0.0, 1.0)
    return term, step


def _plan(estimate: MeshEstimate, model: _CanonicalModel, config: GraspPlannerConfig, frame: RGBDFrame | None) -> GraspResult:
    if estimate.lost:
        return _empty(f"estimate lost (seq {estimate.seq})")
    if estimate.confidence < config.min_confidence:
        return _empty(f"estimate confidence {estimate.confidence:.3g} below min_confidence {config.min_confidence:.3g}")

    rejected = {}
    reachable_vertex = None
    if config.kind == "highest":
        # Every vertex is a candidate: drop the unreachable ones, then take the highest.
        reachable_vertex = _inside_workspace(estimate.vertices, config)
        if not np.all(reachable_vertex):
            rejected["outside workspace"] = int(np.sum(~reachable_vertex))
    found = _candidates(estimate, model, config, reachable_vertex)
    if isinstance(found, str):
        return _empty(found, rejected)
    vid, positions, approach, closing, valid = found.vertex_ids, found.positions, found.approach, found.closing, found.valid
    n_candidates = len(vid)

    def none_left(rejected):
        causes = ", ".join(f"{n} {cause}" for cause, n in rejected.items())
        return _empty(f"all {n_candidates} {config.kind} candidates rejected: {causes}", rejected)

    reachable = _inside_workspace(positions, config)
    if np.any(~valid):
        rejected["degenerate geometry"] = int(np.sum(~valid))
    if np.any(valid & ~reachable):
        rejected["outside workspace"] = int(np.sum(valid & ~reachable))
    keep = valid & reachable
    if not np.any(keep):
        return none_left(rejected)
    vid, positions, approach, closing = vid[keep], positions[keep], approach[keep], closing[keep]
    angle = found.angle_rad[keep]
    inward = None if found.inward is None else found.inward[keep]

    nearest = _clearance(estimate, model.graph, vid, config)
    clearance = _clearance_term(nearest, config)
    confidence = float(estimate.confidence)
    score = config.weight_clearance * clearance + config.weight_confidence * confidence
    total_weight = config.weight_clearance + config.weight_confidence
    visibility, single_layer, step = None, None, np.full(len(vid), np.nan)
    if frame is not None:
        points = estimate.vertices[vid]
        uv = project(points, frame.camera.K, frame.camera.D)
        seen = depth_agrees(points, frame.depth_m, uv, config.visibility_tol_m, config.visibility_window_px)
        visibility = seen.astype(np.float64)
        score = score + config.weight_visibility * visibility
        total_weight += config.weight_visibility
        if inward is not None:
            single_layer, step = _single_layer(points, inward, frame, config)
            score = score + config.weight_single_layer * single_layer
            total_weight += config.weight_single_layer
    score = score / total_weight

    low = score < config.min_score
    if np.any(low):
        rejected["below min_score"] = int(np.sum(low))
    # Equal scores (a cloth lying flat and in view scores 1 at every corner): the sharpest
    # corner first, as the surest corner of the cloth rather than a bend of its outline
    # (a T-shirt's shoulder), then the lower vertex id, to be repeatable.
    order = [k for k in np.lexsort((vid, angle, -score)) if not low[k]]
    if not order:
        return none_left(rejected)

    plans = _grasp_plans(estimate, vid[order], positions[order], approach[order], closing[order], score[order],
                         config.kind, config)
    terms = []
    for k in order:
        terms.append(
            GraspTerms(
                visibility=None if visibility is None else float(visibility[k]),
                clearance=float(clearance[k]),
                confidence=confidence,
                nearest_layer_m=float(nearest[k]),
                single_layer=None if single_layer is None else float(single_layer[k]),
                step_m=float(step[k]),
            )
        )
    if log.isEnabledFor(logging.DEBUG):  # the steps are formatted only for a reader
        log.debug("%d %s grasp(s), best score %.3f at vertex %d; steps above the surface beyond (mm): %s", len(plans),
                  config.kind, plans[0].score, plans[0].vertex_id, " ".join(f"{t.step_m * 1000:.1f}" for t in terms))
    return GraspResult(plans=tuple(plans), terms=tuple(terms), reason="", rejected=rejected)


def plan_grasps(estimate: MeshEstimate, config: GraspPlannerConfig | None = None, frame: RGBDFrame | None = None) -> GraspResult:
    """Grasp candidates on a tracked cloth mesh, best first.

    Candidates depend on ``config.kind``: the corners of the canonical outline
    (found by ``find_corners``) followed through the estimate, points evenly
    spaced along the outline, or the highest reachable vertex. Candidates outside
    the workspace are dropped; the rest are scored by the weighted mean of
    visibility (only with ``frame``), clearance from other cloth layers, the
    estimate's confidence and, for corner and boundary grasps with ``frame``,
    whether a single layer of cloth lies there (see ``GraspTerms``). This recomputes the canonical
    outline on every call; ``GraspPlanner`` caches it.

    Parameters
    ----------
    estimate : MeshEstimate; vertices (N, 3) float64 metres, camera frame
    config : GraspPlannerConfig, default settings when None
    frame : RGBDFrame the estimate came from, or None; its ``depth_m`` (H, W)
        float32 metres and ``camera.K`` give the visibility term

    Returns
    -------
    GraspResult; its ``plans`` are GraspPlan in ``estimate.frame_id`` with
    ``kind = config.kind``, positions (3,) metres, unit ``approach`` (gripper z),
    ``quat_xyzw`` of ``R_cam_gripper`` (columns: closing x, y = z x x, approach
    z; w >= 0), ``opening_width_m`` from the config, score in [0, 1]. Empty with
    a one-line ``reason`` when the estimate is lost or too unconfident, has no
    boundary (corner and boundary kinds), no corners, or no candidate survives.

    Raises
    ------
    ValueError : ``estimate`` not a MeshEstimate or without faces, ``frame`` not
        an RGBDFrame or in another camera frame, or a malformed canonical mesh
    """
    config = GraspPlannerConfig() if config is None else config
    _check_inputs(estimate, frame)
    return _plan(estimate, _build_model(estimate, config, with_outline=config.kind != "highest"), config, frame)


class GraspPlanner:
    """Grasp planner that keeps the canonical-mesh analysis between frames.

    The canonical mesh does not change while a cloth is tracked, so its outline,
    corners and edge graph are computed for the first estimate and reused while
    later estimates carry the same canonical mesh (compared by content digest,
    since every decoded message holds new arrays).

    Parameters
    ----------
    config : GraspPlannerConfig, default settings when None
    """

    def __init__(self, config: GraspPlannerConfig | None = None):
        self.config = GraspPlannerConfig() if config is None else config
        self._key: bytes | None = None
        self._model: _CanonicalModel | None = None

    def _model_for(self, estimate: MeshEstimate) -> _CanonicalModel:
        key = _canonical_key(estimate)
        if key != self._key:
            # Built with the outline whatever the kind, so that corners() can answer.
            self._model = _build_model(estimate, self.config, with_outline=True)
            self._key = key
            log.info(
                "canonical mesh analysed: %d vertices, %d corners",
                len(estimate.canonical),
                0 if self._model.outline is None else len(self._model.outline.corner_rows),
            )
        return self._model

    def corners(self, estimate: MeshEstimate) -> np.ndarray:
        """(C,) int64 corner vertex ids of the estimate's canonical mesh (cached).

        Empty when the estimate has no boundary vertices.
        """
        _check_inputs(estimate, None)
        outline = self._model_for(estimate).outline
        return np.zeros(0, np.int64) if outline is None else outline.corner_ids

    def plan(self, estimate: MeshEstimate, frame: RGBDFrame | None = None) -> GraspResult:
        """Grasp candidates for one estimate, as ``plan_grasps`` with this planner's config."""
        _check_inputs(estimate, frame)
        return _plan(estimate, self._model_for(estimate), self.config, frame)

    def adjacent_corners(self, estimate: MeshEstimate, held_vertex: int, frame: RGBDFrame | None = None,
                         max_candidates: int = 2, even_if_lost: bool = False):
        """The corners adjacent to a held point, as ``grasping.adjacent_corners`` with this
        planner's config and its cached analysis of the canonical mesh.

        Returns an ``AdjacentCornersResult``; raises ValueError as ``adjacent_corners`` does.
        """
        # Imported here: grasping._adjacent builds on this module's helpers.
        from grasping._adjacent import _adjacent_on_model

        _check_inputs(estimate, frame)
        return _adjacent_on_model(estimate, self._model_for(estimate), self.config, frame, held_vertex, max_candidates,
                                  even_if_lost)
