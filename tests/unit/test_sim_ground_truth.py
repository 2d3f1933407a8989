"""Ground-truth accuracy metric (pure NumPy), against known geometry."""

import numpy as np
import pytest

from perception.geometry import face_areas
from sim import _reference
from sim.cloth_mesh import rectangle_cloth
from sim.ground_truth import (
    bind_to_surface,
    closest_point_barycentric,
    error_summary,
    hidden_behind_occluder,
    material_point_tracks,
    occluded_area_ratio,
    surface_points,
    vertex_errors,
)


def _plane(width=0.6, height=0.4, spacing=0.1):
    mesh = rectangle_cloth(width, height, spacing_m=spacing)
    return np.c_[mesh.uv_m, np.zeros(mesh.n_vertices)], mesh.faces


def test_closest_point_matches_reference_in_every_region():
    rng = np.random.default_rng(0)
    for _ in range(300):
        a, b, c = rng.normal(size=(3, 3))
        p = rng.normal(size=3) * 2.0
        w = closest_point_barycentric(p, a, b, c)
        assert np.all(w >= -1e-12) and w.sum() == pytest.approx(1.0)
        expected = _reference.closest_point_on_triangle(p, a, b, c)
        np.testing.assert_allclose(w @ np.array([a, b, c]), expected, atol=1e-9)


def test_closest_point_on_degenerate_triangle_is_on_it():
    a = np.zeros(3)
    b = np.array([1.0, 0.0, 0.0])
    w = closest_point_barycentric(np.array([0.5, 1.0, 0.0]), a, b, b.copy())
    np.testing.assert_allclose(w @ np.array([a, b, b]), [0.5, 0.0, 0.0], atol=1e-12)


def test_bind_points_above_a_plane():
    verts, faces = _plane()
    points = np.array([[0.05, 0.05, 0.01], [0.33, 0.21, -0.02], [0.6, 0.4, 0.0], [0.7, 0.2, 0.0]])
    tri, bary = bind_to_surface(points, verts, faces)
    assert tri.shape == (4,) and bary.shape == (4, 3)
    closest = surface_points(verts, faces, tri, bary)
    np.testing.assert_allclose(closest, [[0.05, 0.05, 0], [0.33, 0.21, 0], [0.6, 0.4, 0], [0.6, 0.2, 0]], atol=1e-12)


def test_bind_matches_brute_force_reference_on_a_bent_sheet():
    verts, faces = _plane(0.3, 0.2, 0.05)
    verts[:, 2] = 0.1 * np.sin(verts[:, 0] * 10)
    points = np.random.default_rng(1).uniform([-0.05, -0.05, -0.1], [0.35, 0.25, 0.2], size=(40, 3))
    tri, bary = bind_to_surface(points, verts, faces)
    np.testing.assert_allclose(surface_points(verts, faces, tri, bary),
                               _reference.bind_to_surface(points, verts, faces), atol=1e-9)


def test_rigid_translation_error_is_the_offset():
    verts, faces = _plane()
    T = 5
    offset = np.array([0.003, -0.004, 0.0])  # 5 mm in the plane
    gt = np.stack([verts + t * offset for t in range(T)])
    rng = np.random.default_rng(2)
    est0 = np.c_[rng.uniform(0.1, 0.5, 30), rng.uniform(0.1, 0.3, 30), np.zeros(30)]
    est = np.repeat(est0[None], T, axis=0)  # the estimate does not move
    errors = vertex_errors(est, gt, faces)
    assert errors.shape == (T, 30)
    np.testing.assert_allclose(errors, np.arange(T)[:, None] * 0.005 * np.ones((1, 30)), atol=1e-12)
    # and an estimate that moves with the cloth has no error, however far it moves
    np.testing.assert_allclose(vertex_errors(gt[:, 3:9], gt, faces), 0.0, atol=1e-12)


def test_error_is_followed_as_a_material_point_not_re_bound():
    verts, faces = _plane()
    lifted = verts + np.array([0.0, 0.0, 0.01])
    est = np.stack([verts[[7]], verts[[7]] + [0.05, 0.0, 0.0]])  # slides 5 cm along the plane
    gt = np.stack([verts, verts])
    # re-binding at frame 1 would give 0; following the material point gives 5 cm
    np.testing.assert_allclose(vertex_errors(est, gt, faces), [[0.0], [0.05]], atol=1e-12)
    np.testing.assert_allclose(vertex_errors(est[:1], lifted[None], faces), [[0.01]], atol=1e-12)


def test_error_summary_in_millimetres():
    errors = np.linspace(0.0, 0.01, 101)  # 0 to 10 mm
    s = error_summary(errors.reshape(1, -1))
    assert s["mean_mm"] == pytest.approx(5.0)
    assert s["p95_mm"] == pytest.approx(9.5)
    assert s["max_mm"] == pytest.approx(10.0)
    assert s["count"] == 101


def test_inputs_are_checked():
    verts, faces = _plane()
    with pytest.raises(ValueError, match=r"points with shape \(N, 3\), got \(2, 2\)"):
        bind_to_surface(np.zeros((2, 2)), verts, faces)
    with pytest.raises(ValueError, match=r"gt_faces with vertex ids in \[0, "):
        bind_to_surface(np.zeros((2, 3)), verts, faces + 1000)
    with pytest.raises(ValueError, match="3 frames, gt_vertices 2"):
        vertex_errors(np.zeros((3, 4, 3)), np.zeros((2, len(verts), 3)), faces)
    with pytest.raises(ValueError, match=r"est_vertices with shape \(T, N, 3\)"):
        vertex_errors(np.zeros((4, 3)), np.zeros((2, len(verts), 3)), faces)
    with pytest.raises(ValueError, match="finite errors"):
        error_summary(np.array([np.nan]))


K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])


def _occluder(depth_m=1.0):
    """An 80x100 image with an occluder over columns 40-59 (every row) at ``depth_m``."""
    mask = np.zeros((80, 100), bool)
    mask[:, 40:60] = True
    return mask, np.where(mask, depth_m, 0.0).astype(np.float32)


def test_points_behind_an_occluder_are_hidden_and_only_those():
    mask, depth = _occluder(1.0)
    # columns: 30 (beside it), 45 and 59 (on it), 60 (just beside it); rows 40
    x = (np.array([30.0, 45.0, 59.0, 60.0]) - 50.0) / 100.0
    behind = np.column_stack([2.0 * x, np.zeros(4), np.full(4, 2.0)])
    np.testing.assert_array_equal(hidden_behind_occluder(behind, mask, depth, K), [False, True, True, False])
    in_front = behind * 0.4  # the same pixels at 0.8 m, nearer than the occluder
    assert not hidden_behind_occluder(in_front, mask, depth, K).any()
    outside = np.array([[5.0, 0.0, 1.5], [0.0, 0.0, -2.0]])  # off the image; behind the camera
    assert not hidden_behind_occluder(outside, mask, depth, K).any()
    assert hidden_behind_occluder(behind, mask, depth, K, margin_m=0.5).sum() == 2
    assert not hidden_behind_occluder(behind, mask, depth, K, margin_m=1.5).any()
    with pytest.raises(ValueError, match="one shape"):
        hidden_behind_occluder(behind, mask, depth[:10], K)


def test_face_areas_of_a_known_triangle():
    v = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0], [0.0, 0.2, 1.5]])
    assert face_areas(v, np.array([[0, 1, 2]]))[0] == pytest.approx(0.5 * 0.3 * np.hypot(0.2, 0.5))


def test_occluded_area_ratio_counts_fully_hidden_faces_only():
    canonical, faces = _plane(0.6, 0.4, 0.1)
    hidden = canonical[:, 0] <= 0.2 + 1e-9  # the left third, columns u = 0, 0.1, 0.2
    squeezed = canonical.copy()
    squeezed[hidden, 0] *= 0.5  # the hidden part squeezed to half its width
    squeezed += [0.1, -0.2, 1.3]  # and the whole mesh moved
    ratio, rest = occluded_area_ratio(squeezed, canonical, faces, hidden)
    assert rest == pytest.approx(0.2 * 0.4) and ratio == pytest.approx(0.5)
    # faces with a visible vertex do not count, even though the squeeze stretched them
    ratio, _ = occluded_area_ratio(squeezed, canonical, faces, canonical[:, 0] <= 0.1 + 1e-9)
    assert ratio == pytest.approx(0.5)
    kept, _ = occluded_area_ratio(canonical @ np.diag([1.0, -1.0, -1.0]), canonical, faces, hidden)
    assert kept == pytest.approx(1.0), "a turned mesh keeps its area"
    ratio, rest = occluded_area_ratio(squeezed, canonical, faces, np.zeros(len(canonical), bool))
    assert np.isnan(ratio) and rest == 0.0
    with pytest.raises(ValueError, match="expected hidden of shape"):
        occluded_area_ratio(squeezed, canonical, faces, hidden[:3])


def test_material_point_tracks_follow_the_points_bound_in_the_first_frame():
    verts, faces = _plane()
    gt = np.stack([verts, verts + [0.0, 0.0, 0.1], verts * [1.5, 1.0, 1.0]])
    first = verts[[0, 5]] + [0.0, 0.0, 0.02]  # 2 cm above two vertices
    tracks = material_point_tracks(first, gt, faces)
    np.testing.assert_allclose(tracks[:, 0], gt[:, 0], atol=1e-12)
    np.testing.assert_allclose(tracks[2, 1], gt[2, 5], atol=1e-12)
