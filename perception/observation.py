"""What the tracker takes from one frame once the object is segmented.

An Observation holds the grey image for features, the object mask, the object's depth
smoothed within the mask (sensor noise averaged over a small window, never across the
object's edge), the matching range image for the depth term, and the object's outline
lifted to 3D for the boundary term.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ipc.messages import RGBDFrame
from perception.geometry import backproject, pixel_index, ray_lengths, rays
from perception.raster import bounding_box
from perception.segmentation import SHADOW_PX, contour_parts, valid_depth


@dataclass
class Observation:
    """grey : (H, W) uint8; mask : (H, W) bool object mask;
    depth_m : (H, W) float32 smoothed object depth along z, 0 off the object or unmeasured;
    range_m : (H, W) float32 the same as distance from the camera centre;
    outline_cam : (P, 3) float64 metres, the object's outline points;
    hidden_contour_cam : (Q, 3) float64 metres, the rest of its contour: where the image's
    border cuts it or something nearer hides it, which says nothing of where it ends;
    K : (3, 3)."""

    grey: np.ndarray
    mask: np.ndarray
    depth_m: np.ndarray
    range_m: np.ndarray
    outline_cam: np.ndarray
    hidden_contour_cam: np.ndarray
    K: np.ndarray

    def depth_at(self, xy: np.ndarray) -> np.ndarray:
        """(P,) float64 smoothed object depth at pixels (P, 2); 0 where none."""
        h, w = self.depth_m.shape
        cols, rows, inside = pixel_index(np.asarray(xy, np.float64), w, h)
        return np.where(inside, self.depth_m[rows, cols], 0.0).astype(np.float64)

    def points_at(self, xy: np.ndarray):
        """3D points (P, 3) at pixels (P, 2) and the (P,) bool mask of those with depth."""
        d = self.depth_at(xy)
        return backproject(np.asarray(xy, np.float64), d, self.K), d > 0


def smooth_depth_in_mask(depth_m: np.ndarray, mask: np.ndarray, window_px: int) -> np.ndarray:
    """Mean of valid object depths in a ``window_px`` square around each object pixel.

    Only pixels of ``mask`` with valid depth take part, so the object's edge is not blurred
    into the background. returns (H, W) float32, 0 off the mask or where nothing was measured.
    """
    out = np.zeros(depth_m.shape, np.float32)
    box = bounding_box(mask, pad=window_px // 2 + 1)
    if box is None:
        return out
    y0, y1, x0, x1 = box
    d = depth_m[y0:y1, x0:x1]
    m = mask[y0:y1, x0:x1] & valid_depth(d)
    if window_px <= 1:
        out[y0:y1, x0:x1] = np.where(m, d, 0.0)
        return out
    w = m.astype(np.float32)
    num = cv2.boxFilter(np.where(m, d, 0.0).astype(np.float32), -1, (window_px, window_px), normalize=False,
                        borderType=cv2.BORDER_CONSTANT)
    den = cv2.boxFilter(w, -1, (window_px, window_px), normalize=False, borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        sm = np.where((den > 0) & mask[y0:y1, x0:x1], num / den, 0.0)
    out[y0:y1, x0:x1] = sm
    return out


def grey_of(frame: RGBDFrame) -> np.ndarray:
    """(H, W) uint8 grey image of the frame's colour."""
    return cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)


def observe(frame: RGBDFrame, mask: np.ndarray, window_px: int = 5, occlusion_margin_m: float = 0.03,
            grey: np.ndarray | None = None, unsearched: np.ndarray | None = None) -> Observation:
    """Build the Observation of ``frame`` for the object ``mask`` (H, W) bool
    (``grey``: the frame's grey image when the caller already made it). The outline
    leaves out the stretches next to the frame's known occluders (``frame.occluder_mask``)
    and next to ``unsearched`` (H, W) bool pixels, where the segmentation stopped looking."""
    K = frame.camera.K
    grey = grey_of(frame) if grey is None else grey
    depth = smooth_depth_in_mask(frame.depth_m, mask, window_px)
    h, w = depth.shape
    rng = np.zeros_like(depth)
    # the contour lies in the mask's box; the pixels that decide whether it is hidden lie
    # within SHADOW_PX of it, plus one for the neighbours. With that padding the crop's
    # border meets the mask only where the image's border does.
    box = bounding_box(mask, pad=SHADOW_PX + 1)
    if box is None:
        empty = np.zeros((0, 3))
        return Observation(grey=grey, mask=mask.astype(bool), depth_m=depth, range_m=rng, outline_cam=empty,
                           hidden_contour_cam=empty, K=K)
    y0, y1, x0, x1 = box
    rng[y0:y1, x0:x1] = depth[y0:y1, x0:x1] * ray_lengths(K, w, h)[y0:y1, x0:x1]  # depth is 0 off the mask
    occluder = None if frame.occluder_mask is None else frame.occluder_mask[y0:y1, x0:x1]
    if unsearched is not None:
        cut = unsearched[y0:y1, x0:x1]
        occluder = cut if occluder is None else occluder | cut
    lifted = []
    for part in contour_parts(mask[y0:y1, x0:x1], frame.depth_m[y0:y1, x0:x1], occlusion_margin_m, occluder):
        oy, ox = np.divmod(part, x1 - x0)
        oy, ox = oy + y0, ox + x0
        od = depth[oy, ox]
        ok = od > 0
        uv = np.column_stack([ox[ok], oy[ok]]).astype(np.float64)
        lifted.append(rays(uv, K) * od[ok, None])
    return Observation(grey=grey, mask=mask.astype(bool), depth_m=depth, range_m=rng, outline_cam=lifted[0],
                       hidden_contour_cam=lifted[1], K=K)
