"""Tests of grasp selection (grasping/): smoke, exceptions, cardinality, correctness.

Meshes are built here as the tracker builds its canonical mesh: a hexagonal grid
of equilateral triangles (spacing s) laid over a polygon, keeping the vertices
inside it; boundary vertices have fewer than six neighbours. Expected answers
come from the polygon's geometry.
"""

import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grasping import (
    GraspPlanner,
    GraspPlannerConfig,
    GraspResult,
    GraspTerms,
    _planner,
    corner_angles,
    find_corners,
    plan_grasps,
)
from ipc.messages import CameraInfo, GraspPlan, MeshEstimate, RGBDFrame
from perception.geometry import invert_transform, look_at, transform_points

S = 0.02  # grid spacing, metres
ROW = S * np.sqrt(3) / 2  # distance between grid rows, metres


# --------------------------------------------------------------------------- meshes


def inside_polygon(points, polygon, eps=1e-9):
    """(K,) bool: points (K, 2) inside a simple polygon (P, 2), outline included."""
    x, y = points[:, 0], points[:, 1]
    inside = np.zeros(len(points), bool)
    on_outline = np.zeros(len(points), bool)
    for (x0, y0), (x1, y1) in zip(polygon, np.roll(polygon, -1, axis=0)):
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < x_cross)
        d = np.array([x1 - x0, y1 - y0])
        t = np.clip(((x - x0) * d[0] + (y - y0) * d[1]) / (d @ d), 0.0, 1.0)
        on_outline |= np.hypot(x - x0 - t * d[0], y - y0 - t * d[1]) < eps
    return inside | on_outline


def hex_mesh(polygon, spacing=S, origin=(0.0, 0.0)):
    """Hex-grid mesh of a polygon: canonical (N, 3) in z = 0, faces (M, 3) CCW, boundary (B,).

    Grid vertices sit at origin + (i s + (j mod 2) s / 2, j s sqrt(3) / 2).
    """
    polygon = np.asarray(polygon, float)
    row = spacing * np.sqrt(3) / 2
    j0 = int(np.floor((polygon[:, 1].min() - origin[1]) / row)) - 2
    j0 -= j0 % 2  # even rows are not shifted
    i0 = int(np.floor((polygon[:, 0].min() - origin[0]) / spacing)) - 2
    nj = int(np.ceil((polygon[:, 1].max() - origin[1]) / row)) + 2 - j0
    ni = int(np.ceil((polygon[:, 0].max() - origin[0]) / spacing)) + 2 - i0
    j, i = np.mgrid[0:nj, 0:ni]
    grid = np.stack(
        [origin[0] + (i0 + i) * spacing + (j % 2) * spacing / 2, origin[1] + (j0 + j) * row], axis=-1
    ).reshape(-1, 2)
    idx = np.arange(nj * ni).reshape(nj, ni)
    tris = []
    for jj in range(nj - 1):
        a, b, c, d = idx[jj, :-1], idx[jj, 1:], idx[jj + 1, :-1], idx[jj + 1, 1:]
        if jj % 2 == 0:  # the row above is shifted right by s / 2
            tris += [np.stack([a, b, c], 1), np.stack([b, d, c], 1)]
        else:
            tris += [np.stack([a, b, d], 1), np.stack([a, d, c], 1)]
    tris = np.concatenate(tris)
    tris = tris[inside_polygon(grid, polygon)[tris].all(axis=1)]
    used = np.unique(tris)
    remap = np.full(len(grid), -1)
    remap[used] = np.arange(len(used))
    faces = remap[tris].astype(np.int32)
    canonical = np.column_stack([grid[used], np.zeros(len(used))])
    return canonical, faces, boundary_of(faces, len(used))


def boundary_of(faces, n):
    """(B,) int32 vertices with fewer than six neighbours."""
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    return np.flatnonzero(np.bincount(edges.ravel(), minlength=n) < 6).astype(np.int32)


def rectangle(cols=20, rows=16):
    """Rectangle cols*S by rows*ROW (rows even) whose corners are grid vertices.

    Returns canonical, faces, boundary and (4,) ids of the vertices at (0, 0),
    (W, 0), (W, H), (0, H).
    """
    W, H = cols * S, rows * ROW
    polygon = np.array([[0, 0], [W, 0], [W, H], [0, H]])
    canonical, faces, boundary = hex_mesh(polygon)
    ids = np.array([np.argmin(np.linalg.norm(canonical[:, :2] - c, axis=1)) for c in polygon])
    assert np.allclose(canonical[ids, :2], polygon), "test setup: corners must be grid vertices"
    return canonical, faces, boundary, ids


# T-shirt outline, metres, counter-clockwise: hem, right armpit, right sleeve end
# (two corners), right shoulder, right neck corner, V-neck bottom, then mirrored.
_RIGHT = [(0.25, 0.0), (0.25, 0.40), (0.45, 0.32), (0.51, 0.46), (0.20, 0.62), (0.09, 0.64)]
TSHIRT = np.array(_RIGHT + [(0.0, 0.46)] + [(-x, y) for x, y in reversed(_RIGHT)])
# Interior angles: hem 90, sleeve ends 91 and 94, neck 106 degrees are corners;
# armpits (292), V-neck bottom (307) are concave and shoulders (163) nearly straight.
TSHIRT_CORNERS = [0, 2, 3, 5, 7, 9, 10, 12]


def estimate(canonical, faces, boundary, vertices=None, **kw):
    """MeshEstimate of a flat cloth facing the camera 1 m away unless ``vertices`` given."""
    if vertices is None:
        vertices = canonical - canonical.mean(axis=0) + [0.0, 0.0, 1.0]
    return MeshEstimate(vertices=vertices, faces=faces, boundary=boundary, canonical=canonical, **kw)


CAMERA = CameraInfo(width=200, height=150, K=np.array([[200.0, 0, 100], [0, 200.0, 75], [0, 0, 1]]))


def frame_of_boxes(boxes, background_m=1.5):
    """RGBDFrame of camera-facing rectangles: boxes = [(x0, x1, y0, y1, z), ...], metres, camera frame."""
    v, u = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width]
    ray_x = (u - CAMERA.cx) / CAMERA.fx
    ray_y = (v - CAMERA.cy) / CAMERA.fy
    depth = np.full(u.shape, background_m, np.float32)
    for x0, x1, y0, y1, z in sorted(boxes, key=lambda b: -b[4]):  # far first, near overwrites
        hit = (ray_x * z >= x0) & (ray_x * z <= x1) & (ray_y * z >= y0) & (ray_y * z <= y1)
        depth[hit] = z
    return RGBDFrame(rgb=np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8), depth_m=depth, camera=CAMERA)


def nearest_polygon_vertex(points, polygon):
    """For points (K, 2): index of the nearest polygon vertex and the distance, metres."""
    d = np.linalg.norm(points[:, None, :2] - polygon[None], axis=2)
    return np.argmin(d, axis=1), np.min(d, axis=1)


def quat_to_matrix(q):
    """Rotation matrix of a unit quaternion (x, y, z, w), written out independently of the code under test."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


# --------------------------------------------------------------------------- find_corners


def test_find_corners_smoke_and_cardinality():
    canonical, faces, boundary, _ = rectangle()
    corners = find_corners(canonical, faces, boundary)
    assert corners.shape == (4,)
    assert corners.dtype == np.int64
    assert set(corners) <= set(boundary)


def test_find_corners_rectangle_exact():
    canonical, faces, boundary, ids = rectangle()
    assert sorted(find_corners(canonical, faces, boundary)) == sorted(ids)


@pytest.mark.parametrize("angle_deg", [0.0, 10.0, 22.5, 30.0, 45.0, 71.0])
def test_find_corners_rotated_rectangle_any_grid_phase(angle_deg):
    rng = np.random.default_rng(int(angle_deg * 10))
    c, s = np.cos(np.deg2rad(angle_deg)), np.sin(np.deg2rad(angle_deg))
    polygon = np.array([[-0.2, -0.15], [0.2, -0.15], [0.2, 0.15], [-0.2, 0.15]]) @ np.array([[c, s], [-s, c]])
    for _ in range(3):
        canonical, faces, boundary = hex_mesh(polygon, origin=rng.uniform(0.0, S, 2))
        corners = find_corners(canonical, faces, boundary)
        which, dist = nearest_polygon_vertex(canonical[corners], polygon)
        assert sorted(which) == [0, 1, 2, 3]
        assert np.all(dist < 2 * S)


def test_corner_angles_measure_a_trapezoid_s_corners_at_the_same_vertices_as_find_corners():
    # a right trapezoid: 60, 90, 90 and 120 degrees at its polygon vertices 0-3
    polygon = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.4], [0.4 / np.tan(np.radians(60.0)), 0.4]])
    canonical, faces, boundary = hex_mesh(polygon)
    ids, angles, _ = corner_angles(canonical, faces, boundary)
    assert np.array_equal(ids, find_corners(canonical, faces, boundary))
    which, _ = nearest_polygon_vertex(canonical[ids], polygon)
    measured = dict(zip(which, np.degrees(angles)))
    assert sorted(measured) == [0, 1, 2, 3]
    for k, true in enumerate((60.0, 90.0, 90.0, 120.0)):
        assert abs(measured[k] - true) < 12.0, (k, measured[k])


def test_find_corners_tshirt():
    rng = np.random.default_rng(5)
    for _ in range(3):
        canonical, faces, boundary = hex_mesh(TSHIRT, origin=rng.uniform(0.0, S, 2))
        corners = find_corners(canonical, faces, boundary)
        which, dist = nearest_polygon_vertex(canonical[corners], TSHIRT)
        assert sorted(which) == TSHIRT_CORNERS
        assert np.all(dist < 2 * S)


def test_find_corners_survives_notches_in_the_outline():
    # Missing triangles along the outline (a ragged segmentation) must not add or move corners.
    rectangle_polygon = np.array([[-0.2, -0.15], [0.2, -0.15], [0.2, 0.15], [-0.2, 0.15]])
    for seed, (polygon, expected) in enumerate([(rectangle_polygon, [0, 1, 2, 3]), (TSHIRT, TSHIRT_CORNERS)] * 3):
        rng = np.random.default_rng(seed)
        canonical, faces, _ = hex_mesh(polygon, origin=rng.uniform(0.0, S, 2))
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
        on_outline = (counts[inverse.ravel()] == 1).reshape(3, -1).any(axis=0)
        centroid = canonical[faces].mean(axis=1)
        _, to_corner = nearest_polygon_vertex(centroid, polygon)
        notched = faces[~(on_outline & (to_corner > 2.5 * S) & (rng.random(len(faces)) < 0.3))]
        corners = find_corners(canonical, notched, boundary_of(notched, len(canonical)))
        which, dist = nearest_polygon_vertex(canonical[corners], polygon)
        assert sorted(which) == expected
        assert np.all(dist < 2.5 * S)


def test_find_corners_l_shape_skips_concave_corner():
    polygon = np.array([[0, 0], [0.4, 0], [0.4, 0.2], [0.2, 0.2], [0.2, 0.4], [0, 0.4]])
    canonical, faces, boundary = hex_mesh(polygon, origin=(0.003, 0.007))
    which, dist = nearest_polygon_vertex(canonical[find_corners(canonical, faces, boundary)], polygon)
    assert sorted(which) == [0, 1, 2, 4, 5]  # 3 is the concave corner
    assert np.all(dist < 2 * S)


def test_find_corners_round_cloth_has_none():
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    canonical, faces, boundary = hex_mesh(0.2 * np.column_stack([np.cos(t), np.sin(t)]))
    assert find_corners(canonical, faces, boundary).shape == (0,)


def test_find_corners_ignores_holes():
    canonical, faces, boundary, ids = rectangle()
    centroid = canonical[faces].mean(axis=1)
    hole = np.all(np.abs(centroid[:, :2] - canonical[:, :2].mean(axis=0)) < 0.06, axis=1)
    faces = faces[~hole]
    boundary = boundary_of(faces, len(canonical))
    assert sorted(find_corners(canonical, faces, boundary)) == sorted(ids)


def test_find_corners_independent_of_winding_plane_and_numbering():
    canonical, faces, boundary, ids = rectangle()
    rng = np.random.default_rng(0)
    # Clockwise faces (mirrored canonical frame).
    assert sorted(find_corners(canonical, faces[:, ::-1], boundary)) == sorted(ids)
    # A flat mesh in another plane.
    R = Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix()
    assert sorted(find_corners(canonical @ R.T + [1.0, 2.0, 3.0], faces, boundary)) == sorted(ids)
    # Renumbered vertices: corners are found by geometry, not by index.
    perm = rng.permutation(len(canonical))  # new id of old vertex k is inverse[k]
    inverse = np.argsort(perm)
    corners = find_corners(canonical[perm], inverse[faces], inverse[boundary])
    assert sorted(corners) == sorted(inverse[ids])


def test_find_corners_two_pieces_touching_at_a_vertex():
    # Two rectangles sharing one corner vertex: the outline touches itself there.
    a_canonical, a_faces, _, a_ids = rectangle(10, 8)
    offset = a_canonical[a_ids[2]]  # (W, H) of the first is (0, 0) of the second
    b_canonical = a_canonical + offset
    shared = a_ids[0]
    b_ids_new = np.arange(len(a_canonical)) + len(a_canonical)
    b_ids_new[shared] = a_ids[2]
    canonical = np.concatenate([a_canonical, b_canonical])
    faces = np.concatenate([a_faces, b_ids_new[a_faces]]).astype(np.int32)
    boundary = boundary_of(faces, len(canonical))
    corners = find_corners(canonical, faces, boundary)
    expected = set(a_ids) | set(b_ids_new[a_ids])
    assert len(expected) == 7
    assert sorted(corners) == sorted(expected)


def test_find_corners_only_returns_given_boundary_vertices():
    canonical, faces, boundary, ids = rectangle()
    given = np.setdiff1d(boundary, ids[:1])
    corners = find_corners(canonical, faces, given)
    assert set(corners) <= set(given) and set(ids[1:]) <= set(corners)
    # The (0, 0) corner's place is taken by the sharpest vertex the caller allows.
    assert len(corners) == 4


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda c, f, b: (c[:, :2], f, b), r"canonical with shape \(N, 3\), got \(\d+, 2\)"),
        (lambda c, f, b: (c, f[:, :2], b), r"faces with shape \(K, 3\), got \(\d+, 2\)"),
        (lambda c, f, b: (c, f, b[:0]), r"boundary to be non-empty, got shape \(0,\)"),
        (lambda c, f, b: (c, f[:0], b), r"faces to be non-empty"),
        (lambda c, f, b: (c, f, b + len(c)), r"boundary with vertex ids in \[0, \d+\)"),
        (lambda c, f, b: (c, f.astype(float), b), r"faces with an integer dtype, got float64"),
        (lambda c, f, b: (np.where(c == c.max(), np.nan, c), f, b), r"canonical with finite values"),
        (lambda c, f, b: (np.zeros_like(c), f, b), r"canonical mesh spanning a plane"),
    ],
)
def test_find_corners_bad_input(change, match):
    canonical, faces, boundary, _ = rectangle(6, 4)
    with pytest.raises(ValueError, match=match):
        find_corners(*change(canonical, faces, boundary))


def test_find_corners_bad_parameters():
    canonical, faces, boundary, _ = rectangle(6, 4)
    with pytest.raises(ValueError, match=r"max_angle_rad in \(0, pi\), got 4"):
        find_corners(canonical, faces, boundary, max_angle_rad=4.0)
    with pytest.raises(ValueError, match=r"window_spacings > 0, got 0"):
        find_corners(canonical, faces, boundary, window_spacings=0.0)


# --------------------------------------------------------------------------- plan_grasps


@pytest.mark.parametrize("kind", ["corner", "boundary", "highest"])
def test_plan_grasps_smoke_and_cardinality(kind):
    canonical, faces, boundary, _ = rectangle()
    result = plan_grasps(estimate(canonical, faces, boundary), GraspPlannerConfig(kind=kind))
    assert isinstance(result, GraspResult) and result and result.reason == ""
    assert len(result.plans) == len(result.terms) == {"corner": 4, "highest": 1}.get(kind, len(result.plans))
    assert all(isinstance(p, GraspPlan) and p.kind == kind for p in result.plans)
    assert all(isinstance(t, GraspTerms) and t.visibility is None for t in result.terms)
    scores = [p.score for p in result.plans]
    assert scores == sorted(scores, reverse=True)
    assert all(0.0 <= s <= 1.0 for s in scores)


def test_boundary_candidates_are_evenly_spaced_along_the_outline():
    canonical, faces, boundary, _ = rectangle()
    config = GraspPlannerConfig(kind="boundary", boundary_spacing_m=0.06)
    result = plan_grasps(estimate(canonical, faces, boundary), config)
    ids = np.array([p.vertex_id for p in result.plans])
    assert set(ids) <= set(boundary)
    W, H = canonical[:, 0].max(), canonical[:, 1].max()
    # Position of each sample along the rectangle's perimeter, counter-clockwise from (0, 0).
    x, y = canonical[ids, 0], canonical[ids, 1]
    edge = np.argmin(np.stack([y, W - x, H - y, x]), axis=0)
    along = np.choose(edge, [x, W + y, W + H + (W - x), 2 * W + H + (H - y)])
    gaps = np.diff(np.sort(np.concatenate([along, [np.min(along) + 2 * (W + H)]])))
    assert len(ids) == pytest.approx(2 * (W + H) / 0.06, abs=2)
    assert np.all(np.abs(gaps - 0.06) < 1.5 * S)


def test_corners_follow_a_rigid_motion_exactly():
    canonical, faces, boundary, ids = rectangle()
    before = estimate(canonical, faces, boundary)
    R = Rotation.from_rotvec([0.3, -0.4, 0.8]).as_matrix()
    centre = before.vertices.mean(axis=0)
    t = np.array([0.05, -0.02, 0.2])
    after = estimate(canonical, faces, boundary, vertices=(before.vertices - centre) @ R.T + centre + t)
    planner = GraspPlanner(GraspPlannerConfig(kind="corner"))
    first, second = planner.plan(before), planner.plan(after)
    assert sorted(p.vertex_id for p in second.plans) == sorted(ids)
    moved = {p.vertex_id: p for p in second.plans}
    for p in first.plans:
        q = moved[p.vertex_id]
        np.testing.assert_allclose(q.position, R @ (p.position - centre) + centre + t, atol=1e-12)
        np.testing.assert_allclose(q.approach, R @ p.approach, atol=1e-12)
        np.testing.assert_allclose(quat_to_matrix(q.quat_xyzw), R @ quat_to_matrix(p.quat_xyzw), atol=1e-12)
        assert q.score == pytest.approx(p.score)


def test_highest_point_of_a_tilted_plane():
    canonical, faces, boundary, ids = rectangle()
    # Plane through (0, 0, 1) spanned by orthonormal e1, e2: vertex = x e1 + y e2.
    e1 = np.array([1.0, -0.4, 0.3]) / np.linalg.norm([1.0, -0.4, 0.3])
    e2 = np.cross([0.2, 0.1, -1.0], e1)
    e2 /= np.linalg.norm(e2)
    vertices = canonical[:, :1] * e1 + canonical[:, 1:2] * e2 + [0.0, 0.0, 1.0]
    tilted = estimate(canonical, faces, boundary, vertices=vertices)
    assert e1 @ [0, -1, 0] > 0 and e2 @ [0, -1, 0] > 0  # image-up grows with x and y
    camera_up = GraspPlannerConfig(kind="highest")
    np.testing.assert_allclose(camera_up.up_cam, [0.0, -1.0, 0.0])
    result = plan_grasps(tilted, camera_up)
    assert [p.vertex_id for p in result.plans] == [ids[2]]  # corner (W, H)
    np.testing.assert_allclose(result.plans[0].position, vertices[ids[2]])
    # A world frame whose up is e1 - 2 e2 in the camera frame: the highest corner is (W, 0).
    up_cam = (e1 - 2 * e2) / np.linalg.norm(e1 - 2 * e2)
    R_world_cam = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up_cam])[0].as_matrix()
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = R_world_cam
    T_world_cam[:3, 3] = [0.3, -0.1, 0.8]
    config = GraspPlannerConfig(kind="highest", T_world_cam=T_world_cam)  # up_world defaults to +z
    np.testing.assert_allclose(config.up_world, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(config.up_cam, up_cam, atol=1e-12)
    assert [p.vertex_id for p in plan_grasps(tilted, config).plans] == [ids[1]]


def test_highest_point_is_the_highest_reachable_one():
    canonical, faces, boundary, ids = rectangle()
    flat = estimate(canonical, faces, boundary)
    top_y = flat.vertices[:, 1].min()  # image up is -y
    config = GraspPlannerConfig(kind="highest", workspace_min_world=[-1, top_y + 0.05, 0], workspace_max_world=[1, 1, 2])
    result = plan_grasps(flat, config)
    assert flat.vertices[result.plans[0].vertex_id, 1] == pytest.approx(top_y + 3 * ROW)  # first row at or past 5 cm
    assert result.rejected["outside workspace"] == int(np.sum(flat.vertices[:, 1] < top_y + 0.05))


def folded(canonical, faces, boundary, gap_m=0.02):
    """Flat rectangle at z = 1 with its right half folded over the left half, ``gap_m`` in front."""
    flat = estimate(canonical, faces, boundary)
    vertices = flat.vertices.copy()
    mid = 0.5 * (canonical[:, 0].min() + canonical[:, 0].max())
    right = canonical[:, 0] > mid + 1e-9
    x_mid = vertices[:, 0].min() + (mid - canonical[:, 0].min())
    vertices[right, 0] = 2 * x_mid - vertices[right, 0]
    vertices[right, 2] -= gap_m
    return flat, estimate(canonical, faces, boundary, vertices=vertices)


def test_corner_under_a_fold_scores_lower():
    canonical, faces, boundary, ids = rectangle()
    flat, fold = folded(canonical, faces, boundary)
    x0, y0 = flat.vertices[:, :2].min(axis=0)
    x1, y1 = flat.vertices[:, :2].max(axis=0)
    flat_frame = frame_of_boxes([(x0, x1, y0, y1, 1.0)])
    xm = 0.5 * (x0 + x1)
    fold_frame = frame_of_boxes([(x0, xm, y0, y1, 1.0), (x0, xm, y0, y1, 0.98)])
    planner = GraspPlanner()
    before = planner.plan(flat, flat_frame)
    after = planner.plan(fold, fold_frame)
    terms_before = {p.vertex_id: t for p, t in zip(before.plans, before.terms)}
    terms_after = {p.vertex_id: t for p, t in zip(after.plans, after.terms)}
    score_before = {p.vertex_id: p.score for p in before.plans}
    score_after = {p.vertex_id: p.score for p in after.plans}
    hidden, on_top = ids[[0, 3]], ids[[1, 2]]  # left corners lie under the folded right corners
    assert all(terms_before[v].visibility == 1.0 and terms_before[v].clearance == 1.0 for v in ids)
    for v in hidden:
        assert terms_after[v].visibility == 0.0
        assert terms_after[v].clearance < 1.0
        assert terms_after[v].nearest_layer_m == pytest.approx(0.02)
        assert score_after[v] < score_before[v]
    for v in on_top:
        assert terms_after[v].visibility == 1.0
    assert {p.vertex_id for p in after.plans[:2]} == set(on_top)
    # Without depth data the other layer still shows as lost clearance.
    no_frame = plan_grasps(fold, GraspPlannerConfig())
    assert all(t.clearance == pytest.approx(0.4) for t in no_frame.terms)  # 2 cm of a 5 cm radius


def test_min_score_drops_hidden_corners():
    canonical, faces, boundary, ids = rectangle()
    flat, fold = folded(canonical, faces, boundary)
    x0, y0 = flat.vertices[:, :2].min(axis=0)
    x1, y1 = flat.vertices[:, :2].max(axis=0)
    frame = frame_of_boxes([(x0, 0.5 * (x0 + x1), y0, y1, 0.98)])
    # Camera-facing layers: no surface beyond the outline to measure layers against.
    result = plan_grasps(fold, GraspPlannerConfig(min_score=0.5, weight_single_layer=0.0), frame)
    assert sorted(p.vertex_id for p in result.plans) == sorted(ids[[1, 2]])
    assert result.rejected == {"below min_score": 2}


def test_vertex_outside_the_image_is_not_visible():
    canonical, faces, boundary, ids = rectangle()
    far_right = estimate(canonical, faces, boundary, vertices=canonical - canonical.mean(axis=0) + [0.55, 0.0, 1.0])
    frame = frame_of_boxes([(0.35, 0.75, -0.15, 0.15, 1.0)])
    result = plan_grasps(far_right, GraspPlannerConfig(), frame)
    visibility = {p.vertex_id: t.visibility for p, t in zip(result.plans, result.terms)}
    assert visibility[ids[0]] == 1.0 and visibility[ids[3]] == 1.0  # x = 0.35, in view
    assert visibility[ids[1]] == 0.0 and visibility[ids[2]] == 0.0  # x = 0.75, beyond the image edge


def test_unreachable_corners_are_excluded():
    canonical, faces, boundary, ids = rectangle()
    flat = estimate(canonical, faces, boundary)
    x0, y0, _ = flat.vertices[ids[0]]  # the (0, 0) corner has the smallest x and y
    config = GraspPlannerConfig(workspace_min_world=[x0 + 0.05, -1.0, 0.0], workspace_max_world=[1.0, 1.0, 2.0])
    result = plan_grasps(flat, config)
    assert sorted(p.vertex_id for p in result.plans) == sorted(ids[[1, 2]])  # x = 0 side is out
    assert result.rejected == {"outside workspace": 2}
    # A z-up world frame (x_world = x_cam, y_world = z_cam, z_world = -y_cam) with a low ceiling.
    T_world_cam = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0.5], [0, 0, 0, 1]])
    config = GraspPlannerConfig(
        T_world_cam=T_world_cam, workspace_min_world=[-1.0, -1.0, -1.0], workspace_max_world=[1.0, 2.0, 0.5 - y0 - 0.05]
    )
    result = plan_grasps(flat, config)
    assert sorted(p.vertex_id for p in result.plans) == sorted(ids[[2, 3]])  # y = 0 side (highest) is out
    nowhere = GraspPlannerConfig(workspace_min_world=[5.0, 5.0, 5.0], workspace_max_world=[6.0, 6.0, 6.0])
    result = plan_grasps(flat, nowhere)
    assert result.plans == () and not result
    assert result.reason == "all 4 corner candidates rejected: 4 outside workspace"


@pytest.mark.parametrize("kind, edge_approach",
                         [("corner", "pinch"), ("boundary", "pinch"), ("corner", "normal"), ("highest", "pinch")])
def test_gripper_frame_convention(kind, edge_approach):
    canonical, faces, boundary, _ = rectangle()
    tilt = Rotation.from_rotvec([0.2, 0.3, 0.1]).as_matrix()
    flat = estimate(canonical, faces, boundary)
    centre = flat.vertices.mean(axis=0)
    cloth = estimate(canonical, faces, boundary, vertices=(flat.vertices - centre) @ tilt.T + centre)
    normal_to_camera = tilt @ [0.0, 0.0, -1.0]  # the flat cloth's normal toward the camera is -z
    config = GraspPlannerConfig(kind=kind, edge_approach=edge_approach, pinch_inset_m=0.0)
    for plan in plan_grasps(cloth, config).plans:
        R = quat_to_matrix(plan.quat_xyzw)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert np.linalg.norm(plan.approach) == pytest.approx(1.0)
        np.testing.assert_allclose(R[:, 2], plan.approach, atol=1e-12)  # gripper z = approach
        assert plan.quat_xyzw[3] >= 0
        assert plan.opening_width_m == config.opening_width_m
        np.testing.assert_allclose(plan.position, cloth.vertices[plan.vertex_id], atol=1e-12)
        to_centre = centre - plan.position
        if kind == "highest" or edge_approach == "normal":
            np.testing.assert_allclose(plan.approach, -normal_to_camera, atol=1e-9)
        else:
            np.testing.assert_allclose(R[:, 0], normal_to_camera, atol=1e-9)  # fingers close across the cloth
            assert abs(plan.approach @ normal_to_camera) < 1e-9  # in the tangent plane
            assert plan.approach @ to_centre > 0  # from outside the cloth, inward
        if kind != "highest" and edge_approach == "normal":
            assert abs(R[:, 0] @ normal_to_camera) < 1e-9 and R[:, 0] @ to_centre > 0  # across the edge


def test_corner_pinch_approaches_along_the_bisector():
    canonical, faces, boundary, ids = rectangle()
    result = plan_grasps(estimate(canonical, faces, boundary), GraspPlannerConfig(pinch_inset_m=0.01))
    plan = {p.vertex_id: p for p in result.plans}[ids[0]]  # the (0, 0) corner, cloth towards +x +y
    np.testing.assert_allclose(plan.approach, [np.sqrt(0.5), np.sqrt(0.5), 0.0], atol=0.06)
    corner = estimate(canonical, faces, boundary).vertices[ids[0]]
    np.testing.assert_allclose(plan.position, corner + 0.01 * plan.approach, atol=1e-12)


def test_lost_or_unconfident_estimate_gives_no_plans():
    canonical, faces, boundary, _ = rectangle(6, 4)
    lost = plan_grasps(estimate(canonical, faces, boundary, lost=True, seq=7))
    assert lost.plans == () and lost.reason == "estimate lost (seq 7)"
    shaky = plan_grasps(estimate(canonical, faces, boundary, confidence=0.2), GraspPlannerConfig(min_confidence=0.5))
    assert shaky.plans == () and shaky.reason == "estimate confidence 0.2 below min_confidence 0.5"


def test_confidence_scales_the_score():
    canonical, faces, boundary, _ = rectangle(6, 4)
    sure = plan_grasps(estimate(canonical, faces, boundary, confidence=1.0))
    unsure = plan_grasps(estimate(canonical, faces, boundary, confidence=0.4))
    assert sure.plans[0].score == pytest.approx(1.0)
    assert unsure.plans[0].score == pytest.approx((1.0 + 0.4) / 2)  # mean of clearance and confidence


def test_degenerate_or_unreachable_geometry_gives_a_reason():
    canonical, faces, boundary, _ = rectangle(6, 4)
    collapsed = estimate(canonical, faces, boundary, vertices=np.tile([0.0, 0.0, 1.0], (len(canonical), 1)))
    result = plan_grasps(collapsed)
    assert result.plans == () and result.reason == "all 4 corner candidates rejected: 4 degenerate geometry"
    result = plan_grasps(collapsed, GraspPlannerConfig(kind="highest"))
    assert result.reason == "all 1 highest candidates rejected: 1 degenerate geometry"
    nowhere = GraspPlannerConfig(kind="highest", workspace_min_world=[5.0, 5.0, 5.0], workspace_max_world=[6.0, 6.0, 6.0])
    result = plan_grasps(estimate(canonical, faces, boundary), nowhere)
    assert result.reason == "no vertex inside the workspace"
    assert result.rejected == {"outside workspace": len(canonical)}


def test_no_boundary_or_no_corners_gives_a_reason():
    canonical, faces, _, _ = rectangle(6, 4)
    result = plan_grasps(estimate(canonical, faces, np.zeros(0, np.int32)))
    assert result.plans == () and result.reason == "estimate has no boundary vertices"
    assert plan_grasps(estimate(canonical, faces, np.zeros(0, np.int32)), GraspPlannerConfig(kind="highest")).plans
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    disc = hex_mesh(0.15 * np.column_stack([np.cos(t), np.sin(t)]))
    result = plan_grasps(estimate(*disc))
    assert result.plans == () and result.reason.startswith("no corners on the canonical outline")


def test_bad_inputs_raise_one_line_errors():
    canonical, faces, boundary, _ = rectangle(6, 4)
    flat = estimate(canonical, faces, boundary)
    with pytest.raises(ValueError, match="Expected estimate of type MeshEstimate, got ndarray"):
        plan_grasps(flat.vertices)
    with pytest.raises(ValueError, match="Expected frame of type RGBDFrame or None, got ndarray"):
        plan_grasps(flat, None, np.zeros((150, 200), np.float32))
    other = RGBDFrame(rgb=np.zeros((150, 200, 3), np.uint8), depth_m=np.ones((150, 200), np.float32),
                      camera=CameraInfo(width=200, height=150, K=CAMERA.K, frame_id="other_optical_frame"))
    with pytest.raises(ValueError, match="same camera frame, got 'other_optical_frame'"):
        plan_grasps(flat, None, other)
    no_faces = estimate(canonical, faces[:0], boundary)
    with pytest.raises(ValueError, match=r"at least one face, got faces of shape \(0, 3\)"):
        GraspPlanner().plan(no_faces)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"kind": "center"}, "Expected kind in"),
        ({"edge_approach": "scoop"}, "Expected edge_approach in"),
        ({"T_world_cam": np.eye(3)}, r"T_world_cam with shape \(4, 4\), got \(3, 3\)"),
        ({"T_world_cam": np.diag([1.0, 1.0, -1.0, 1.0])}, "determinant"),
        ({"T_world_cam": np.diag([2.0, 1.0, 1.0, 1.0])}, "orthonormal"),
        ({"up_world": [0.0, 0.0, 0.0]}, "up_world to be a non-zero direction"),
        ({"up_world": [0.0, 1.0]}, r"up_world with shape \(3,\), got \(2,\)"),
        ({"workspace_min_world": [1, 0, 0], "workspace_max_world": [0, 1, 1]}, "workspace_min_world <= workspace_max_world"),
        ({"workspace_min_world": [0, 0]}, r"shape \(3,\), got \(2,\) and \(3,\)"),
        ({"clearance_radius_m": 0.0}, "clearance_radius_m > 0, got 0"),
        ({"weight_visibility": -1.0}, "weight_visibility >= 0, got -1"),
        ({"weight_clearance": 0.0, "weight_confidence": 0.0}, "weight_clearance \\+ weight_confidence > 0"),
        ({"min_score": 1.5}, r"min_score in \[0, 1\], got 1.5"),
        ({"visibility_window_px": 1.5}, "visibility_window_px an integer >= 0"),
        ({"neighbour_geodesic_factor": 0.5}, "neighbour_geodesic_factor >= 1"),
        ({"corner_max_angle_rad": np.pi}, r"corner_max_angle_rad in \(0, pi\)"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GraspPlannerConfig(**kwargs)


def test_planner_analyses_each_canonical_mesh_once(monkeypatch):
    calls = []
    build = _planner._build_model

    def counting(estimate, config, with_outline):
        calls.append(len(estimate.canonical))
        return build(estimate, config, with_outline)

    monkeypatch.setattr(_planner, "_build_model", counting)
    canonical, faces, boundary, ids = rectangle()
    planner = GraspPlanner()
    for dz in (0.0, 0.1, 0.2):  # new arrays each time, as decoded messages are
        lifted = estimate(canonical, faces, boundary).vertices + dz
        moved = estimate(canonical.copy(), faces.copy(), boundary.copy(), vertices=lifted)
        assert planner.plan(moved)
        np.testing.assert_array_equal(np.sort(planner.corners(moved)), np.sort(ids))
    assert calls == [len(canonical)]
    other = hex_mesh(TSHIRT)
    assert len(planner.corners(estimate(*other))) == len(TSHIRT_CORNERS)
    assert calls == [len(canonical), len(other[0])]


def test_plans_carry_the_estimate_frame_and_time(caplog):
    canonical, faces, boundary, _ = rectangle(6, 4)
    est = estimate(canonical, faces, boundary, timestamp_s=12.5, frame_id="cam_optical")
    with caplog.at_level(logging.DEBUG, logger="grasping"):
        result = plan_grasps(est)
    assert all(p.frame_id == "cam_optical" and p.timestamp_s == 12.5 for p in result.plans)
    assert any("corner grasp(s)" in r.getMessage() for r in caplog.records)


def test_equal_scores_put_the_sharpest_corners_first():
    # Flat and unoccluded: every corner scores the same; the hem (90 deg) and sleeve ends
    # (91-94 deg) must come before the neck corners (106 deg), whatever their vertex ids:
    # upside down, the neck corners have the lowest ids.
    upside_down = (TSHIRT * [1.0, -1.0])[::-1]  # still counter-clockwise
    canonical, faces, boundary = hex_mesh(upside_down)
    result = plan_grasps(estimate(canonical, faces, boundary), GraspPlannerConfig(kind="corner"))
    assert len({p.score for p in result.plans}) == 1 and len(result.plans) == len(TSHIRT_CORNERS)
    which, _ = nearest_polygon_vertex(canonical[[p.vertex_id for p in result.plans], :2], upside_down)
    which = len(TSHIRT) - 1 - which  # index in TSHIRT
    assert set(which[:6]) == {0, 2, 3, 9, 10, 12} and set(which[6:]) == {5, 7}


# --------------------------------------------------------------------------- layers at the outline

TABLE_CAMERA = CameraInfo(width=640, height=480, K=np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]]))


def table_view(elevation_deg=60.0, distance_m=1.1):
    """T_world_cam of a camera looking down at the world origin (z up) from the -y side."""
    e = np.radians(elevation_deg)
    return look_at(distance_m * np.array([0.0, -np.cos(e), np.sin(e)]), np.zeros(3))


def frame_of_layers(T_world_cam, slabs):
    """RGBDFrame of a table (z = 0) under flat slabs: slabs = [(x0, x1, y0, y1, top_z), ...], world metres.

    Each pixel's ray stops at the highest slab top it crosses inside that slab, else at
    the table; the slabs' sides are not drawn (they are a few millimetres high).
    """
    v, u = np.mgrid[0 : TABLE_CAMERA.height, 0 : TABLE_CAMERA.width]
    rays_cam = np.stack([(u - TABLE_CAMERA.cx) / TABLE_CAMERA.fx, (v - TABLE_CAMERA.cy) / TABLE_CAMERA.fy,
                         np.ones(u.shape)], axis=-1)
    R, eye = T_world_cam[:3, :3], T_world_cam[:3, 3]
    rays = rays_cam @ R.T  # world direction per unit of camera depth
    depth = -eye[2] / rays[..., 2]  # the table
    for x0, x1, y0, y1, top in sorted(slabs, key=lambda s: s[4]):  # highest last, overwrites
        t = (top - eye[2]) / rays[..., 2]
        x, y = eye[0] + t * rays[..., 0], eye[1] + t * rays[..., 1]
        depth = np.where((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1), t, depth)
    return RGBDFrame(rgb=np.zeros((TABLE_CAMERA.height, TABLE_CAMERA.width, 3), np.uint8),
                     depth_m=depth.astype(np.float32), camera=TABLE_CAMERA)


def cloth_on_table(T_world_cam, top_z, half=(0.2, 0.15)):
    """MeshEstimate of a rectangle lying on the table at ``top_z`` (canonical = flat world xy), camera frame."""
    W, H = 2 * half[0], 2 * half[1]
    canonical, faces, boundary = hex_mesh(np.array([[0, 0], [W, 0], [W, H], [0, H]]), spacing=0.02)
    world = canonical - [half[0], half[1], 0.0] + [0.0, 0.0, top_z]
    vertices = transform_points(invert_transform(T_world_cam), world)
    return estimate(canonical, faces, boundary, vertices=vertices), world


@pytest.mark.parametrize("elevation_deg", [50.0, 70.0])
def test_step_above_beyond_measures_one_and_two_layers(elevation_deg):
    from grasping._layers import step_above_beyond

    T = table_view(elevation_deg)
    layer = 0.006
    # right part folded over: two layers from x = 0.05 to the crease at x = 0.2
    frame = frame_of_layers(T, [(-0.2, 0.2, -0.15, 0.15, layer), (0.05, 0.2, -0.15, 0.15, 2 * layer)])
    corners_world = np.array([[-0.2, -0.15, layer], [-0.2, 0.15, layer], [0.2, -0.15, 2 * layer], [0.2, 0.15, 2 * layer]])
    outward_world = corners_world * [1.0, 1.0, 0.0]
    outward_world /= np.linalg.norm(outward_world, axis=1, keepdims=True)
    points = transform_points(invert_transform(T), corners_world)
    outward, up = outward_world @ T[:3, :3], T[:3, :3].T @ [0.0, 0.0, 1.0]  # to the camera frame
    steps = step_above_beyond(points, outward, up, frame)
    np.testing.assert_allclose(steps, [layer, layer, 2 * layer, 2 * layer], atol=0.001)
    # A point beyond the image, or a frame without depth there, is not measured.
    outside = step_above_beyond(points[:1] + [5.0, 0.0, 0.0], outward[:1], up, frame)
    no_depth = RGBDFrame(rgb=frame.rgb, depth_m=np.zeros_like(frame.depth_m), camera=TABLE_CAMERA)
    unmeasured = step_above_beyond(points, outward, up, no_depth)
    assert np.isnan(outside).all() and np.isnan(unmeasured).all()


def test_corners_at_a_folds_end_rank_after_true_corners():
    # A towel folded along x = 0.2: its outline is a rectangle again, two of whose corners
    # are the fold's ends, where two layers lie. Outline geometry scores all four alike.
    T = table_view()
    layer = 0.006
    cloth, world = cloth_on_table(T, layer)
    frame = frame_of_layers(T, [(-0.2, 0.2, -0.15, 0.15, layer), (0.05, 0.2, -0.15, 0.15, 2 * layer)])
    on_fold = world[:, 0] > 0.05 + 1e-9
    folded_cloth = MeshEstimate(vertices=cloth.vertices + np.outer(on_fold, T[:3, :3].T @ [0, 0, layer]),
                                faces=cloth.faces, boundary=cloth.boundary, canonical=cloth.canonical)
    config = GraspPlannerConfig(kind="corner", T_world_cam=T, layer_thickness_m=0.008)
    result = plan_grasps(folded_cloth, config, frame)
    assert len(result.plans) == 4
    x_of = {p.vertex_id: world[p.vertex_id, 0] for p in result.plans}
    terms = {p.vertex_id: t for p, t in zip(result.plans, result.terms)}
    assert [x_of[p.vertex_id] < 0 for p in result.plans] == [True, True, False, False]
    for p in result.plans:
        t = terms[p.vertex_id]
        if x_of[p.vertex_id] < 0:
            assert t.single_layer == 1.0 and t.step_m == pytest.approx(layer, abs=0.001)
        else:
            assert t.single_layer < 0.6 and t.step_m == pytest.approx(2 * layer, abs=0.001)
    # Turned off, the four corners tie again.
    flat_scores = plan_grasps(folded_cloth, GraspPlannerConfig(kind="corner", T_world_cam=T, weight_single_layer=0.0),
                              frame)
    assert len({round(p.score, 9) for p in flat_scores.plans}) == 1


def test_a_corner_far_above_the_surface_beyond_is_not_judged():
    # A cloth on a box 10 cm above the table: the surface beyond its outline is the table,
    # too far below for a layer; the term says nothing rather than calling it a fold.
    T = table_view()
    cloth, _ = cloth_on_table(T, 0.10)
    frame = frame_of_layers(T, [(-0.2, 0.2, -0.15, 0.15, 0.10)])
    result = plan_grasps(cloth, GraspPlannerConfig(kind="corner", T_world_cam=T), frame)
    assert len(result.terms) == 4
    assert all(t.single_layer == 1.0 and t.step_m == pytest.approx(0.10, abs=0.005) for t in result.terms)


@pytest.mark.parametrize("change, match", [
    (dict(window_px=2.5), "window_px: expected an integer >= 0, got 2.5"),
    (dict(window_px=-1), "window_px: expected an integer >= 0, got -1"),
    (dict(tol_m=float("nan")), "tol_m: expected a non-negative number"),
    (dict(depth_m=np.ones((4, 5, 1), np.float32)), r"depth_m: expected \(H, W\) metres, got shape \(4, 5, 1\)"),
    (dict(uv=np.zeros((1, 2))), r"points_cam and uv: expected \(K, 3\) and \(K, 2\), got \(2, 3\) and \(1, 2\)"),
])
def test_depth_agrees_names_a_bad_argument(change, match):
    from grasping import depth_agrees

    args = dict(points_cam=np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]), depth_m=np.ones((4, 5), np.float32),
                uv=np.array([[2.0, 2.0], [2.0, 2.0]]), tol_m=0.01, window_px=1)
    assert depth_agrees(**args).tolist() == [True, False]  # the point at the measured 1 m, not the one behind
    with pytest.raises(ValueError, match=match):
        depth_agrees(**{**args, **change})
