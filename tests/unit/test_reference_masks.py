"""Reference masks (perception.reference_masks) on drawn scenes whose object pixels are known:
a grey bar held by two skin-coloured hands, one behind it and one at its own depth."""

import numpy as np
import pytest

from perception.reference_masks import (
    MaskConfig,
    ReferenceMaskError,
    automatic_seed,
    depth_steps,
    follow_object,
    skin_mask,
)

H, W = 240, 320
GREY = (120, 122, 128)
SKIN = (205, 150, 125)
SHIRT = (70, 75, 70)


def scene(k: int):
    """Frame k: a bar (0.55 m) moving right 3 px a frame, a hand 4 cm behind its left end, a hand
    at the bar's depth against its right end, a shirt far behind; depth cut to a band as the
    recording's authors did (0 beyond 0.7 m). Returns rgb, depth_m, the bar's true mask."""
    rng = np.random.default_rng(k)
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[:] = SHIRT
    depth = np.zeros((H, W), np.float32)
    x0 = 60 + 3 * k
    bar = np.zeros((H, W), bool)
    bar[100:140, x0:x0 + 180] = True
    rgb[bar] = GREY
    depth[bar] = 0.55
    left = np.zeros((H, W), bool)
    left[125:170, x0 - 15:x0 + 30] = True
    left &= ~bar  # behind the bar: only the part below shows
    rgb[left] = SKIN
    depth[left] = 0.59
    right = np.zeros((H, W), bool)
    right[95:145, x0 + 180:x0 + 210] = True  # touching the bar's end at the same depth
    rgb[right] = SKIN
    depth[right] = 0.55
    rgb = np.clip(rgb.astype(int) + rng.integers(-6, 7, rgb.shape), 0, 255).astype(np.uint8)
    return rgb, depth, bar


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_follows_the_bar_and_leaves_the_hands_out():
    frames = [scene(k) for k in range(6)]
    masks = list(follow_object(((rgb, d) for rgb, d, _ in frames)))
    assert len(masks) == 6
    for (_, depth, bar), mask in zip(frames, masks):
        assert iou(mask, bar) > 0.97
        hands = (depth > 0) & ~bar
        assert (mask & hands).sum() < 0.02 * hands.sum()


def test_automatic_seed_is_the_measured_non_skin_region():
    rgb, depth, bar = scene(0)
    seed = automatic_seed(rgb, depth)
    assert iou(seed, bar) > 0.97
    assert skin_mask(rgb)[depth == 0.59].mean() > 0.9 and not skin_mask(rgb)[bar].any()


def test_a_given_seed_is_used():
    rgb, depth, bar = scene(0)
    (mask,) = follow_object([(rgb, depth)], seed=bar)
    assert iou(mask, bar) > 0.97


def test_depth_steps_mark_seams_not_slopes():
    depth = np.tile(np.linspace(0.5, 0.6, 100, dtype=np.float32), (50, 1))  # 1 mm a pixel: a slope
    depth[:, 60:] += 0.03  # a 3 cm step
    steps = depth_steps(depth, 0.012)
    assert not steps[:, 5:55].any() and steps[10, 59] and steps[10, 60]


def test_no_object_and_bad_seeds_raise_one_line():
    rgb, depth, bar = scene(0)
    with pytest.raises(ReferenceMaskError, match="no automatic seed"):
        next(follow_object([(rgb, np.zeros_like(depth))]))
    with pytest.raises(ReferenceMaskError, match="seed mask"):
        next(follow_object([(rgb, depth)], seed=np.zeros((10, 10), bool)))
    with pytest.raises(ValueError, match="grow_px"):
        MaskConfig(grow_px=0)


def test_an_object_that_leaves_is_reported():
    rgb, depth, bar = scene(0)
    empty = np.zeros_like(depth)
    with pytest.raises(ReferenceMaskError, match="frame 1"):
        list(follow_object([(rgb, depth), (rgb, empty)]))
