"""Mesh topology and per-face geometry (perception.geometry), on meshes whose answer is known."""

import numpy as np
import pytest

from perception.geometry import (
    boundary_edges,
    boundary_half_edges,
    boundary_vertices,
    directed_edges,
    face_areas,
    face_normals,
    unique_edges,
    vertex_normals,
)

# two counter-clockwise triangles (seen from +z) sharing the edge 1-2: a unit square 0 1 3 2
SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
FACES = np.array([[0, 1, 2], [2, 1, 3]])


def test_edges_of_two_triangles():
    assert directed_edges(FACES).tolist() == [[0, 1], [2, 1], [1, 2], [1, 3], [2, 0], [3, 2]]
    assert unique_edges(FACES).tolist() == [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]
    assert unique_edges(FACES).dtype == np.int64
    assert boundary_edges(FACES).tolist() == [[0, 1], [0, 2], [1, 3], [2, 3]]
    assert boundary_vertices(FACES).tolist() == [0, 1, 2, 3]


def test_boundary_half_edges_keep_the_winding():
    half = boundary_half_edges(FACES)
    # the shared edge 1-2 is used twice and left out; the outline runs counter-clockwise
    assert half.tolist() == [[0, 1], [1, 3], [2, 0], [3, 2]]
    assert boundary_half_edges(np.zeros((0, 3), np.int64)).shape == (0, 2)


def test_an_interior_vertex_is_not_on_the_boundary():
    # a fan of six triangles around vertex 0
    faces = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    assert boundary_vertices(faces).tolist() == [1, 2, 3, 4, 5, 6]
    assert len(boundary_edges(faces)) == 6 and len(unique_edges(faces)) == 12


def test_normals_and_areas_of_a_flat_square():
    np.testing.assert_allclose(face_normals(SQUARE, FACES), [[0, 0, 1], [0, 0, 1]])
    np.testing.assert_allclose(face_areas(SQUARE, FACES), [0.5, 0.5])
    unit = vertex_normals(SQUARE, FACES)
    np.testing.assert_allclose(unit, np.tile([0.0, 0.0, 1.0], (4, 1)))
    # not normalised: the sum over a vertex's faces of twice their areas
    np.testing.assert_allclose(vertex_normals(SQUARE, FACES, unit=False)[:, 2], [1.0, 2.0, 2.0, 1.0])
    # a vertex without faces has a zero normal either way
    lonely = np.vstack([SQUARE, [[5.0, 5.0, 5.0]]])
    assert np.all(vertex_normals(lonely, FACES)[4] == 0)


def test_normals_follow_the_winding_and_rotate_with_the_mesh():
    flipped = vertex_normals(SQUARE, FACES[:, [0, 2, 1]])
    np.testing.assert_allclose(flipped, np.tile([0.0, 0.0, -1.0], (4, 1)))
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    np.testing.assert_allclose(vertex_normals(SQUARE @ R.T, FACES), np.tile(R[:, 2], (4, 1)), atol=1e-12)
    with pytest.raises(IndexError):
        face_normals(SQUARE, np.array([[0, 1, 7]]))
