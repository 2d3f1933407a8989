"""Depth and colour noise model (pure NumPy), on depth images of known geometry."""

import numpy as np
import pytest

from sim.noise import (
    DepthNoiseModel,
    add_colour_noise,
    add_depth_noise,
    incidence_angles,
    standard_normal_fast,
)

W, H, F = 160, 120, 130.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
U = (np.arange(W) - K[0, 2]) / F
V = (np.arange(H) - K[1, 2]) / F


def _wall(z):
    return np.full((H, W), z, np.float32)


def _tilted_wall(z0, angle_rad):
    """A plane through (0, 0, z0) turned about the camera's y axis: z = z0 + tan(a) x."""
    return np.broadcast_to(z0 / (1 - np.tan(angle_rad) * U[None, :]), (H, W)).astype(np.float32).copy()


def _quiet(**kw):
    """A model with only the effects a test names switched on."""
    base = {"sigma_base_m": 0.0, "sigma_quad_m": 0.0, "disparity_step_px": 1e-6, "shadow_px": 0,
            "grazing_start_rad": np.pi, "grazing_stop_rad": np.pi + 1, "dropout_prob": 0.0}
    base.update(kw)
    return DepthNoiseModel(**base)


def test_incidence_angle_of_tilted_planes():
    for deg in (0.0, 30.0, 60.0):
        angles = incidence_angles(_tilted_wall(1.5, np.radians(deg)), K)
        n = np.array([-np.tan(np.radians(deg)), 0.0, 1.0])
        n /= np.linalg.norm(n)
        for row, col in ((60, 80), (10, 20), (100, 110)):
            ray = np.array([U[col], V[row], 1.0])
            expected = np.degrees(np.arccos(abs(n @ ray) / np.linalg.norm(ray)))
            assert np.degrees(angles[row, col]) == pytest.approx(expected, abs=0.1)


def test_axial_noise_grows_with_distance_squared():
    model = _quiet(sigma_base_m=0.0012, sigma_quad_m=0.0019)
    rng = np.random.default_rng(0)
    for z in (1.0, 2.0, 3.0):
        noisy = add_depth_noise(_wall(z), K, model, rng)
        expected = 0.0012 + 0.0019 * (z - 0.4) ** 2
        assert noisy.mean() == pytest.approx(z, abs=3 * expected / np.sqrt(noisy.size) + 1e-6)
        assert noisy.std() == pytest.approx(expected, rel=0.03)


def test_quantisation_steps_grow_with_distance_squared():
    model = _quiet(disparity_step_px=0.125, baseline_m=0.075)
    for z in (1.0, 2.0):
        ramp = np.broadcast_to(np.linspace(z, z + 0.1, W, dtype=np.float32), (H, W))
        levels = np.unique(add_depth_noise(ramp, K, model, np.random.default_rng(0)))
        step = np.median(np.diff(levels))
        assert step == pytest.approx(z**2 * 0.125 / (F * 0.075), rel=0.1)
        assert step == pytest.approx(model.depth_step(z, F), rel=0.1)


def test_missing_behind_depth_discontinuities():
    depth = _wall(2.0)
    depth[40:80, 60:100] = 1.0  # a box in front of the wall
    noisy = add_depth_noise(depth, K, _quiet(shadow_px=2), np.random.default_rng(0))
    missing = noisy == 0
    ring = np.zeros_like(missing)
    ring[38:82, 58:102] = True
    ring[40:80, 60:100] = False
    assert missing[ring].all(), "the wall next to the box is in the emitter's shadow"
    assert not missing[45:75, 65:95].any() and not missing[:30].any()


def test_missing_at_grazing_angles_only():
    model = _quiet(grazing_start_rad=np.radians(70), grazing_stop_rad=np.radians(84))
    rng = np.random.default_rng(0)
    # turned 25 degrees, every ray meets the plane at less than 70 degrees
    assert (add_depth_noise(_tilted_wall(1.5, np.radians(25)), K, model, rng) > 0)[1:-1, 1:-1].all()
    steep = add_depth_noise(_tilted_wall(1.5, np.radians(86)), K, model, rng)
    assert (steep == 0).mean() > 0.95


def test_random_dropouts_and_range_limits():
    model = _quiet(dropout_prob=0.01)
    noisy = add_depth_noise(_wall(1.5), K, model, np.random.default_rng(0))
    assert (noisy == 0).mean() == pytest.approx(0.01, abs=0.004)
    far = add_depth_noise(_wall(6.0), K, _quiet(), np.random.default_rng(0))
    assert (far == 0).all()
    empty = add_depth_noise(np.zeros((H, W), np.float32), K, DepthNoiseModel(), np.random.default_rng(0))
    assert (empty == 0).all()


def test_noise_is_seeded():
    depth = _tilted_wall(1.2, 0.3)
    a = add_depth_noise(depth, K, DepthNoiseModel(), np.random.default_rng(5))
    b = add_depth_noise(depth, K, DepthNoiseModel(), np.random.default_rng(5))
    c = add_depth_noise(depth, K, DepthNoiseModel(), np.random.default_rng(6))
    assert a.dtype == np.float32 and a.shape == (H, W)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_colour_noise():
    img = np.full((H, W, 3), 128, np.uint8)
    noisy = add_colour_noise(img, 2.0, np.random.default_rng(0))
    assert noisy.dtype == np.uint8
    assert (noisy.astype(float) - 128).std() == pytest.approx(2.0, rel=0.05)
    assert add_colour_noise(np.full((4, 4, 3), 255, np.uint8), 5.0, np.random.default_rng(0)).max() == 255
    with pytest.raises(ValueError, match=r"expected an \(H, W, 3\) uint8 image, got float64"):
        add_colour_noise(np.zeros((4, 4, 3)), 2.0, np.random.default_rng(0))


def test_fast_normal_has_unit_variance():
    x = standard_normal_fast(np.random.default_rng(0), (200_000,))
    assert x.dtype == np.float32
    assert abs(x.mean()) < 0.01 and x.std() == pytest.approx(1.0, abs=0.01)
    with pytest.raises(ValueError, match="bits 8 or 16"):
        standard_normal_fast(np.random.default_rng(0), (3,), bits=12)


def test_depth_image_is_checked():
    with pytest.raises(ValueError, match=r"float \(H, W\) depth image, got uint16"):
        add_depth_noise(np.zeros((4, 4), np.uint16), K, DepthNoiseModel(), np.random.default_rng(0))
