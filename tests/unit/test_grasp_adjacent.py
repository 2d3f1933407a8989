"""The corners adjacent to a held one (grasping.adjacent_corners) and the planner's request for them.

Meshes come from the project's own builders: the tracker's hexagonal canonical mesh over a
polygon (perception.mesh) and the simulation's T-shirt (sim.cloth_mesh). Which corners are
adjacent is known from the polygon: the corners next to each other along its outline.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grasping import (
    AdjacentCornersResult,
    GraspPlanner,
    GraspPlannerConfig,
    _planner,
    adjacent_corners,
    plan_grasps,
)
from grasping._adjacent import HELD_MAX_OFFSET_SPACINGS
from grasping.service import PlannerCore
from ipc.messages import (
    AdjacentCorner,
    AdjacentCornersReply,
    AdjacentCornersRequest,
    CameraInfo,
    ErrorReply,
    MeshEstimate,
    RGBDFrame,
)
from perception.geometry import boundary_half_edges
from perception.mesh import lattice_covering, lattice_to_xy, mesh_from_lattice, rectangle_mesh
from sim.cloth_mesh import TShirtShape, points_in_polygon, tshirt_cloth

S = 0.02  # grid spacing, metres
W, H = 0.4, 0.3
ROW = S * np.sqrt(3) / 2  # distance between lattice rows, metres
# rectangle_mesh keeps vertices inside the rectangle; its rows alternate between starting at
# 0 and at s / 2, so the top corners (row 17, odd) sit at x = s / 2 and W - s / 2.
TOP = 17 * ROW
RECTANGLE = np.array([[0.0, 0.0], [W, 0.0], [W - S / 2, TOP], [S / 2, TOP]])  # counter-clockwise


def towel_estimate(vertices=None, **kw) -> MeshEstimate:
    """The tracker's canonical mesh of a W x H towel; flat 1 m in front of the camera unless ``vertices``."""
    mesh = rectangle_mesh(W, H, S)
    canonical = mesh.canonical
    if vertices is None:
        vertices = canonical - [W / 2, H / 2, 0.0] + [0.0, 0.0, 1.0]
    return MeshEstimate(vertices=vertices, faces=mesh.faces, boundary=mesh.boundary, canonical=canonical, **kw)


def polygon_estimate(polygon, spacing=S, vertices=None, **kw) -> MeshEstimate:
    """The tracker's canonical mesh (hexagonal lattice) of the vertices inside ``polygon`` (P, 2)."""
    polygon = np.asarray(polygon, float)
    lattice = lattice_covering((polygon[:, 0].min(), polygon[:, 0].max()), (polygon[:, 1].min(), polygon[:, 1].max()),
                               spacing)
    inside = points_in_polygon(lattice_to_xy(lattice, spacing), polygon)
    mesh = mesh_from_lattice(lattice[inside], spacing)
    canonical = mesh.canonical
    if vertices is None:
        vertices = canonical - canonical.mean(axis=0) + [0.0, 0.0, 1.0]
    return MeshEstimate(vertices=vertices, faces=mesh.faces, boundary=mesh.boundary, canonical=canonical, **kw)


def nearest_vertex(estimate: MeshEstimate, point) -> int:
    return int(np.argmin(np.linalg.norm(estimate.canonical[:, :2] - np.asarray(point, float), axis=1)))


def polygon_corner_of(estimate: MeshEstimate, vertex_ids, polygon) -> list[int]:
    """Index of the polygon vertex nearest to each mesh vertex (canonical frame)."""
    pts = estimate.canonical[np.asarray(vertex_ids), :2]
    return [int(k) for k in np.argmin(np.linalg.norm(pts[:, None] - np.asarray(polygon)[None], axis=2), axis=1)]


def expected_neighbours(corner_polygon_ids: list[int]) -> dict[int, set[int]]:
    """Polygon index -> the polygon indices of the previous and next corner along the polygon."""
    order = sorted(corner_polygon_ids)
    return {c: {order[(i - 1) % len(order)], order[(i + 1) % len(order)]} for i, c in enumerate(order)}


def by_side(result: AdjacentCornersResult) -> dict[int, AdjacentCorner]:
    return {c.side: c for c in result.candidates}


# --------------------------------------------------------------------------- rectangle


def test_rectangle_corners_have_their_two_edge_neighbours_never_the_diagonal():
    est = towel_estimate()
    corners = [nearest_vertex(est, c) for c in RECTANGLE]
    assert np.allclose(est.canonical[corners, :2], RECTANGLE), "test setup: the towel's corners are mesh vertices"
    assert sorted(GraspPlanner().corners(est)) == sorted(corners)
    for k, held in enumerate(corners):
        result = adjacent_corners(est, held)
        assert isinstance(result, AdjacentCornersResult) and result and result.reason == ""
        assert result.held_outline_vertex == held
        sides = by_side(result)
        assert set(sides) == {1, -1} and len(result.candidates) == 2
        # The canonical mesh's faces are counter-clockwise: forward is counter-clockwise.
        assert sides[1].plan.vertex_id == corners[(k + 1) % 4]
        assert sides[-1].plan.vertex_id == corners[(k - 1) % 4]
        assert corners[(k + 2) % 4] not in {c.plan.vertex_id for c in result.candidates}
        for c in result.candidates:
            edge = np.linalg.norm(est.canonical[held] - est.canonical[c.plan.vertex_id])
            assert edge <= c.material_distance_m <= edge + 0.1 * S
            assert c.plan.kind == "corner" and c.visible == 1.0 and c.reachable
            assert c.plan.frame_id == est.frame_id and c.plan.timestamp_s == est.timestamp_s


@pytest.mark.parametrize("edge_approach", ["pinch", "normal"])
def test_candidates_are_placed_exactly_as_corner_grasps(edge_approach):
    config = GraspPlannerConfig(edge_approach=edge_approach, pinch_inset_m=0.015, opening_width_m=0.05)
    est = towel_estimate(vertices=bent_and_moved(towel_estimate().canonical))
    corner_plans = {p.vertex_id: p for p in plan_grasps(est, config).plans}
    for held in corner_plans:
        for c in adjacent_corners(est, held, config).candidates:
            same = corner_plans[c.plan.vertex_id]
            np.testing.assert_allclose(c.plan.position, same.position, atol=1e-12)
            np.testing.assert_allclose(c.plan.approach, same.approach, atol=1e-12)
            np.testing.assert_allclose(c.plan.quat_xyzw, same.quat_xyzw, atol=1e-12)
            assert c.plan.opening_width_m == same.opening_width_m == 0.05


def bent_and_moved(canonical: np.ndarray) -> np.ndarray:
    """The towel folded in half over a 3 cm radius about x = W / 2 (a U, the two halves 6 cm
    apart, as a cloth hanging folded), then turned and moved: (N, 3) camera frame."""
    x, y = canonical[:, 0] - W / 2, canonical[:, 1]
    radius = 0.03
    arc = np.pi * radius  # the fold's length along x
    p = np.zeros((len(x), 3))
    for side in (-1, 1):
        on = side * x > arc / 2
        p[on] = np.column_stack([np.full(on.sum(), side * radius), y[on], side * x[on] - arc / 2])
    bend = np.abs(x) <= arc / 2
    theta = x[bend] / radius
    p[bend] = np.column_stack([radius * np.sin(theta), y[bend], -radius * np.cos(theta)])
    R = Rotation.from_euler("xyz", [40, -25, 70], degrees=True).as_matrix()
    return p @ R.T + [0.05, -0.02, 1.1]


def test_adjacency_follows_the_material_through_a_rigid_motion_and_a_strong_bend():
    flat = towel_estimate()
    folded = towel_estimate(vertices=bent_and_moved(flat.canonical))
    corners = [nearest_vertex(flat, c) for c in RECTANGLE]
    # Folded, corner 0 lies next to corner 1 and corner 3 next to corner 2 (6 cm apart), and
    # each corner's diagonal is as near to it in space as its neighbour along the short side.
    v = folded.vertices
    assert np.linalg.norm(v[corners[0]] - v[corners[1]]) < 0.07
    assert np.linalg.norm(v[corners[0]] - v[corners[2]]) < np.linalg.norm(v[corners[0]] - v[corners[3]]) + 0.01
    config = GraspPlannerConfig(pinch_inset_m=0.0)
    for held in corners:
        before = adjacent_corners(flat, held, config)
        after = adjacent_corners(folded, held, config)
        assert [(c.plan.vertex_id, c.side) for c in sorted(after.candidates, key=lambda c: c.side)] == \
               [(c.plan.vertex_id, c.side) for c in sorted(before.candidates, key=lambda c: c.side)]
        for a, b in zip(sorted(after.candidates, key=lambda c: c.side), sorted(before.candidates, key=lambda c: c.side)):
            assert a.material_distance_m == pytest.approx(b.material_distance_m, abs=1e-12)
            # Positions follow the estimate: with no inset, the grasp is at the corner vertex.
            np.testing.assert_allclose(a.plan.position, v[a.plan.vertex_id], atol=1e-12)


def test_a_held_vertex_mid_edge_gets_that_edges_end_corners():
    est = towel_estimate()
    corners = [nearest_vertex(est, c) for c in RECTANGLE]
    mid_bottom = nearest_vertex(est, (W / 2, 0.0))
    result = adjacent_corners(est, mid_bottom)
    assert result.held_outline_vertex == mid_bottom
    sides = by_side(result)
    assert (sides[1].plan.vertex_id, sides[-1].plan.vertex_id) == (corners[1], corners[0])
    for c in result.candidates:
        assert c.material_distance_m == pytest.approx(W / 2, abs=1e-9)
    # One row inside the edge, off the outline: the held point is the bottom edge's vertex.
    inside = nearest_vertex(est, (W / 2 + S / 2, ROW))
    assert inside not in est.boundary
    off = adjacent_corners(est, inside)
    assert est.canonical[off.held_outline_vertex, 1] == 0.0
    assert {c.plan.vertex_id for c in off.candidates} == {corners[0], corners[1]}


def test_a_held_vertex_just_inside_a_corner_holds_that_corner():
    est = towel_estimate()
    corners = [nearest_vertex(est, c) for c in RECTANGLE]
    near_corner = nearest_vertex(est, (S * 1.5, ROW))  # second row, one in from the left side
    assert near_corner not in corners and near_corner not in est.boundary
    result = adjacent_corners(est, near_corner)
    assert {c.plan.vertex_id for c in result.candidates} == {corners[1], corners[3]}


def test_material_distance_evens_out_the_grid_zigzag_at_any_angle():
    """Sides at an angle to the lattice are zigzag paths of edges up to 15 % longer than the
    side; the material distance must stay close to the straight distance between the corners."""
    excess = []
    for angle_deg in (0, 15, 30, 45, 60, 75):
        a = np.radians(angle_deg)
        rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        polygon = np.array([[0, 0], [0.5, 0], [0.5, 0.35], [0, 0.35]]) @ rotation.T + [0.007, 0.003]
        est = polygon_estimate(polygon)
        planner = GraspPlanner()
        corners = planner.corners(est)
        assert len(corners) == 4
        for held in corners:
            for c in planner.adjacent_corners(est, int(held)).candidates:
                straight = np.linalg.norm(est.canonical[held] - est.canonical[c.plan.vertex_id])
                excess.append(c.material_distance_m - straight)
    excess = np.array(excess)
    assert excess.min() >= -1e-9 and excess.max() < 0.3 * S, (excess.min(), excess.max())


# --------------------------------------------------------------------------- other outlines

L_SHAPE = np.array([[0, 0], [0.5, 0], [0.5, 0.2], [0.2, 0.2], [0.2, 0.45], [0, 0.45]])  # concave at index 3


def test_l_shape_neighbours_skip_the_concave_corner():
    est = polygon_estimate(L_SHAPE + [0.004, 0.006])
    corners = GraspPlanner().corners(est)
    ids = polygon_corner_of(est, corners, L_SHAPE + [0.004, 0.006])
    assert sorted(ids) == [0, 1, 2, 4, 5], "test setup: the five convex corners"
    neighbours = expected_neighbours(ids)
    assert neighbours[2] == {1, 4}  # along the outline through the concave corner
    for vertex, k in zip(corners, ids):
        result = adjacent_corners(est, int(vertex))
        got = polygon_corner_of(est, [c.plan.vertex_id for c in result.candidates], L_SHAPE + [0.004, 0.006])
        assert set(got) == neighbours[k] and len(got) == 2


def tshirt_estimate(spacing_m=0.02, vertices=None) -> tuple[MeshEstimate, np.ndarray]:
    """The simulation's T-shirt as a canonical mesh, and its outline polygon in the same frame."""
    shirt = tshirt_cloth(spacing_m=spacing_m)
    canonical = np.column_stack([shirt.uv_m, np.zeros(shirt.n_vertices)])
    boundary = np.unique(boundary_half_edges(shirt.faces)).astype(np.int32)
    outline = TShirtShape().outline()
    outline = outline - outline.min(axis=0)  # as tshirt_cloth places it
    if vertices is None:
        vertices = canonical - canonical.mean(axis=0) + [0.0, 0.0, 1.0]
    est = MeshEstimate(vertices=vertices, faces=shirt.faces.astype(np.int32), boundary=boundary, canonical=canonical)
    return est, outline


def test_tshirt_corners_are_their_outline_neighbours():
    est, outline = tshirt_estimate()
    # Outline points: neck 0..8, right shoulder 9, right cuff top 10 and bottom 11, right
    # armpit 12, right hem 13, left hem 14, left armpit 15, left cuff bottom 16 and top 17,
    # left shoulder 18. Shoulders are too flat and armpits concave to be corners.
    corners = GraspPlanner().corners(est)
    ids = polygon_corner_of(est, corners, outline)
    assert sorted(ids) == [0, 8, 10, 11, 13, 14, 16, 17]
    neighbours = expected_neighbours(ids)
    assert neighbours[13] == {11, 14} and neighbours[14] == {13, 16}  # the hem, and under the sleeve
    for vertex, k in zip(corners, ids):
        result = adjacent_corners(est, int(vertex))
        got = polygon_corner_of(est, [c.plan.vertex_id for c in result.candidates], outline)
        assert set(got) == neighbours[k], k
    hem = adjacent_corners(est, int(corners[ids.index(13)]))
    along_hem = next(c for c in hem.candidates if polygon_corner_of(est, [c.plan.vertex_id], outline) == [14])
    assert along_hem.material_distance_m == pytest.approx(TShirtShape().body_width_m, abs=2 * 0.02)


def test_one_other_corner_is_returned_once_on_its_nearer_side():
    # A half disc: two corners where the diameter meets the arc, the arc smooth.
    angles = np.linspace(0.0, np.pi, 60)
    half_disc = np.column_stack([0.25 * np.cos(angles), 0.25 * np.sin(angles)])
    est = polygon_estimate(half_disc + [0.003, 0.002])
    corners = GraspPlanner().corners(est)
    assert len(corners) == 2
    result = adjacent_corners(est, int(corners[0]))
    assert len(result.candidates) == 1 and result.candidates[0].plan.vertex_id == corners[1]
    # Nearer along the diameter (0.5 m) than round the arc (0.79 m).
    assert result.candidates[0].material_distance_m == pytest.approx(0.5, abs=2 * S)
    # Held at the top of the arc: each corner about a quarter circle away, measured along
    # the curve (a straight line from the held point to the corner is 10 % shorter).
    xy = est.canonical[:, :2] - [0.003, 0.002]  # about the disc's centre
    rim = xy[est.boundary]
    radius = np.median(np.linalg.norm(rim[rim[:, 1] > 0.05], axis=1))  # of the mesh's outline, inside the cloth's
    top = nearest_vertex(est, (0.003, 0.252))
    quarter = adjacent_corners(est, top)
    assert {c.plan.vertex_id for c in quarter.candidates} == set(corners.tolist())
    held_angle = np.arctan2(*xy[quarter.held_outline_vertex][::-1])
    for c in quarter.candidates:
        turn = abs(np.arctan2(*xy[c.plan.vertex_id][::-1]) - held_angle)
        assert c.material_distance_m == pytest.approx(turn * radius, abs=0.3 * S)
        assert c.material_distance_m > np.linalg.norm(xy[c.plan.vertex_id] - xy[quarter.held_outline_vertex]) + S


def test_no_other_corner_gives_an_empty_result_and_a_reason():
    disc = np.column_stack([0.2 * np.cos(np.linspace(0, 2 * np.pi, 80, endpoint=False)),
                            0.2 * np.sin(np.linspace(0, 2 * np.pi, 80, endpoint=False))])
    est = polygon_estimate(disc)
    rim = int(est.boundary[0])
    result = adjacent_corners(est, rim)
    assert not result and result.candidates == () and result.reason == "no corners on the outline of the held point"
    assert result.held_outline_vertex == rim
    no_boundary = towel_estimate()
    no_boundary = MeshEstimate(vertices=no_boundary.vertices, faces=no_boundary.faces, boundary=np.zeros(0, np.int32),
                               canonical=no_boundary.canonical)
    empty = adjacent_corners(no_boundary, 0)
    assert empty.reason == "estimate has no boundary vertices" and empty.held_outline_vertex == -1


def test_lost_or_unconfident_estimates_give_no_candidates():
    held = nearest_vertex(towel_estimate(), (0, 0))
    lost = adjacent_corners(towel_estimate(lost=True, seq=4), held)
    assert not lost and lost.reason == "estimate lost (seq 4)" and lost.held_outline_vertex == held
    shaky = adjacent_corners(towel_estimate(confidence=0.3), held, GraspPlannerConfig(min_confidence=0.5))
    assert not shaky and shaky.reason == "estimate confidence 0.3 below min_confidence 0.5"
    # asked even if lost: the same corners as on the estimate not flagged
    kept = adjacent_corners(towel_estimate(seq=4), held)
    for estimate, config in ((towel_estimate(lost=True, seq=4), None),
                             (towel_estimate(confidence=0.3), GraspPlannerConfig(min_confidence=0.5))):
        asked = adjacent_corners(estimate, held, config, even_if_lost=True)
        assert [c.plan.vertex_id for c in asked.candidates] == [c.plan.vertex_id for c in kept.candidates]
        assert len(asked.candidates) == 2 and asked.reason == ""


# --------------------------------------------------------------------------- scores


def test_unreachable_corners_score_zero_but_are_returned_last():
    est = towel_estimate()
    corners = [nearest_vertex(est, c) for c in RECTANGLE]
    # Camera frame = world frame here: the box leaves out x > 0.1 (the right side of the towel).
    config = GraspPlannerConfig(workspace_max_world=np.array([0.1, 1.0, 2.0]))
    result = adjacent_corners(est, corners[0], config)
    first, second = result.candidates
    assert (first.plan.vertex_id, first.reachable) == (corners[3], True) and first.plan.score > 0.5
    assert (second.plan.vertex_id, second.reachable, second.plan.score) == (corners[1], False, 0.0)
    (only,) = adjacent_corners(est, corners[0], config, max_candidates=1).candidates
    assert only.plan.vertex_id == first.plan.vertex_id


def test_visibility_from_the_flags_and_the_depth_image():
    est = towel_estimate(confidence=0.8)
    corners = [nearest_vertex(est, c) for c in RECTANGLE]
    flat = adjacent_corners(est, corners[0])
    assert {c.visible for c in flat.candidates} == {1.0}  # nothing known: nothing hidden
    # Without visibility the score is the mean of clearance (1) and confidence.
    assert [c.plan.score for c in flat.candidates] == [pytest.approx(0.9)] * 2

    visible = np.ones(len(est.vertices), bool)
    near_right = np.linalg.norm(est.canonical[:, :2] - RECTANGLE[1], axis=1) < 0.03
    visible[near_right] = False
    flagged = MeshEstimate(vertices=est.vertices, faces=est.faces, boundary=est.boundary, canonical=est.canonical,
                           confidence=0.8, visible=visible)
    sides = by_side(adjacent_corners(flagged, corners[0]))
    assert sides[1].visible == 0.0 and sides[-1].visible == 1.0
    assert sides[-1].plan.score == pytest.approx((1 + 0.8 + 1) / 3) and sides[1].plan.score == pytest.approx(1.8 / 3)

    # A frame: the towel at 1 m fills its pixels, except something 0.5 m away in front of
    # the top left corner (corners[3], at camera x, y = -0.19, +0.144: pixel (62, 104)).
    camera = CameraInfo(width=200, height=150, K=np.array([[200.0, 0, 100], [0, 200.0, 75], [0, 0, 1]]))
    depth = np.full((150, 200), 1.0, np.float32)
    depth[90:, :75] = 0.5
    frame = RGBDFrame(rgb=np.zeros((150, 200, 3), np.uint8), depth_m=depth, camera=camera)
    sides = by_side(adjacent_corners(est, corners[0], frame=frame))
    assert sides[1].visible == 1.0 and sides[-1].visible == 0.0
    assert sides[-1].plan.score == pytest.approx((1 + 0.8 + 0) / 3)
    # Something covering the corner vertex's pixels only (a spacing is 4 pixels): the
    # material around it is still seen, so the corner is partly visible.
    depth = np.full((150, 200), 1.0, np.float32)
    depth[103:106, 61:64] = 0.5
    frame = RGBDFrame(rgb=np.zeros((150, 200, 3), np.uint8), depth_m=depth, camera=camera)
    partly = by_side(adjacent_corners(est, corners[0], frame=frame))[-1].visible
    assert 0.5 < partly < 1.0


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("held, match", [
    (-1, r"Expected held_vertex in \[0, 369\) \(a vertex of the canonical mesh\), got -1"),
    (369, r"Expected held_vertex in \[0, 369\)"),
    (1.0, r"Expected held_vertex an integer vertex id, got 1\.0"),
    (True, r"Expected held_vertex an integer vertex id, got True"),
])
def test_held_vertex_outside_the_mesh_is_a_one_line_error(held, match):
    est = towel_estimate()
    assert len(est.vertices) == 369
    with pytest.raises(ValueError, match=match) as e:
        adjacent_corners(est, held)
    assert "\n" not in str(e.value)


def test_held_vertex_far_from_the_outline_is_an_error():
    est = towel_estimate()
    centre = nearest_vertex(est, (W / 2, H / 2))
    with pytest.raises(ValueError, match=rf"Expected held_vertex within {HELD_MAX_OFFSET_SPACINGS:g} grid spacings "
                                         rf"\(0\.060 m\) of the canonical outline, got vertex {centre}, 0\.1\d\d m away"):
        adjacent_corners(est, centre)
    with pytest.raises(ValueError, match="Expected max_candidates an integer >= 1, got 0"):
        adjacent_corners(est, 0, max_candidates=0)
    with pytest.raises(ValueError, match="Expected estimate of type MeshEstimate"):
        adjacent_corners("towel", 0)


def test_planner_method_reuses_its_analysis_and_agrees(monkeypatch):
    calls = []
    build = _planner._build_model

    def counting(estimate, config, with_outline):
        calls.append(with_outline)
        return build(estimate, config, with_outline)

    monkeypatch.setattr(_planner, "_build_model", counting)
    planner = GraspPlanner(GraspPlannerConfig(kind="highest"))
    corners = planner.corners(towel_estimate())
    for held in corners:
        moved = towel_estimate(vertices=bent_and_moved(towel_estimate().canonical))
        mine, theirs = planner.adjacent_corners(moved, int(held)), adjacent_corners(moved, int(held), planner.config)
        assert mine.held_outline_vertex == theirs.held_outline_vertex and len(mine.candidates) == 2
        for a, b in zip(mine.candidates, theirs.candidates):
            assert (a.plan.vertex_id, a.side, a.material_distance_m, a.plan.score) == \
                   (b.plan.vertex_id, b.side, b.material_distance_m, b.plan.score)
            np.testing.assert_array_equal(a.plan.position, b.plan.position)
    assert calls == [True]  # one analysis, reused for estimates carrying the same canonical mesh


# --------------------------------------------------------------------------- the planner core


def test_planner_core_answers_whatever_kinds_it_serves():
    core = PlannerCore(kinds=("highest",), max_age_s=60.0)
    request = AdjacentCornersRequest(request_id=5, held_vertex=0)
    not_ready = core.handle(request)
    assert isinstance(not_ready, ErrorReply) and not_ready.code == "not_ready" and not_ready.request_id == 5
    core.on_estimate(towel_estimate(seq=9))
    reply = core.handle(request)
    assert isinstance(reply, AdjacentCornersReply)
    assert (reply.request_id, reply.estimate_seq, reply.held_vertex, reply.held_outline_vertex) == (5, 9, 0, 0)
    est = towel_estimate()
    corners = [nearest_vertex(est, c) for c in RECTANGLE]
    assert {c.plan.vertex_id for c in reply.candidates} == {corners[1], corners[3]}
    own = core.handle(AdjacentCornersRequest(held_vertex=corners[2], max_candidates=1, estimate=towel_estimate(seq=11)))
    assert own.estimate_seq == 11 and len(own.candidates) == 1
    core.on_estimate(towel_estimate(seq=12, lost=True))
    assert core.handle(AdjacentCornersRequest(held_vertex=0)).candidates == ()
    anyway = core.handle(AdjacentCornersRequest(held_vertex=0, even_if_lost=True))
    assert anyway.estimate_seq == 12 and {c.plan.vertex_id for c in anyway.candidates} == {corners[1], corners[3]}
    with pytest.raises(ValueError, match=r"held_vertex in \[0, 369\)"):
        core.handle(AdjacentCornersRequest(held_vertex=400))
