"""perception.appearance: whether a surface found later can be the cloth first seen."""

import numpy as np

from perception.appearance import AppearanceModel
from sim.cloth_mesh import rectangle_cloth

K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])
MESH = rectangle_cloth(0.4, 0.3, spacing_m=0.02)
V = np.c_[MESH.uv_m - [0.2, 0.15], np.full(MESH.n_vertices, 1.0)]  # fills most of a 320x240 image


def _model(rgb: np.ndarray) -> AppearanceModel:
    return AppearanceModel(rgb, V, MESH.faces, K, np.ones(MESH.n_vertices, bool), 0.02)


def _print(rng) -> np.ndarray:
    """Blocks of many hues, each a few mesh spacings wide."""
    blocks = rng.integers(30, 230, size=(8, 12, 3)).astype(np.uint8)
    return np.kron(blocks, np.ones((30, 27, 1), np.uint8))[:240, :320]


def _shaded_arm() -> np.ndarray:
    """One skin tone, shaded across like a lit cylinder."""
    shade = 0.55 + 0.45 * np.sin(np.linspace(0.0, np.pi, 320))[None, :, None]
    return np.broadcast_to(np.array([225.0, 190.0, 180.0]) * shade, (240, 320, 3)).astype(np.uint8)


def test_a_print_is_not_taken_for_a_plain_arm_its_shading_notwithstanding():
    printed, arm = _model(_print(np.random.default_rng(0))), _model(_shaded_arm())
    assert arm.textured, "shading alone spreads the grey levels: texture cannot tell the two apart"
    assert not printed.could_be(arm)
    assert printed.could_be(_model((_print(np.random.default_rng(0)) * 0.6).astype(np.uint8))), "dimmer light"
    assert printed.could_be(_model(_print(np.random.default_rng(1)))), "another part of the print"


def test_a_plain_cloth_cannot_tell_and_does_not_refuse():
    plain = _model(np.full((240, 320, 3), (200, 170, 190), np.uint8))
    assert plain.chroma_spread < 0.01
    assert plain.could_be(_model(_shaded_arm()))


def _on_background(inside: np.ndarray) -> np.ndarray:
    """``inside`` where the mesh projects, a dark background around it (the mesh's outline)."""
    rgb = np.full((240, 320, 3), 40, np.uint8)
    uv = V[:, :2] / V[:, 2:] * K[0, 0] + K[:2, 2]
    (x0, y0), (x1, y1) = np.floor(uv.min(axis=0)).astype(int), np.ceil(uv.max(axis=0)).astype(int)
    rgb[y0:y1 + 1, x0:x1 + 1] = inside[y0:y1 + 1, x0:x1 + 1]
    return rgb


def test_a_print_does_not_look_like_a_plain_surface_with_the_same_outline():
    """Blurred, the samples along a mesh's outline mix in the background: a ring darker than
    the surface inside, on the print and on a plain surface alike. Compared on them too, a
    plain surface laid exactly where the print was correlates with it."""
    printed = _print(np.random.default_rng(0))
    plain = np.broadcast_to(printed.reshape(-1, 3).mean(axis=0).astype(np.uint8), printed.shape)
    seen = np.ones(MESH.n_vertices, bool)
    outline = np.flatnonzero(np.bincount(MESH.edges().ravel(), minlength=MESH.n_vertices) < 6)
    model = AppearanceModel(_on_background(printed), V, MESH.faces, K, seen, 0.02, outline)
    assert model.likeness(_on_background(printed), V, MESH.faces, K, seen) == 1.0
    assert model.likeness(_on_background(plain), V, MESH.faces, K, seen) == 0.0


def test_a_mesh_slid_over_part_of_the_print_is_told_by_its_regions():
    """Half the mesh moved by 4.2 cm along the print (a lifted part of the cloth whose material
    points slid): the whole still correlates as well as the global check asks (the other
    half lies right); region by region the slide shows."""
    # grey blocks about a mesh spacing wide (10 px here): a print's shapes and letters
    printed = np.kron(np.random.default_rng(0).integers(30, 230, size=(24, 32, 1)), np.ones((10, 10, 3))).astype(np.uint8)
    seen = np.ones(MESH.n_vertices, bool)
    model = AppearanceModel(printed, V, MESH.faces, K, seen, 0.02, canonical=np.c_[MESH.uv_m, np.zeros(MESH.n_vertices)])
    assert model.likeness(printed, V, MESH.faces, K, seen) == 1.0
    assert model.last_regions_slid == 0.0
    slid = V.copy()
    slid[MESH.uv_m[:, 0] < 0.2, :2] += 0.03  # the left half, 4.2 cm along the diagonal
    likeness = model.likeness(printed, slid, MESH.faces, K, seen)
    assert model.last_value > 0.4, "as a whole the slid mesh correlates: the global check alone gives 1"
    assert model.last_regions_slid > 0.25
    assert likeness < 0.6
