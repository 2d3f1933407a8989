"""Mesh topology and per-face geometry (perception.geometry), on meshes whose answer is known."""

import numpy as np
import pytest

from perception.geometry import (
    boundary_chains,
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


def _grid_faces(n: int, skip=()) -> np.ndarray:
    """Counter-clockwise faces of an n x n grid of squares (vertex id row * (n + 1) + col),
    two triangles a square, leaving out the squares in ``skip`` (row, col)."""
    faces = []
    for r in range(n):
        for c in range(n):
            if (r, c) in skip:
                continue
            a, b, d, e = r * (n + 1) + c, r * (n + 1) + c + 1, (r + 1) * (n + 1) + c, (r + 1) * (n + 1) + c + 1
            faces += [[a, b, d], [d, b, e]]
    return np.array(faces)


def test_boundary_chains_close_the_outline_and_each_hole():
    (loop,) = boundary_chains(FACES)
    start = int(np.flatnonzero(loop == 0)[0])
    assert np.roll(loop, -start).tolist() == [0, 1, 3, 2]  # the faces' winding
    chains = boundary_chains(_grid_faces(3, skip={(1, 1)}))  # a 3 x 3 grid with its middle square out
    assert sorted(len(c) for c in chains) == [4, 12]
    hole = next(c for c in chains if len(c) == 4)
    assert sorted(hole.tolist()) == [5, 6, 9, 10]
    # every outline edge in exactly one chain
    chained = sorted((int(a), int(b)) for c in chains for a, b in zip(c, np.roll(c, -1)))
    assert chained == sorted(map(tuple, boundary_half_edges(_grid_faces(3, skip={(1, 1)})).tolist()))


def test_an_outline_touching_itself_has_no_chains():
    # two squares of a 2 x 2 grid meeting only at the middle vertex
    assert boundary_chains(_grid_faces(2, skip={(0, 1), (1, 0)})) == []
    assert boundary_chains(np.zeros((0, 3), np.int64)) == []


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
