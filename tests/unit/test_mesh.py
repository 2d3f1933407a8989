import numpy as np
import pytest

from perception.geometry import boundary_chains, unique_edges
from perception.mesh import (
    barycentric_2d,
    barycentric_matrix,
    lattice_to_xy,
    locate_in_faces,
    mesh_from_lattice,
    rectangle_mesh,
)
from perception.raster import faces_mask, locate_pixels, shrink


def test_rectangle_mesh_is_equilateral_and_inside():
    m = rectangle_mesh(0.6, 0.45, 0.03)
    xy = m.material_xy
    e = unique_edges(m.faces)
    lengths = np.linalg.norm(xy[e[:, 0]] - xy[e[:, 1]], axis=1)
    np.testing.assert_allclose(lengths, 0.03, rtol=1e-12)
    assert xy[:, 0].min() >= -1e-12 and xy[:, 0].max() <= 0.6 + 1e-12
    assert xy[:, 1].min() >= -1e-12 and xy[:, 1].max() <= 0.45 + 1e-12
    # a few hundred vertices for a 60 cm cloth at the default spacing
    assert 250 < m.n_vertices < 500


def test_boundary_is_vertices_with_fewer_than_six_neighbours():
    m = rectangle_mesh(0.3, 0.3, 0.03)
    degree = np.bincount(unique_edges(m.faces).ravel(), minlength=m.n_vertices)
    assert set(m.boundary) == set(np.flatnonzero(degree < 6))
    interior = np.setdiff1d(np.arange(m.n_vertices), m.boundary)
    assert len(interior) > 0 and np.all(degree[interior] == 6)
    xy = m.material_xy
    # boundary vertices lie on the outline: within one spacing of the rectangle's sides
    d = np.minimum.reduce([xy[m.boundary, 0], 0.3 - xy[m.boundary, 0], xy[m.boundary, 1], 0.3 - xy[m.boundary, 1]])
    assert d.max() < 0.03


def test_triplets_collinear_equidistant_and_about_3n():
    m = rectangle_mesh(0.6, 0.45, 0.02)
    xy = m.material_xy
    i, j, k = m.triplets.T
    np.testing.assert_allclose(xy[i] - xy[j], xy[j] - xy[k], atol=1e-12)
    n = m.n_vertices
    assert 2.4 * n < len(m.triplets) <= 3 * n  # n_col ~ 3n, fewer at the boundary
    assert m.k_col().shape == (len(m.triplets), n)


def test_flat_mesh_has_zero_smoothness_energy_and_bent_mesh_does_not():
    m = rectangle_mesh(0.4, 0.3, 0.03)
    K = m.stiffness()
    V = m.canonical
    assert abs(float(np.sum(V * (K @ V)))) < 1e-12
    # any affine map of the flat mesh is still free of energy (second differences vanish)
    A = np.array([[0.9, 0.2, 0.1], [-0.1, 1.1, 0.3], [0.2, 0.0, 1.0]])
    Va = V @ A.T + [0.1, -0.2, 1.3]
    assert abs(float(np.sum(Va * (K @ Va)))) < 1e-12
    Vb = V.copy()
    Vb[:, 2] = 2.0 * (V[:, 0] - 0.2) ** 2
    assert float(np.sum(Vb * (K @ Vb))) > 1e-6


def test_barycentric_round_trip():
    rng = np.random.default_rng(3)
    tri = rng.normal(size=(50, 3, 2))
    w = rng.dirichlet([1, 1, 1], size=50)
    p = np.einsum("pk,pkj->pj", w, tri)
    np.testing.assert_allclose(barycentric_2d(p, tri), w, atol=1e-9)
    # and through the deformed mesh (paper eq. 12): the same weights reproduce the point
    m = rectangle_mesh(0.3, 0.2, 0.05)
    xy = m.material_xy
    fid = rng.integers(0, len(m.faces), 20)
    w = rng.dirichlet([1, 1, 1], size=20)
    pts = np.einsum("pk,pkj->pj", w, xy[m.faces[fid]])
    found, bary = locate_in_faces(pts, xy, m.faces)
    B = barycentric_matrix(found, bary, m.faces, m.n_vertices)
    np.testing.assert_allclose(B @ xy, pts, atol=1e-12)
    V = np.column_stack([xy, np.sin(xy[:, 0])])  # deform: B V equals the deformed triangles' points
    np.testing.assert_allclose(B @ V, np.einsum("pk,pkj->pj", bary, V[m.faces[found]]), atol=1e-12)


def test_locate_pixels_agrees_with_exact_location():
    m = rectangle_mesh(0.3, 0.2, 0.03)
    uv = m.material_xy * 1000 + 20  # pixels
    rng = np.random.default_rng(0)
    fid = rng.integers(0, len(m.faces), 100)
    w = rng.dirichlet([4, 4, 4], size=100)  # away from edges, where pixel rounding decides
    pts = np.einsum("pk,pkj->pj", w, uv[m.faces[fid]])
    found, bary = locate_pixels(pts, uv, m.faces, np.ones(m.n_vertices), (260, 360))
    assert np.mean(found == fid) > 0.9
    np.testing.assert_allclose(np.einsum("pk,pkj->pj", bary, uv[m.faces[found]]), pts, atol=1e-9)


def test_bad_inputs():
    with pytest.raises(ValueError, match="spacing_m must be a positive"):
        rectangle_mesh(0.3, 0.3, 0.0)
    with pytest.raises(ValueError, match="width_m"):
        rectangle_mesh(float("nan"), 0.3, 0.03)
    with pytest.raises(ValueError, match="no triangle fits"):
        mesh_from_lattice(np.array([[0, 0], [5, 5]]), 0.03)
    with pytest.raises(ValueError, match=r"expected shape \(N, 2\)"):
        mesh_from_lattice(np.zeros((3, 3)), 0.03)


def test_largest_piece_kept():
    lat = np.array([[q, r] for q in range(4) for r in range(3)] + [[q + 10, r] for q in range(2) for r in range(2)])
    m = mesh_from_lattice(lat, 0.1)
    assert m.n_vertices == 12
    np.testing.assert_allclose(lattice_to_xy(m.lattice, 0.1), m.material_xy)


def test_every_triangle_between_kept_vertices_is_built():
    """A triangle exists exactly when its three lattice corners are kept, whatever else is missing."""
    rng = np.random.default_rng(4)
    full = np.array([[q, r] for q in range(8) for r in range(6)])
    keep = full[rng.random(len(full)) < 0.8]
    m = mesh_from_lattice(keep, 0.1)
    kept = {tuple(x) for x in m.lattice}
    expected = 0
    for q, r in kept:
        expected += {(q + 1, r), (q, r + 1)} <= kept  # up triangle from its lowest corner
        expected += {(q, r + 1), (q - 1, r + 1)} <= kept  # down triangle from its lowest corner
    assert len(m.faces) == expected
    xy = m.material_xy
    a, b, c = (xy[m.faces[:, i]] for i in range(3))
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    assert np.all(cross > 0)  # all counter-clockwise in the material frame


def test_shrink_averages_whole_blocks_and_repeats_the_far_edge():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (7, 9, 3)).astype(np.float32)
    out = shrink(img, 2)
    assert out.shape == (4, 5, 3)
    # an inner block is the mean of its four pixels
    assert np.allclose(out[1, 2], img[2:4, 4:6].reshape(-1, 3).mean(axis=0))
    # the last column's blocks hold the image's last column twice, the corner block its last pixel four times
    assert np.allclose(out[0, 4], img[0:2, 8].mean(axis=0))
    assert np.allclose(out[3, 4], img[6, 8])
    grey = rng.integers(0, 256, (6, 6)).astype(np.uint8)
    assert shrink(grey, 3).shape == (2, 2) and shrink(grey, 1) is grey
    with pytest.raises(ValueError, match="factor"):
        shrink(grey, 0)


def test_a_mesh_drawn_by_its_outline_covers_the_pixels_its_triangles_do():
    mesh = rectangle_mesh(0.3, 0.2, 0.02)
    keep = np.linalg.norm(mesh.material_xy - [0.15, 0.1], axis=1) > 0.05  # a hole in the middle
    faces = mesh.faces[np.all(keep[mesh.faces], axis=1)]
    outline = boundary_chains(faces)
    assert len(outline) == 2
    rng = np.random.default_rng(5)
    for _ in range(5):
        angle = rng.uniform(0, np.pi)
        R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        uv = (mesh.material_xy - [0.15, 0.1]) @ R.T * rng.uniform(600, 1100) + [320, 240] + rng.uniform(-40, 40, 2)
        drawn = faces_mask(uv, faces, (480, 640), outline)
        assert np.array_equal(drawn, faces_mask(uv, faces, (480, 640)))
        assert not drawn[tuple(np.rint(uv[~keep].mean(axis=0)[::-1]).astype(int))]  # the hole stays open
    # a fold: part of the mesh turned over onto the rest; drawn by its triangles, not cut out by even-odd
    folded = mesh.material_xy.copy()
    folded[folded[:, 0] > 0.2, 0] = 0.4 - folded[folded[:, 0] > 0.2, 0]
    uv = folded * 1000 + 100
    assert np.array_equal(faces_mask(uv, faces, (480, 640), outline), faces_mask(uv, faces, (480, 640)))
