"""Faults a recording did not have, injected into its frames: something passing in front of
the object, depth going missing, and the view cut to another scene.

A real recording shows a tracker what a real sensor and a real object do, but seldom what
goes wrong while a robot works: its own arm passing in front of the cloth, a sensor losing
depth over part of the object or for a whole frame, a camera bumped to another view. Put
into a recording whose clean run is known, each fault's effect can be measured against that
run (``benchmarks/real_faults.py``); dropped frames need no function here (track every
other frame).

Pure functions on ``RGBDFrame``s (rgb (H, W, 3) uint8; depth_m (H, W) float32 metres, 0 or
NaN missing); boxes are (y0, y1, x0, x1) pixel bounds, end exclusive, as
``perception.raster.bounding_box`` gives them.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ipc.messages import RGBDFrame
from perception.segmentation import valid_depth

#: An arm's colour under room light, RGB: a bar of it hides the object as a forearm would.
ARM_RGB = (196, 152, 128)


def _check_box(box, shape) -> tuple[int, int, int, int]:
    y0, y1, x0, x1 = (int(v) for v in box)
    h, w = shape
    if not (0 <= y0 < y1 <= h and 0 <= x0 < x1 <= w):
        raise ValueError(f"Expected a box (y0, y1, x0, x1) inside a {h}x{w} image, got {tuple(box)}")
    return y0, y1, x0, x1


def bar_in_front(frame: RGBDFrame, box, progress: float, width_px: int, gap_m: float,
                 rgb=ARM_RGB) -> tuple[RGBDFrame, np.ndarray]:
    """``frame`` with a bar ``width_px`` wide in front of the object, and the bar's mask.

    The bar reaches down from the image's top edge to a fifth of the box's height below the
    box, as an arm reaching in from above, and sweeps across the box from left to right:
    at ``progress`` 0 its right edge is at the box's left side, at 1 its left edge is at
    the box's right side. It stands ``gap_m`` metres in front of the nearest tenth of the
    depths measured in the box (a flat surface facing the camera), shaded across its width
    like a cylinder so that it is not one flat colour.

    box : (y0, y1, x0, x1) int, e.g. the object's bounding box over the recording
    progress : float in [0, 1]; width_px : int >= 1; gap_m : float > 0
    returns (RGBDFrame, (H, W) bool mask of the bar); the frame unchanged where the bar is
        not, and the same frame when the bar lies outside the image or the box has no depth
    """
    h, w = frame.depth_m.shape
    y0, y1, x0, x1 = _check_box(box, (h, w))
    if not 0.0 <= progress <= 1.0:
        raise ValueError(f"Expected progress in [0, 1], got {progress}")
    if int(width_px) < 1 or not gap_m > 0:
        raise ValueError(f"Expected width_px >= 1 and gap_m > 0, got {width_px} and {gap_m}")
    width_px = int(width_px)
    left = int(round(x0 - width_px + progress * (x1 - x0 + width_px)))
    cols = np.arange(max(left, 0), min(left + width_px, w))
    bottom = min(h, y1 + (y1 - y0) // 5)
    mask = np.zeros((h, w), bool)
    box_depth = frame.depth_m[y0:y1, x0:x1]
    measured = box_depth[valid_depth(box_depth)]
    if not len(cols) or not len(measured):
        return frame, mask
    mask[:bottom, cols] = True
    depth = frame.depth_m.copy()
    depth[mask] = max(float(np.percentile(measured, 10)) - gap_m, 0.05)
    across = (cols - (left + 0.5 * width_px)) / (0.5 * width_px)  # -1 .. 1 over the bar
    shade = np.sqrt(np.clip(1.0 - 0.8 * across**2, 0.0, 1.0))
    colour = (np.asarray(rgb, np.float64)[None, :] * shade[:, None]).round().clip(0, 255).astype(np.uint8)
    image = frame.rgb.copy()
    image[:bottom, cols] = colour[None, :, :]
    return dataclasses.replace(frame, rgb=image, depth_m=depth), mask


def depth_holes(frame: RGBDFrame, box, fraction: float, rng: np.random.Generator,
                blob_px: int = 15) -> RGBDFrame:
    """``frame`` with depth missing (0) in round blobs of about ``blob_px`` pixels' radius
    inside ``box``, until about ``fraction`` of the box's measured pixels have none: what a
    structured-light sensor does on dark, shiny or steeply turned parts of a cloth.

    fraction : float in [0, 1]; rng : numpy Generator (the blobs' places); blob_px : int >= 1
    """
    h, w = frame.depth_m.shape
    y0, y1, x0, x1 = _check_box(box, (h, w))
    if not 0.0 <= fraction <= 1.0 or int(blob_px) < 1:
        raise ValueError(f"Expected fraction in [0, 1] and blob_px >= 1, got {fraction} and {blob_px}")
    inside = valid_depth(frame.depth_m[y0:y1, x0:x1])
    total = int(inside.sum())
    blobs = np.zeros((y1 - y0, x1 - x0), np.uint8)  # drawn in the box: a blob on its rim is cut there
    for _ in range(10_000):  # bounded: a blob over unmeasured pixels only takes nothing
        if total == 0 or (blobs.view(bool) & inside).sum() >= fraction * total:
            break
        centre = (int(rng.integers(0, x1 - x0)), int(rng.integers(0, y1 - y0)))
        cv2.circle(blobs, centre, int(rng.integers(max(1, blob_px // 2), blob_px + 1)), 1, -1)
    depth = frame.depth_m.copy()
    depth[y0:y1, x0:x1][blobs.view(bool)] = 0.0
    return dataclasses.replace(frame, depth_m=depth)


def no_depth(frame: RGBDFrame) -> RGBDFrame:
    """``frame`` with no depth at all: a sensor that sent a colour image and an empty depth image."""
    return dataclasses.replace(frame, depth_m=np.zeros_like(frame.depth_m))


def cut_to(frame: RGBDFrame, other: RGBDFrame) -> RGBDFrame:
    """``other``'s images in ``frame``'s place (its camera, time and sequence number): the
    view cut to another scene by the same camera, as one knocked aside would show it.
    Images of another size are resized to ``frame``'s."""
    h, w = frame.depth_m.shape
    rgb, depth = other.rgb, other.depth_m
    if depth.shape != (h, w):
        rgb = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
        depth = cv2.resize(np.nan_to_num(depth, nan=0.0), (w, h), interpolation=cv2.INTER_NEAREST)
    return dataclasses.replace(frame, rgb=rgb, depth_m=depth, occluder_mask=None)
