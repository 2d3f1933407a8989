"""Objects in front of the cloth that nobody announced (``perception.occluders``): a patch
nearer than the predicted mesh is one when it stands out from the cloth around it by a step
all round, and not when it runs on into the cloth (a part the mesh lags behind, a flap
folded over along a crease) or when the whole cloth moved; closer than that, where colour
tells the cloth from its surroundings, when it is not of the cloth's colour and not the
empty workspace (the table bared under a lagging mesh)."""

import cv2
import numpy as np
import pytest

from ipc.messages import CameraInfo
from perception.colour_model import ColourModel
from perception.geometry import project
from perception.mesh import rectangle_mesh
from perception.occluders import occluders_in_front
from perception.raster import faces_mask
from perception.support import fit_support

CAM = CameraInfo.from_fov(320, 240, np.deg2rad(45))
K = CAM.K
Z = 1.3
ROWS, COLS = np.mgrid[0:240, 0:320]


@pytest.fixture(scope="module")
def sheet():
    """A 0.6 x 0.45 m mesh facing the camera at 1.3 m: the prediction."""
    mesh = rectangle_mesh(0.6, 0.45, 0.03)
    return mesh.canonical - [0.3, 0.225, -Z], mesh.faces


def flat(z=Z):
    """The measured sheet, in front of a wall at 2.5 m: (240, 320) float32 metres."""
    depth = np.full((240, 320), 2.5, np.float32)
    x = (COLS - K[0, 2]) / K[0, 0] * z
    y = (ROWS - K[1, 2]) / K[1, 1] * z
    depth[(np.abs(x) < 0.3) & (np.abs(y) < 0.225)] = z
    return depth


def box(r0, r1, c0, c1):
    region = np.zeros((240, 320), bool)
    region[r0:r1, c0:c1] = True
    return region


@pytest.mark.parametrize("gap_m, shadow_px", [(0.04, 0), (0.04, 3), (0.2, 6)])
def test_an_object_in_front_of_the_cloth_is_found(sheet, gap_m, shadow_px):
    depth = flat()
    hand = box(100, 140, 140, 180)
    if shadow_px:  # a depth sensor measures nothing beside a discontinuity
        depth[box(100 - shadow_px, 140 + shadow_px, 140 - shadow_px, 180 + shadow_px)] = 0.0
    depth[hand] = Z - gap_m
    front = occluders_in_front(depth, *sheet, K, near_m=0.03)
    assert front is not None and front[hand].all()
    assert not front[box(60, 90, 60, 260)].any()  # the cloth around it is not
    assert front.sum() < 1.5 * hand.sum()  # grown by its edge pixels


def test_an_object_over_the_cloth_s_edge_is_found(sheet):
    depth = flat()
    arm = box(150, 240, 140, 170)  # from below the sheet up onto it
    depth[arm] = Z - 0.05
    front = occluders_in_front(depth, *sheet, K, near_m=0.03)
    vertices, faces = sheet
    over_mesh = cv2.erode(faces_mask(project(vertices, K), faces, depth.shape).view(np.uint8), np.ones((5, 5))) > 0
    assert front is not None and front[arm & over_mesh].all() and (arm & over_mesh).sum() > 300


def test_nothing_nearer_than_the_margin_or_smaller_than_a_patch_is_taken(sheet):
    depth = flat()
    depth[box(100, 140, 140, 180)] = Z - 0.02  # within the margin
    depth[box(60, 64, 60, 64)] = Z - 0.2  # 16 pixels: a speck
    assert occluders_in_front(depth, *sheet, K, near_m=0.03) is None


def test_cloth_the_mesh_lags_behind_is_not_an_occluder(sheet):
    # A bulge 6 cm towards the camera, smooth: nearer than predicted, but continuous.
    x = (COLS - K[0, 2]) / K[0, 0] * Z
    y = (ROWS - K[1, 2]) / K[1, 1] * Z
    depth = flat()
    on = depth < 2.0
    depth[on] -= (0.06 * np.exp(-(x**2 + y**2) / (2 * 0.08**2)))[on].astype(np.float32)
    assert occluders_in_front(depth, *sheet, K, near_m=0.03) is None
    # The whole sheet moved 5 cm nearer than predicted: no cloth around it agrees, nothing found.
    assert occluders_in_front(flat(Z - 0.05), *sheet, K, near_m=0.03) is None


def test_a_flap_folded_over_along_a_crease_is_not_an_occluder(sheet):
    # A flap 4 cm in front of the sheet, joined to it by a ramp along one side (the crease).
    depth = flat()
    depth[box(100, 130, 140, 180)] = Z - 0.04
    ramp = np.linspace(Z - 0.04, Z, 12, dtype=np.float32)
    depth[100:130, 180:192] = ramp
    assert occluders_in_front(depth, *sheet, K, near_m=0.03) is None


def test_known_occluders_are_not_looked_for_again_and_a_vertex_behind_the_camera_is_no_trouble(sheet):
    depth = flat()
    hand = box(100, 140, 140, 180)
    depth[hand] = Z - 0.05
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, known=hand) is None
    vertices, faces = sheet
    behind = vertices.copy()
    behind[0, 2] = -0.1
    front = occluders_in_front(depth, behind, faces, K, near_m=0.03)
    assert front is not None and front[hand].all()


def test_an_object_found_before_needs_a_step_on_less_of_its_rim_but_cannot_take_cloth_along(sheet):
    # An object in front whose rim meets the cloth without a step on two of its sides (the
    # mesh drawn towards it there): not taken at first sight, taken when it was in front in
    # the frame before, a few pixels away; not when the patch has grown to twice its size.
    depth = flat()
    hand = box(100, 140, 140, 180)
    depth[hand] = Z - 0.05
    depth[100:140, 180:192] = np.linspace(Z - 0.05, Z, 12, dtype=np.float32)
    depth[88:100, 140:180] = np.linspace(Z, Z - 0.05, 12, dtype=np.float32)[:, None]
    assert occluders_in_front(depth, *sheet, K, near_m=0.03) is None
    front = occluders_in_front(depth, *sheet, K, near_m=0.03, before=np.roll(hand, 6, axis=1))
    assert front is not None and front[hand].all()
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, before=box(100, 120, 140, 160)) is None


def coloured(cloth):
    """(240, 320, 3) uint8: a blue cloth where ``cloth`` (240, 320) bool, grey elsewhere, with sensor noise."""
    rng = np.random.default_rng(0)
    rgb = np.where(cloth[..., None], [40, 70, 170], [150, 150, 145]).astype(np.float64)
    return np.clip(rgb + rng.normal(0, 2, rgb.shape), 0, 255).astype(np.uint8)


def red_in_front(region, gap_m=0.015):
    """(depth, rgb, colour model): the blue sheet in front of a grey wall, and a red object
    ``gap_m`` in front of the sheet over ``region`` (240, 320) bool; the model learnt without it."""
    depth = flat()
    rgb = coloured(depth < 2.0)
    colour = ColourModel(rgb, depth < 2.0)
    depth[region] = Z - gap_m
    rgb[region] = (200, 60, 50)
    return depth, rgb, colour


def test_an_object_closer_than_the_step_is_found_by_its_colour_with_its_part_beside_the_cloth(sheet):
    arm = box(0, 140, 140, 175)  # from above the image down onto the sheet, 1.5 cm in front of it
    depth, rgb, colour = red_in_front(arm)
    assert occluders_in_front(depth, *sheet, K, near_m=0.03) is None  # no step to see
    front = occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour)
    vertices, faces = sheet
    over_mesh = faces_mask(project(vertices, K), faces, depth.shape)
    assert front is not None and front[arm & over_mesh].mean() > 0.95
    # Its part in front of the wall, next to the sheet, hides the sheet's outline too (the
    # search reaches some way beyond the mesh, not to the image's edge).
    grown = lambda r: cv2.dilate(over_mesh.view(np.uint8), np.ones((2 * r + 1,) * 2, np.uint8)).view(bool)  # noqa: E731
    beside = arm & grown(16) & ~grown(4)
    assert beside.sum() > 300 and front[beside].all()
    assert not front[~cv2.dilate(arm.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool)].any()  # nor the wall


def test_cloth_of_the_cloth_s_colour_nearer_than_predicted_is_not_taken_for_an_object(sheet):
    depth = flat()
    rgb = coloured(depth < 2.0)
    colour = ColourModel(rgb, depth < 2.0)
    depth[box(100, 140, 140, 180)] = Z - 0.015  # a patch of the cloth the mesh lags behind
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour) is None


def test_the_table_bared_under_a_lagging_mesh_is_not_an_object_in_front(sheet):
    # The sheet lay on a grey table (the wall, 3 mm behind it). Now a corner is lifted: the
    # predicted mesh sank 2 cm into the table where the cloth left it, and, seen obliquely,
    # the lifted cloth beyond lies farther from the camera than the bared table. There the
    # table is nearer than the mesh and than the cloth around it, and not of the cloth's
    # colour, as an arm in front would be.
    lying = flat()
    lying[lying > 2.0] = Z + 0.003
    cloth = np.abs(lying - Z) < 0.001
    rgb = coloured(cloth)
    colour = ColourModel(rgb, cloth)
    support = fit_support(lying, cloth, K)
    assert support is not None
    vertices, faces = sheet
    sunk = vertices + [0.0, 0.0, 0.02]
    depth = np.where(cloth, Z + 0.03, lying).astype(np.float32)
    bared = box(100, 140, 190, 240)  # from under the sheet's right edge, joined to the table beyond
    depth[bared] = Z + 0.003
    rgb[bared] = (150, 150, 145)
    found = occluders_in_front(depth, sunk, faces, K, near_m=0.03, rgb=rgb, colour=colour)
    assert found is not None and found[bared & (COLS < 228)].mean() > 0.9  # without knowing the table: taken
    assert occluders_in_front(depth, sunk, faces, K, near_m=0.03, rgb=rgb, colour=colour, support=support) is None
    workspace = np.abs(depth - (Z + 0.003)) < 1e-4  # the empty workspace, as a background tells it
    assert occluders_in_front(depth, sunk, faces, K, near_m=0.03, rgb=rgb, colour=colour, workspace=workspace) is None


def test_an_object_found_by_its_colour_is_kept_while_a_little_nearer_than_the_mesh(sheet):
    # An arm 1.5 cm in front of the cloth, and the mesh behind it drawn 1 cm towards it: it
    # is only 5 mm nearer than the mesh, which is enough for an object found the frame before.
    arm = box(0, 140, 140, 175)
    depth, rgb, colour = red_in_front(arm)
    vertices, faces = sheet
    drawn = vertices - [0.0, 0.0, 0.01]
    assert occluders_in_front(depth, drawn, faces, K, near_m=0.03, rgb=rgb, colour=colour) is None
    front = occluders_in_front(depth, drawn, faces, K, near_m=0.03, rgb=rgb, colour=colour, before=arm)
    over_mesh = faces_mask(project(vertices, K), faces, depth.shape)
    assert front is not None and front[arm & over_mesh].mean() > 0.95


def test_a_patch_of_another_colour_within_the_cloth_is_a_print_not_an_object_in_front(sheet):
    # A print the first frame did not show, on a fold's crest: nearer than the mesh and than
    # the cloth all round, but it does not reach past the cloth as an arm or a hand would.
    depth, rgb, colour = red_in_front(box(100, 140, 140, 180))
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour) is None


def test_a_fold_in_the_shade_is_cloth_not_an_object_in_front(sheet):
    # A part of the cloth nearer than the lagging mesh, darkened and greyed by the shade of a
    # fold (its colour no longer the cloth's), runs on into the cloth beside it without a step.
    depth = flat()
    rgb = coloured(depth < 2.0)
    colour = ColourModel(rgb, depth < 2.0)
    x = (COLS - K[0, 2]) / K[0, 0] * Z
    y = (ROWS - K[1, 2]) / K[1, 1] * Z
    bulge = 0.03 * np.exp(-(x**2 + y**2) / (2 * 0.06**2))
    on = depth < 2.0
    depth[on] -= bulge[on].astype(np.float32)
    shade = on & (bulge > 0.015)
    rgb[shade] = (90, 92, 100)
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour) is None


SHEET_VERTICES = rectangle_mesh(0.6, 0.45, 0.03).canonical


def too_near(region, wall_m=2.5):
    """(depth, rgb, colour model, what the frame before showed): the blue sheet in front of a grey
    wall at ``wall_m`` (0: beyond the sensor's range, no depth), and a red object over ``region``
    (240, 320) bool too near the camera for depth; the model learnt without it; the sheet
    segmented and every vertex seen in the frame before."""
    depth = flat()
    sheet_mask = depth < 2.0
    if not wall_m:
        depth[~sheet_mask] = 0.0
    rgb = coloured(sheet_mask)
    colour = ColourModel(rgb, sheet_mask)
    depth[region] = 0.0
    rgb[region] = (200, 60, 50)
    return depth, rgb, colour, {"object_before": (sheet_mask,), "seen_before": np.ones(len(SHEET_VERTICES), bool)}


def test_an_object_too_near_to_measure_is_found_where_the_cloth_was(sheet):
    hand = box(60, 200, 0, 150)  # from the image's left edge over the sheet's left part: no depth at all
    depth, rgb, colour, before = too_near(hand)
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour) is None  # nothing to step from
    front = occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour, **before)
    vertices, faces = sheet
    over_mesh = faces_mask(project(vertices, K), faces, depth.shape)
    assert front is not None and front[hand & over_mesh].mean() > 0.95
    # Its part beside the sheet, where it hides the sheet's outline, is taken too, not the
    # sheet beside it nor the wall far from it.
    grown = lambda r: cv2.dilate(over_mesh.view(np.uint8), np.ones((2 * r + 1,) * 2, np.uint8)).view(bool)  # noqa: E731
    assert front[hand & grown(12) & ~grown(4)].mean() > 0.95
    assert not front[~cv2.dilate(hand.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool)].any()


def test_pixels_without_depth_that_never_were_cloth_or_are_of_its_hue_are_not_an_object_too_near(sheet):
    vertices, faces = sheet
    # The wall beyond the sensor's range shows where the prediction overhangs the sheet (a mesh
    # left a little too large): without depth, not of the sheet's hue, but never the sheet.
    depth, rgb, colour, _ = too_near(np.zeros((240, 320), bool), wall_m=0)
    smaller = flat() < 2.0
    smaller[:, :110] = False  # the sheet's left part moved away long ago
    depth[~smaller] = 0.0
    rgb[~smaller] = (150, 150, 145)
    seen = np.ones(len(vertices), bool)
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour, object_before=(smaller,),
                              seen_before=seen) is None
    # The sheet's own pixels without depth (seen at a grazing angle): of its hue.
    depth, rgb, colour, before = too_near(np.zeros((240, 320), bool))
    depth[box(80, 160, 120, 200)] = 0.0
    assert occluders_in_front(depth, *sheet, K, near_m=0.03, rgb=rgb, colour=colour, **before) is None
