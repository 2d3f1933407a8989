"""Cloth meshes, strain and textures (pure NumPy, no PyBullet)."""

import numpy as np
import pytest

from perception.geometry import boundary_vertices
from sim.cloth_mesh import (
    ClothMesh,
    TShirtShape,
    edge_strain,
    points_in_polygon,
    rectangle_cloth,
    tshirt_cloth,
    write_obj,
)
from sim.textures import plain_texture, poster_texture


def _signed_areas(uv, faces):
    d1 = uv[faces[:, 1]] - uv[faces[:, 0]]
    d2 = uv[faces[:, 2]] - uv[faces[:, 0]]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def test_rectangle_has_exact_size_corners_and_area():
    mesh = rectangle_cloth(0.6, 0.45, spacing_m=0.025)
    assert mesh.uv_m.shape == (25 * 19, 2)
    assert mesh.faces.shape == (24 * 18 * 2, 3)
    assert mesh.size_m == pytest.approx((0.6, 0.45))
    np.testing.assert_allclose(mesh.uv_m[mesh.landmarks["top_left"]], [0.0, 0.0])
    np.testing.assert_allclose(mesh.uv_m[mesh.landmarks["bottom_right"]], [0.6, 0.45])
    areas = _signed_areas(mesh.uv_m, mesh.faces)
    assert np.all(areas < 0), "faces must be counter-clockwise seen from the front (v down)"
    assert -areas.sum() == pytest.approx(0.6 * 0.45)


def test_rectangle_boundary_is_the_outline():
    mesh = rectangle_cloth(0.3, 0.2, spacing_m=0.05)
    b = boundary_vertices(mesh.faces)
    uv = mesh.uv_m[b]
    on_edge = np.isclose(uv[:, 0], 0) | np.isclose(uv[:, 0], 0.3) | np.isclose(uv[:, 1], 0) | np.isclose(uv[:, 1], 0.2)
    assert on_edge.all()
    assert len(b) == 2 * (7 + 5) - 4


def test_tshirt_mesh_follows_its_outline():
    shape = TShirtShape()
    mesh = tshirt_cloth(shape, spacing_m=0.03)
    outline = shape.outline()
    outline = outline - outline.min(axis=0)
    # every triangle lies inside the outline, and the mesh covers its area
    centroids = mesh.uv_m[mesh.faces].mean(axis=1)
    assert points_in_polygon(centroids, outline).all()
    x, y = outline[:, 0], outline[:, 1]
    polygon_area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    mesh_area = -_signed_areas(mesh.uv_m, mesh.faces).sum()
    assert mesh_area == pytest.approx(polygon_area, rel=0.01)
    assert np.all(_signed_areas(mesh.uv_m, mesh.faces) < 0)
    edges = mesh.rest_lengths()
    assert 0.5 * 0.03 < edges.min() and edges.max() < 1.6 * 0.03
    # shoulders are symmetric about the centre line, near the top
    left, right = mesh.uv_m[mesh.landmarks["left_shoulder"]], mesh.uv_m[mesh.landmarks["right_shoulder"]]
    assert left[0] + right[0] == pytest.approx(mesh.size_m[0], abs=0.03)
    assert right[0] - left[0] == pytest.approx(shape.body_width_m, abs=0.03)
    assert left[1] < 0.1 and right[1] < 0.1


@pytest.mark.parametrize("scale", np.linspace(0.6, 0.85, 6))
def test_tshirt_mesh_has_no_slivers_along_its_outline(scale):
    # Delaunay makes zero-area triangles between collinear outline points; they must be gone
    spacing = 0.03
    mesh = tshirt_cloth(TShirtShape().scaled(scale), spacing_m=spacing)
    assert np.abs(_signed_areas(mesh.uv_m, mesh.faces)).min() > 0.1 * spacing**2


def test_tshirt_scaled_keeps_angle():
    shape = TShirtShape().scaled(1.1)
    assert shape.body_width_m == pytest.approx(0.55)
    assert shape.sleeve_angle_rad == TShirtShape().sleeve_angle_rad


def test_points_in_polygon_unit_square():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    pts = np.array([[0.5, 0.5], [1.5, 0.5], [-0.1, 0.2], [0.99, 0.01]])
    assert points_in_polygon(pts, square).tolist() == [True, False, False, True]


def test_edge_strain_known_stretch():
    mesh = rectangle_cloth(0.2, 0.1, spacing_m=0.05)
    flat = np.c_[mesh.uv_m, np.zeros(mesh.n_vertices)]
    np.testing.assert_allclose(edge_strain(flat, mesh.edges(), mesh.rest_lengths()), 0.0, atol=1e-12)
    stretched = flat * np.array([1.1, 1.1, 1.0])
    np.testing.assert_allclose(edge_strain(stretched, mesh.edges(), mesh.rest_lengths()), 0.1, atol=1e-12)
    rotated = flat @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]).T + 3.0
    np.testing.assert_allclose(edge_strain(rotated, mesh.edges(), mesh.rest_lengths()), 0.0, atol=1e-12)


def test_edge_strain_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"vertices of shape \(V, 3\), got \(4, 2\)"):
        edge_strain(np.zeros((4, 2)), np.array([[0, 1]]), np.array([1.0]))
    with pytest.raises(ValueError, match="positive rest lengths"):
        edge_strain(np.zeros((4, 3)), np.array([[0, 1]]), np.array([0.0]))


def test_mesh_checks_inputs():
    with pytest.raises(ValueError, match=r"ClothMesh.uv_m with shape \(N, 2\), got \(3, 3\)"):
        ClothMesh(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match=r"ClothMesh.faces with vertex ids in \[0, 3\)"):
        ClothMesh(np.zeros((3, 2)), np.array([[0, 1, 3]]))
    with pytest.raises(ValueError, match="spacing_m"):
        rectangle_cloth(0.6, 0.45, spacing_m=0.0)
    with pytest.raises(ValueError, match="too coarse"):
        tshirt_cloth(spacing_m=0.3)


def test_layout_points_places_the_flat_cloth():
    mesh = rectangle_cloth(0.4, 0.2, spacing_m=0.1)
    pts = mesh.layout_points([1.0, 2.0, 3.0], right=[1, 0, 0], down=[0, 0, -1])
    np.testing.assert_allclose(pts[mesh.landmarks["top_left"]], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(pts[mesh.landmarks["bottom_right"]], [1.4, 2.0, 2.8])
    with pytest.raises(ValueError, match="orthonormal"):
        mesh.layout_points([0, 0, 0], right=[1, 0, 0], down=[1, 0, 0])


def test_texture_coords_map_top_left_to_image_top_left():
    mesh = rectangle_cloth(0.4, 0.2, spacing_m=0.1)
    tc = mesh.texture_coords()
    np.testing.assert_allclose(tc[mesh.landmarks["top_left"]], [0.0, 1.0])  # OBJ t is up
    np.testing.assert_allclose(tc[mesh.landmarks["bottom_right"]], [1.0, 0.0])


def test_write_obj_keeps_vertex_order(tmp_path):
    mesh = rectangle_cloth(0.2, 0.1, spacing_m=0.05)
    pts = mesh.layout_points([0, 0, 1], [1, 0, 0], [0, 0, -1])
    path = tmp_path / "c.obj"
    write_obj(path, pts, mesh.faces, mesh.texture_coords())
    lines = path.read_text().splitlines()
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    vt = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("vt ")])
    f = [ln.split()[1:] for ln in lines if ln.startswith("f ")]
    np.testing.assert_allclose(v, pts, atol=1e-6)
    np.testing.assert_allclose(vt, mesh.texture_coords(), atol=1e-6)
    assert f[0] == [f"{i + 1}/{i + 1}" for i in mesh.faces[0]]


def test_poster_texture_is_seeded_and_feature_rich():
    cv2 = pytest.importorskip("cv2")
    a = poster_texture(np.random.default_rng(3), 320, 240)
    b = poster_texture(np.random.default_rng(3), 320, 240)
    c = poster_texture(np.random.default_rng(4), 320, 240)
    assert a.shape == (240, 320, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    keypoints = cv2.ORB_create(500).detect(cv2.cvtColor(a, cv2.COLOR_RGB2GRAY), None)
    assert len(keypoints) > 200


def test_plain_texture_is_uniform():
    t = plain_texture((10, 200, 30), 20, 16)
    assert t.shape == (16, 20, 3)
    assert np.all(t == np.array([10, 200, 30], np.uint8))
    with pytest.raises(ValueError, match="3 values in"):
        plain_texture((10, 300, 30))
