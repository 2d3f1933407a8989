"""The coarse stage's memory of the last frame: which points its blur mixes with a mask."""

import numpy as np

from perception.coarse import FrameMemory


def test_near_a_mask_means_within_the_blur_of_the_stored_frame():
    memory = FrameMemory(scale=4)
    reach = memory.blur_reach_px
    assert reach == 12  # three standard deviations of a one-pixel blur, four pixels to one
    mask = np.zeros((480, 640), bool)
    mask[:, 300:340] = True
    uv = np.array([[300 - reach, 100.0], [300 - reach - 1, 100.0], [339 + reach, 5.0], [340 + reach, 5.0],
                   [320.0, 470.0], [np.nan, 240.0], [-50.0, 240.0]])
    assert memory.near(mask, uv).tolist() == [True, False, True, False, True, False, False]
    assert not memory.near(np.zeros((480, 640), np.uint8), uv).any()  # nothing in front
    assert memory.near(mask.astype(np.uint8) * 255, uv).tolist() == memory.near(mask, uv).tolist()
