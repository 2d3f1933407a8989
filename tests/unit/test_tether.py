"""perception.tether: how far a held cloth's points may be from the points held."""

import numpy as np
import pytest

from perception.tether import Tethers


def strip(n=5, spacing=0.1):
    """A chain of n vertices 10 cm apart along x, and a vertex joined to none of them."""
    edges = np.array([[i, i + 1] for i in range(n - 1)])
    return edges, np.full(n - 1, spacing), n + 1


def test_a_vertex_beyond_its_reach_is_moved_straight_towards_the_held_point_onto_it():
    edges, lengths, n = strip()
    tethers = Tethers(edges, lengths, n, slack=0.0)
    V = np.zeros((n, 3))
    V[:5, 0] = [0.0, 0.1, 0.2, 0.3, 0.4]  # laid straight: every vertex exactly at its reach
    V[4] = [0.0, 0.0, 0.8]  # the end dragged 80 cm away: its reach is 40 cm
    V[5] = [5.0, 0.0, 0.0]  # not joined to the held vertex: no limit
    out = tethers.apply(V, np.array([0]), np.zeros((1, 3)))
    np.testing.assert_allclose(out[4], [0.0, 0.0, 0.4])
    np.testing.assert_allclose(out[:4], V[:4])  # within reach: untouched
    np.testing.assert_allclose(out[5], V[5])
    np.testing.assert_allclose(V[4], [0.0, 0.0, 0.8])  # the input is not changed


def test_slack_and_every_held_point_count():
    edges, lengths, n = strip()
    V = np.zeros((n, 3))
    V[2] = [0.0, 0.5, 0.0]  # 20 cm along the chain from either end vertex held below
    loose = Tethers(edges, lengths, n, slack=0.1)
    np.testing.assert_allclose(np.linalg.norm(loose.apply(V, np.array([0]), np.zeros((1, 3)))[2]), 0.22)
    held = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    both = Tethers(edges, lengths, n, slack=0.0).apply(V, np.array([0, 4]), held)
    assert np.linalg.norm(both[2]) <= 0.2 + 1e-12
    np.testing.assert_allclose(loose.reach(4)[:5], 1.1 * np.array([0.4, 0.3, 0.2, 0.1, 0.0]))


def test_bad_construction_says_what_is_wrong():
    edges, lengths, n = strip()
    with pytest.raises(ValueError, match="4 edges but 3 rest lengths"):
        Tethers(edges, lengths[:3], n, slack=0.05)
    with pytest.raises(ValueError, match="slack: expected a non-negative number"):
        Tethers(edges, lengths, n, slack=-0.1)
