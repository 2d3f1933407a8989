"""perception.tether: how far a held cloth's points may be from the points held."""

import numpy as np
import pytest

from perception.tether import Tethers


def ribbon(n=5, spacing=0.1, width=0.01):
    """A ribbon of triangles: a top row of n vertices ``spacing`` apart along x (ids 0..n-1), a
    bottom row ``width`` below it (ids n..2n-1), and a vertex in no face (id 2n)."""
    top = np.column_stack([spacing * np.arange(n), np.zeros(n), np.zeros(n)])
    rest = np.vstack([top, top + [0.0, width, 0.0], [[9.0, 9.0, 9.0]]])
    faces = np.array([f for i in range(n - 1) for f in ([i, i + 1, n + i], [i + 1, n + i + 1, n + i])])
    return rest, faces


def test_a_vertex_beyond_its_reach_is_moved_straight_towards_the_held_point_onto_it():
    rest, faces = ribbon()
    tethers = Tethers(rest, faces)
    V = rest.copy()  # as laid: every vertex within reach
    V[4] = [0.0, 0.0, 0.8]  # the top row's end dragged 80 cm from the held vertex 0: its reach is 40 cm
    V[10] = [5.0, 0.0, 0.0]  # in no face, joined to nothing: no limit
    out = tethers.apply(V, np.array([0]), rest[[0]], slack=0.0)
    np.testing.assert_allclose(out[4], [0.0, 0.0, 0.4])
    untouched = np.r_[0:4, 5:11]
    np.testing.assert_allclose(out[untouched], V[untouched])
    np.testing.assert_allclose(V[4], [0.0, 0.0, 0.8])  # the input is not changed


def test_slack_and_every_held_point_count():
    rest, faces = ribbon()
    V = rest.copy()
    V[2] = [0.2, 0.5, 0.0]  # the top row's middle, 20 cm along the row from either end
    tethers = Tethers(rest, faces)
    moved = tethers.apply(V, np.array([0]), rest[[0]], slack=0.1)
    np.testing.assert_allclose(np.linalg.norm(moved[2] - rest[0]), 0.22)
    both = tethers.apply(V, np.array([0, 4]), rest[[0, 4]], slack=0.0)
    assert np.linalg.norm(both[2] - rest[4]) <= 0.2 + 1e-12  # the last one held: on its reach
    assert np.linalg.norm(both[2] - rest[0]) < 0.75 * np.linalg.norm(V[2] - rest[0])  # one pass: nearer the first
    np.testing.assert_allclose(tethers.along(4)[:5], [0.4, 0.3, 0.2, 0.1, 0.0])
    assert np.isinf(tethers.along(4)[10])


def test_a_negative_slack_is_refused():
    rest, faces = ribbon()
    with pytest.raises(ValueError, match="slack must be a non-negative number"):
        Tethers(rest, faces).apply(rest, np.array([0]), rest[[0]], slack=-0.1)
