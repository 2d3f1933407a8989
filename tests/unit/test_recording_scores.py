"""Scores against a real recording's references (perception.recording_scores), on a flat
mesh in front of the camera whose projection is known."""

import numpy as np

from perception.geometry import backproject, project
from perception.mesh import rectangle_mesh
from perception.raster import faces_mask
from perception.recording_scores import flow_score, mask_coverage, vertices_on_mask

K = np.array([[500.0, 0, 160], [0, 500.0, 120], [0, 0, 1]])
SHAPE = (240, 320)
MESH = rectangle_mesh(0.2, 0.1, 0.02)
V = MESH.canonical + np.array([-0.1, -0.05, 1.0])  # 100 x 50 px, centred, 1 m away


def test_coverage_of_its_own_footprint_and_of_a_larger_mask():
    own = faces_mask(project(V, K), MESH.faces, SHAPE)
    assert mask_coverage(V, MESH.faces, K, own) == 1.0
    double = own | np.roll(own, own.any(axis=0).sum(), axis=1)  # the footprint and its neighbour
    assert abs(mask_coverage(V, MESH.faces, K, double) - 0.5) < 0.02
    assert mask_coverage(V, MESH.faces, K, np.zeros(SHAPE, bool)) == 0.0


def test_vertices_on_mask_with_and_without_tolerance():
    own = faces_mask(project(V, K), MESH.faces, SHAPE)
    assert vertices_on_mask(V, K, own) > 0.95
    away = np.roll(own, 120, axis=1)
    assert vertices_on_mask(V, K, away) == 0.0
    shifted = V + np.array([0.005, 0.0, 0.0])  # 2.5 px right of the mask's edge at most
    edge = faces_mask(project(V, K), MESH.faces, SHAPE)
    assert vertices_on_mask(shifted, K, edge, tolerance_px=3) == 1.0
    assert vertices_on_mask(shifted, K, edge, tolerance_px=0) < 1.0
    behind = V * np.array([1, 1, -1])
    assert vertices_on_mask(behind, K, own, tolerance_px=3) == 0.0


def test_flow_score_of_a_translation():
    depth = np.zeros(SHAPE, np.float32)
    depth[:] = 1.0  # the plane z = 1 m fills the image
    t = np.array([0.03, -0.01, 0.02], np.float32)
    scene = np.broadcast_to(t, SHAPE + (3,)).copy()
    moved = V + t
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1).astype(float)
    surface = backproject(pixels, np.ones(len(pixels)), K)
    oflow = (project(surface + t, K) - pixels).reshape(SHAPE + (2,)).astype(np.float32)
    right = flow_score(V, moved, depth, scene, oflow, K)
    assert right.used == len(V)
    np.testing.assert_allclose(right.error_m, 0.0, atol=1e-6)
    np.testing.assert_allclose(right.zero_motion_m, np.linalg.norm(t), rtol=1e-6)
    assert np.all(right.error_px < 0.05)  # the flow at the nearest pixel differs little
    still = flow_score(V, V, depth, scene, oflow, K)
    np.testing.assert_allclose(still.error_m, np.linalg.norm(t), rtol=1e-6)
    summary = still.summary()
    assert abs(summary["error_mm"]["mean"] - 1000 * np.linalg.norm(t)) < 1e-3


def test_flow_score_skips_vertices_off_the_surface_and_unknown_flow():
    depth = np.full(SHAPE, 1.0, np.float32)
    scene = np.zeros(SHAPE + (3,), np.float32)
    scene[:, :160] = np.nan  # the left half has no ground truth
    off = V.copy()
    off[:5, 2] += 0.1  # ten centimetres behind the measured surface
    score = flow_score(off, off, depth, scene, None, K)
    left = project(V, K)[:, 0] < 159.5
    assert score.used == int((~left).sum() - (~left[:5]).sum())
    assert np.isnan(score.error_px).all()
