"""The hidden part of a cloth moved with the part seen (perception.hidden_motion)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perception.hidden_motion import MIN_SEEN, carried_prior


def _sheet(nx=21, ny=16, spacing=0.025):
    x, y = np.meshgrid(np.arange(nx) * spacing, np.arange(ny) * spacing)
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


@pytest.mark.parametrize("reach_m", [0.05, 0.2, 1.0])
def test_a_rigid_motion_of_the_part_seen_carries_the_hidden_part_exactly(reach_m):
    """Every vertex seen moved by one turn and shift: whatever the weights, each fit is that
    motion, and the hidden half (its prior where the cloth was) goes where the turn takes it."""
    material = _sheet()
    prior = material + [0.0, 0.0, 1.2]
    motion = Rotation.from_rotvec([0.1, -0.4, 0.2])
    shift = np.array([0.03, -0.01, 0.05])
    moved_truly = motion.apply(prior - prior.mean(axis=0)) + prior.mean(axis=0) + shift
    hidden = material[:, 0] > 0.26
    estimate = np.where(hidden[:, None], prior, moved_truly)  # the solver placed only what it saw
    moved = carried_prior(material, prior, estimate, ~hidden, hidden, reach_m)
    assert moved.shape == prior.shape
    np.testing.assert_allclose(moved, moved_truly, atol=1e-9)


def test_each_hidden_part_moves_as_the_cloth_seen_nearest_it_does():
    """The left third stays, the right third is lifted 10 cm: the hidden middle's left edge
    follows the left (stays), its right edge the right (rises nearly all the way)."""
    material = _sheet(31, 11)
    prior = material + [0.0, 0.0, 1.0]
    x = material[:, 0]
    left, right = x < 0.25, x > 0.5
    estimate = prior + np.where(right[:, None], [0.0, 0.0, -0.1], 0.0)
    hidden = ~left & ~right
    moved = carried_prior(material, prior, estimate, left | right, hidden, reach_m=0.05)
    rise = prior[:, 2] - moved[:, 2]
    assert np.all(np.abs(rise[hidden & (x < 0.27)]) < 0.01)
    assert np.all(rise[hidden & (x > 0.48)] > 0.09)
    np.testing.assert_array_equal(moved[~hidden], estimate[~hidden])  # the rest: the estimate


def test_a_line_of_vertices_seen_shifts_the_hidden_part_but_does_not_turn_it():
    """A single row seen cannot say how the cloth turned about it: only its shift is used."""
    material = _sheet()
    prior = material + [0.0, 0.0, 1.0]
    row = np.isclose(material[:, 1], 0.0)
    noise = np.random.default_rng(0).normal(0.0, 1e-4, prior.shape)
    estimate = prior + [0.02, 0.0, 0.0] + noise * row[:, None]
    moved = carried_prior(material, prior, estimate, row, ~row)
    np.testing.assert_allclose(moved[~row] - prior[~row], np.broadcast_to([0.02, 0.0, 0.0], moved[~row].shape), atol=5e-4)


def test_too_few_vertices_seen_move_nothing():
    material = _sheet()
    prior = material + [0.0, 0.0, 1.0]
    estimate = prior + 0.05
    seen = np.zeros(len(material), bool)
    seen[:MIN_SEEN - 1] = True
    np.testing.assert_array_equal(carried_prior(material, prior, estimate, seen, ~seen), estimate)
    np.testing.assert_array_equal(carried_prior(material, prior, estimate, ~seen, np.zeros_like(seen)), estimate)
