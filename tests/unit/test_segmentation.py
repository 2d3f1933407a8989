"""Depth segmentation against floors, walls and a hand holding the cloth."""

import cv2
import numpy as np
import pytest

from ipc.messages import CameraInfo
from perception.colour_model import ColourModel
from perception.geometry import rays
from perception.raster import reached_from
from perception.segmentation import SegmentationConfig, contour_parts, find_object, object_extent, segment_tracked

CAM = CameraInfo.from_fov(320, 240, np.deg2rad(50))
K = CAM.K
H, W = 240, 320


def outline(mask, *args, **kwargs):
    """(H, W) bool: the contour's outline part (``contour_parts``), where the object ends."""
    image = np.zeros(mask.size, bool)
    image[contour_parts(mask, *args, **kwargs)[0]] = True
    return image.reshape(mask.shape)


def scene_depth(floor=True, wall=True, cloth=True, hand=False):
    """Camera 1 m above a floor, looking level; a wall 2.2 m ahead; a cloth 1.3 m ahead.

    returns depth (H, W) float32 and the true cloth mask
    """
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    r = rays(np.column_stack([uu.ravel(), vv.ravel()]).astype(float), K).reshape(H, W, 3)
    depth = np.full((H, W), np.inf)
    if wall:
        depth = np.minimum(depth, 2.2)
    if floor:  # plane y = 1.0 (1 m below the camera, y down)
        with np.errstate(divide="ignore"):
            t = np.where(r[..., 1] > 1e-6, 1.0 / r[..., 1], np.inf)
        depth = np.minimum(depth, t)
    cloth_mask = np.zeros((H, W), bool)
    if cloth:  # a 0.6 x 0.5 m sheet hanging 1.3 m ahead, bottom edge 0.3 m above the floor
        x, y = r[..., 0] * 1.3, r[..., 1] * 1.3
        cloth_mask = (np.abs(x) < 0.3) & (y > 0.2) & (y < 0.7)
        depth = np.where(cloth_mask, 1.3 + 0.03 * np.sin(8 * x), depth)
    hand_mask = np.zeros((H, W), bool)
    if hand:  # an arm reaching the top-left corner from above, 15 cm in front of the cloth
        x, y = r[..., 0] * 1.15, r[..., 1] * 1.15
        hand_mask = (np.abs(x + 0.28) < 0.05) & (y < 0.26)
        depth = np.where(hand_mask, 1.15, depth)
        cloth_mask &= ~hand_mask
    depth = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
    return depth, cloth_mask, hand_mask


def iou(a, b):
    return (a & b).sum() / max(1, (a | b).sum())


@pytest.mark.parametrize("floor,wall", [(True, True), (True, False), (False, True), (False, False)])
def test_find_object_ignores_floor_and_wall(floor, wall):
    depth, truth, _ = scene_depth(floor, wall)
    mask = find_object(depth, K, SegmentationConfig(), np.random.default_rng(0))
    assert iou(mask, truth) > 0.95


def test_find_object_on_empty_scene_is_empty():
    depth, _, _ = scene_depth(cloth=False)
    assert not find_object(depth, K).any()
    assert not find_object(np.zeros((H, W), np.float32), K).any()


def test_tracked_segmentation_cuts_off_the_hand_and_background():
    depth, truth, hand = scene_depth(hand=True)
    predicted = np.roll(truth | hand, 4, axis=1)  # last frame's mesh, a few pixels off
    predicted &= ~hand  # the mesh is the cloth only
    segment = segment_tracked(depth, predicted, (1.25, 1.35), SegmentationConfig())
    mask = segment.mask
    assert iou(mask, truth) > 0.95
    # the hand (15 cm nearer, a depth jump) joins only as far as the search margin allows
    assert (mask & hand).sum() < 0.2 * hand.sum()
    assert segment.leak < 0.1  # the prediction contains the cloth


def test_tracked_segmentation_reports_a_surface_that_goes_on_beyond_the_search():
    _, cloth, _ = scene_depth()
    depth, _, _ = scene_depth(cloth=False)
    depth = np.minimum(depth, 1.3).astype(np.float32)  # a wall where the cloth was
    segment = segment_tracked(depth, cloth, (1.25, 1.35), SegmentationConfig())
    assert segment.mask.sum() > 1.5 * cloth.sum() and segment.leak > 0.6
    assert segment.unsearched[0, 0] and not segment.unsearched[cloth].any()


def test_tracked_segmentation_leaves_out_the_table_a_lifted_corner_bared():
    """A pink printed cloth on a grey table at its own depth; its corner was lifted, and the
    prediction still covers an 8-pixel strip of bare table beside it (narrower than a print's
    patch). The strip is left out; a print patch of the table's own grey inside the cloth is not."""
    rng = np.random.default_rng(0)
    depth = np.full((H, W), 1.3, np.float32)  # the table, and the cloth lying on it
    rgb = np.clip(rng.normal(120, 4, (H, W, 3)), 0, 255).astype(np.uint8)
    cloth = np.zeros((H, W), bool)
    cloth[60:180, 80:240] = True
    rgb[cloth] = (230, 150, 170)
    rgb[100:112, 120:132] = 120  # a grey print patch, 12 px wide
    rgb[140:150, 180:200] = (40, 40, 160)
    colour = ColourModel(rgb, cloth)
    strip = np.zeros((H, W), bool)
    strip[60:180, 240:248] = True  # where the lifted corner lay
    segment = segment_tracked(depth, cloth | strip, (1.28, 1.32), SegmentationConfig(), rgb=rgb, colour=colour)
    assert (segment.mask & strip).sum() < 0.1 * strip.sum()
    assert segment.mask[100:112, 120:132].mean() > 0.9
    assert iou(segment.mask, cloth) > 0.95


def test_reached_from_keeps_the_regions_a_seed_lies_in():
    """Two blobs of passable pixels, a seed in one: that one only. Blobs touching at a corner
    are one region 8 ways, two 4 ways; a seed outside the passable pixels reaches nothing."""
    passable = np.zeros((10, 10), bool)
    passable[1:4, 1:4] = True
    passable[4:7, 4:7] = True  # touches the first blob at one corner
    passable[8:10, 0:3] = True
    seed = np.zeros_like(passable)
    seed[2, 2] = True
    assert np.array_equal(reached_from(seed, passable), passable & ~(np.arange(10)[:, None] >= 8))
    four = reached_from(seed, passable, connectivity=4)
    assert four[1:4, 1:4].all() and four.sum() == 9
    outside = np.zeros_like(passable)
    outside[0, 9] = True
    assert not reached_from(outside, passable).any()


def lifted_slope(rng):
    """A pink cloth lying on a grey table 1.3 m away (rows 60-140), whose near part (rows
    140-180) rises steeply towards the camera, as when a corner is lifted: there the sensor
    has lost most of the depth, and what is left jumps by centimetres from pixel to pixel,
    specks too small to be a region. depth, rgb, flat part, slope, colour model."""
    depth = np.full((H, W), 1.3, np.float32)
    rgb = np.clip(rng.normal(120, 4, (H, W, 3)), 0, 255).astype(np.uint8)
    flat, slope = np.zeros((H, W), bool), np.zeros((H, W), bool)
    flat[60:140, 80:240] = True
    slope[140:180, 80:240] = True
    rgb[flat | slope] = (230, 150, 170)
    depth[140:180, 80:240] = rng.uniform(0.9, 1.3, (40, 160)) * (rng.random((40, 160)) < 0.4)
    return depth, rgb, flat, slope, ColourModel(rgb, flat | slope)


def test_a_part_of_the_cloth_turned_steeply_away_is_kept_by_its_colour():
    """The mesh still covers the slope; depth finds only the flat part, colour says the
    slope is the cloth too."""
    depth, rgb, flat, slope, colour = lifted_slope(np.random.default_rng(3))
    z = (0.9, 1.32)
    without = segment_tracked(depth, flat | slope, z, SegmentationConfig())
    assert without.mask[slope].mean() < 0.3  # depth alone: only the rim next to the flat part
    segment = segment_tracked(depth, flat | slope, z, SegmentationConfig(), rgb=rgb, colour=colour)
    assert segment.mask[slope].mean() > 0.9 and segment.mask[flat].mean() > 0.95


def test_colour_keeps_no_pixel_without_depth_beyond_the_prediction_or_a_surface_depth_places():
    """Beside the slope, a pink shirt without depth (the sensor reaches only the cloth), and a
    pink box 20 cm in front of the table that the prediction does not cover: neither joins."""
    depth, rgb, flat, slope, colour = lifted_slope(np.random.default_rng(4))
    shirt, box = np.zeros((H, W), bool), np.zeros((H, W), bool)
    shirt[140:200, 240:262] = True
    box[60:140, 240:262] = True
    rgb[shirt | box] = (230, 150, 170)
    depth[shirt] = 0.0
    depth[box] = 1.1
    segment = segment_tracked(depth, flat | slope, (0.9, 1.32), SegmentationConfig(), rgb=rgb, colour=colour)
    assert segment.mask[slope].mean() > 0.9
    assert segment.mask[shirt].mean() < 0.1 and segment.mask[box].mean() < 0.1


def test_with_the_empty_workspace_the_object_takes_in_what_differs_from_it():
    """A cloth on a table at the table's depth, its left third without depth (seen at a
    grazing angle); the mesh lost that third, so the search misses it. What differs from the
    empty workspace and joins the cloth is the cloth, with or without depth; a box 40 cm
    nearer that differs too and touches it (across a band without depth) is not, nor is a
    hand 8 cm nearer that touches it, nor a robot arm on the cloth that the frame masks."""
    depth = np.full((H, W), 1.3, np.float32)
    cloth, box, arm = np.zeros((H, W), bool), np.zeros((H, W), bool), np.zeros((H, W), bool)
    cloth[60:180, 50:280] = True
    depth[60:180, 50:120] = 0.0
    box[20:58, 150:230] = True
    depth[box] = 0.9
    depth[58:60, 150:230] = 0.0  # the sensor's shadow beside the box
    arm[100:140, 200:320] = True
    hands = np.zeros((H, W), bool)
    hands[60:90, 280:300] = True  # touching the cloth's edge, inside the search's depth band
    depth[hands] = 1.22
    differs = cloth | box | arm | hands
    differs[58:60, 150:230] = True
    predicted = np.zeros((H, W), bool)
    predicted[60:180, 160:280] = True
    not_object = arm | ~differs
    before = segment_tracked(depth, predicted, (1.28, 1.32), SegmentationConfig(), not_object=not_object)
    assert before.mask[cloth & ~arm].mean() < 0.7 and not before.mask[60:180, 50:120].any()
    segment = segment_tracked(depth, predicted, (1.28, 1.32), SegmentationConfig(), not_object=not_object,
                              differs=differs)
    assert iou(segment.mask, cloth & ~arm) > 0.97
    assert not segment.mask[box].any() and not segment.mask[arm].any() and segment.mask[hands].sum() < 10
    assert not segment.unsearched[cloth].any() and segment.leak < 0.05
    # with the object beyond reach of the search, its edge there is not where it ends
    edge_only = np.zeros((H, W), bool)
    edge_only[60:180, 240:280] = True
    far = segment_tracked(depth, edge_only, (1.28, 1.32), SegmentationConfig(), not_object=not_object,
                          differs=differs)
    assert far.mask[60:180, 130:200].all() and not far.mask[:, :110].any()
    assert far.leak > 0.1 and far.unsearched[:, :110].all()


def creased_sheet(rng):
    """A pink cloth 1.2 m away on a grey wall 2 m away, parted by a crease without depth
    (rows 100-104) into an upper and a lower part: depth, rgb, upper, lower, colour model."""
    depth = np.full((H, W), 2.0, np.float32)
    rgb = np.clip(rng.normal(120, 4, (H, W, 3)), 0, 255).astype(np.uint8)
    upper, lower = np.zeros((H, W), bool), np.zeros((H, W), bool)
    upper[30:100, 100:200] = True
    lower[104:220, 100:200] = True
    for part in (upper, lower):
        depth[part] = 1.2
        rgb[part] = (230, 150, 170)
    depth[100:104, 100:200] = 0.0  # the crease
    return depth, rgb, upper, lower, ColourModel(rgb, upper | lower)


@pytest.mark.parametrize("gap_px", [0, 4])
def test_the_extent_finds_the_part_of_the_object_the_prediction_lost(gap_px):
    """The mesh was squeezed into the upper part, so the search misses most of the lower
    part. The mask stops at the crease; the extent goes on over the lower part, but not onto
    a pink box 30 cm in front of the cloth, touching it or beyond a band without depth."""
    depth, rgb, upper, lower, colour = creased_sheet(np.random.default_rng(1))
    box = np.zeros((H, W), bool)
    box[30:100, 200 + gap_px:240] = True
    depth[box], rgb[box] = 0.9, (230, 150, 170)
    depth[30:100, 200:200 + gap_px] = 0.0
    segment = segment_tracked(depth, upper, (1.18, 1.22), SegmentationConfig(), rgb=rgb, colour=colour)
    assert not segment.mask[lower].any()
    assert segment.extent[lower].mean() > 0.9 and segment.extent[upper].mean() > 0.9
    assert segment.extent[box].mean() < 0.05
    # without colour to tell the object from the rest, there is no extent
    assert segment_tracked(depth, upper, (1.18, 1.22), SegmentationConfig()).extent is None


def test_the_extent_does_not_run_through_what_cannot_be_the_object():
    """A robot arm of the cloth's colour, at its depth, joins the cloth to a poster of that
    colour: with the arm's mask given, the poster stays out of the extent."""
    depth, rgb, upper, lower, colour = creased_sheet(np.random.default_rng(2))
    arm, poster = np.zeros((H, W), bool), np.zeros((H, W), bool)
    arm[30:60, 200:250] = True
    poster[20:120, 250:310] = True
    for part in (arm, poster):
        depth[part], rgb[part] = 1.2, (230, 150, 170)
    segment = segment_tracked(depth, upper, (1.18, 1.22), SegmentationConfig(), rgb=rgb, colour=colour)
    assert segment.extent[poster].mean() > 0.9  # nothing says the arm is not the cloth
    segment = segment_tracked(depth, upper, (1.18, 1.22), SegmentationConfig(), rgb=rgb, colour=colour,
                              not_object=arm)
    assert segment.extent[poster].mean() < 0.05 and segment.extent[lower].mean() > 0.9
    # looked up on its own (as the tracker does, on its second thread), the same extent
    alone = segment_tracked(depth, upper, (1.18, 1.22), SegmentationConfig(), rgb=rgb, colour=colour,
                            not_object=arm, with_extent=False)
    assert alone.extent is None and np.array_equal(alone.mask, segment.mask)
    extent = object_extent(alone.mask, depth, upper, rgb, colour, SegmentationConfig(), not_object=arm)
    assert np.array_equal(extent, segment.extent)


def test_a_small_object_pressed_against_a_larger_one_is_still_found():
    """An object 24 pixels wide (a small one, or one far away) touched by a hand or pressed by
    another object at its own depth: together they fill the search around the prediction, of
    which the object is a small part. It is still there; colour tells it from what touches it."""
    rng = np.random.default_rng(0)
    depth = np.full((H, W), 2.2, np.float32)
    rgb = np.clip(rng.normal(120, 4, (H, W, 3)), 0, 255).astype(np.uint8)
    toucher = np.zeros((H, W), bool)
    toucher[60:200, 100:240] = True
    obj = np.zeros((H, W), bool)
    obj[110:134, 150:174] = True
    depth[toucher | obj] = 0.6
    rgb[toucher] = (60, 70, 200)
    rgb[obj] = (220, 60, 80)
    colour = ColourModel(rgb, obj)
    predicted = np.roll(obj, 2, axis=1)  # last frame's mesh, a little off
    segment = segment_tracked(depth, predicted, (0.59, 0.61), SegmentationConfig())
    assert segment.mask[obj].mean() > 0.95  # found, with what touches it as far as the search reaches
    segment = segment_tracked(depth, predicted, (0.59, 0.61), SegmentationConfig(), rgb=rgb, colour=colour)
    assert segment.mask[obj].mean() > 0.8  # less its rim, where the colour model is less sure
    assert (segment.mask & toucher & ~predicted).sum() < 0.05 * obj.sum()  # beyond the prediction's sliver


def test_tracked_segmentation_empty_when_object_gone():
    depth, truth, _ = scene_depth(cloth=False)
    _, predicted, _ = scene_depth()
    segment = segment_tracked(depth, predicted, (1.25, 1.35))
    assert not segment.mask.any() and segment.leak == 0.0


def test_outline_skips_occluding_contour_and_image_border():
    depth, truth, hand = scene_depth(hand=True)
    out = outline(truth, depth)
    # pixels of the cloth next to the (nearer) hand are not outline
    near_hand = truth & np.roll(hand, 1, axis=0)
    solid = truth | hand  # away from the cloth's side edges, where the wall is a real outline
    near_hand &= np.roll(solid, 1, axis=1) & np.roll(solid, -1, axis=1)
    assert near_hand.sum() > 5
    assert not (out & near_hand).any()
    assert out[truth].sum() > 0
    # a mask touching the image border has no outline along the border
    full = np.ones((H, W), bool)
    assert not outline(full, np.ones((H, W), np.float32)).any()


def test_outline_skips_a_contour_behind_a_band_without_depth_beside_a_nearer_surface():
    """A depth sensor loses the pixels beside a discontinuity: the cloth's contour behind the
    hand borders a band without depth, and the hand lies beyond it. That contour is still
    hidden; a real edge beside pixels without depth and nothing nearer stays an outline."""
    depth, truth, hand = scene_depth(hand=True)
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    band = cv2.dilate(hand.astype(np.uint8), cross, iterations=4).astype(bool) & ~hand & truth  # a 4-pixel shadow
    cloth = truth & ~band
    shadowed = depth.copy()
    shadowed[band] = 0.0
    behind_band = cloth & cv2.dilate(band.astype(np.uint8), cross).astype(bool)
    # away from the cloth's side edge, where the wall beside it is a real outline
    behind_band &= ~cv2.dilate((~truth & ~hand).astype(np.uint8), cross).astype(bool)
    assert behind_band.sum() > 5
    # looking only at the next pixel, the band reads as background beyond a real edge
    assert outline(cloth, shadowed, shadow_px=0)[behind_band].all()
    # looking across the band, the hand hides the contour; at the band's corners going straight
    # out of the cloth does not meet the hand
    assert outline(cloth, shadowed)[behind_band].mean() < 0.2
    # the cloth's right edge beside a column without depth, the wall beyond: still its outline
    no_wall = shadowed.copy()
    beside = np.roll(cloth, 1, 1) & ~cloth & ~hand  # the cloth is clear of the image's sides
    no_wall[beside] = 0.0
    edge = cloth & np.roll(beside, -1, 1)
    assert edge.sum() > 5
    assert outline(cloth, no_wall)[edge].all()


def test_find_object_sees_a_wall_as_background_though_depth_stops_short_of_the_edges():
    """A registered Kinect image has no depth in its first dozen columns: the wall does not
    reach the image's edge, and must not be taken for the object."""
    depth, truth, _ = scene_depth()
    depth = depth.copy()
    depth[:, :12] = 0.0
    depth[:3] = 0.0
    mask = find_object(depth, K, SegmentationConfig(), np.random.default_rng(0))
    assert iou(mask, truth) > 0.9
