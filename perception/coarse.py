"""A coarse, global look at the motion between two frames, for when the prediction fails.

The tracker predicts each frame's mesh from the previous estimates (constant velocity).
A lifted cloth accelerates, a frame gets dropped, a 15 Hz camera halves the rate: then
the object can move 100 px or more between frames, far beyond what the local
minimisation, the feature gate and the segmentation margin can reach.

``FrameMemory`` keeps the previous frame small and blurred, and offers two things:

- ``translation``: the object's dominant image motion since the previous frame, by phase
  correlation of the region around it at quarter resolution (a fraction of a
  millisecond; it finds a textured object's shift to a few pixels for motions of 150 px,
  and reports a low response where it cannot tell);
- ``agreement``: how well a hypothesis for the mesh explains the new frame: do its
  vertices, seen in the previous frame, land on pixels that look as they looked there
  (normalised correlation of the blurred grey values) and that hold a surface at the
  depth of the object?

The tracker scores its constant-velocity prediction, the previous mesh unmoved and the
mesh moved by the measured translation, and goes on from the best. It judges them by the
vertices seen in the previous frame away from anything that stood in front of the cloth
there (``near``): the stored frame is blurred, so a vertex beside an arm looks like the arm,
and on a plain cloth an arm's edges are all the contrast the image has, so the mesh moved
with the arm would agree best with them.

Images are (H, W) uint8 grey; pixel coordinates (P, 2) float (u, v) at full resolution.
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.geometry import pixel_index
from perception.raster import shrink

#: Below this correlation response the phase-correlation peak is no better than noise.
MIN_RESPONSE = 0.08
#: Standard deviation of the blur of the stored frame, stored pixels.
BLUR_SIGMA = 1.0


class FrameMemory:
    """The previous frame at 1/``scale`` resolution, blurred, for comparisons with the next.

    scale : full-resolution pixels per stored pixel; search_px : the largest motion looked
    for, full-resolution pixels
    """

    def __init__(self, scale: int = 4, search_px: int = 200):
        if int(scale) < 1:
            raise ValueError(f"FrameMemory.scale: expected an integer >= 1, got {scale!r}")
        self.scale = int(scale)
        self.search_px = int(search_px)
        self.previous: np.ndarray | None = None

    def small(self, grey: np.ndarray) -> np.ndarray:
        """(h, w) float32: ``grey`` downsampled and lightly blurred (so that a pixel or two of
        misalignment does not change what a comparison sees)."""
        return cv2.GaussianBlur(shrink(grey, self.scale).astype(np.float32), (0, 0), BLUR_SIGMA)

    @property
    def blur_reach_px(self) -> int:
        """How far (full-resolution pixels) a pixel's value spreads in the stored frame: three
        standard deviations of the blur, at the stored resolution (there the blur's weight
        has fallen to about 1 % of its centre's)."""
        return int(np.ceil(3 * BLUR_SIGMA * self.scale))

    def near(self, mask: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """(P,) bool: which points ``uv`` (P, 2) lie within ``blur_reach_px`` of ``mask`` (H, W)
        bool, full resolution: their stored values are mixed with the masked pixels'."""
        mask = np.asarray(mask, dtype=bool)
        if not mask.any():
            return np.zeros(len(uv), bool)
        reach = 2 * self.blur_reach_px + 1
        grown = cv2.dilate(mask.view(np.uint8), np.ones((reach, reach), np.uint8))
        h, w = mask.shape
        cols, rows, inside = pixel_index(uv, w, h)
        return inside & (grown[rows, cols] > 0)

    def push(self, small: np.ndarray) -> None:
        self.previous = small

    def translation(self, small: np.ndarray, box: tuple) -> tuple[np.ndarray, float] | None:
        """The dominant translation (2,) in full-resolution pixels of the content of ``box``
        (y0, y1, x0, x1, full resolution) from the previous frame to ``small``, and the
        phase-correlation response in [0, 1]; None when there is no previous frame."""
        if self.previous is None or self.previous.shape != small.shape:
            return None
        s = self.scale
        h, w = small.shape
        pad = self.search_px / s
        y0, y1, x0, x1 = (int(np.clip(v, 0, lim)) for v, lim in
                          ((box[0] / s - pad, h), (box[1] / s + pad, h), (box[2] / s - pad, w), (box[3] / s + pad, w)))
        if y1 - y0 < 8 or x1 - x0 < 8:
            return None
        a, b = self.previous[y0:y1, x0:x1], small[y0:y1, x0:x1]
        window = cv2.createHanningWindow((x1 - x0, y1 - y0), cv2.CV_32F)
        (dx, dy), response = cv2.phaseCorrelate(a, b, window)
        return np.array([dx, dy]) * s, float(response)

    def agreement(self, small: np.ndarray, uv_before: np.ndarray, uv_now: np.ndarray) -> float:
        """Normalised correlation in [-1, 1] of the previous image at ``uv_before`` (P, 2) and
        ``small`` at ``uv_now`` (P, 2); 0 when the points hold too little contrast to tell."""
        if self.previous is None or len(uv_before) < 3:
            return 0.0
        a = _sample(self.previous, uv_before / self.scale)
        b = _sample(small, uv_now / self.scale)
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < 3:
            return 0.0
        a, b = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
        spread = np.sqrt(np.sum(a * a) * np.sum(b * b))
        if spread < 1e-6 or a.std() < 2.0:  # grey levels: a plain surface says nothing
            return 0.0
        return float(np.sum(a * b) / spread)


def _sample(img: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Bilinear samples (P,) of ``img`` (h, w) at points (P, 2); NaN outside."""
    h, w = img.shape
    p = np.asarray(p, np.float64)
    inside = np.all(np.isfinite(p), axis=1) & (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)
    q = np.where(inside[:, None], p, 0.0)
    x0 = np.clip(np.floor(q[:, 0]).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(q[:, 1]).astype(np.int64), 0, h - 2)
    fx, fy = q[:, 0] - x0, q[:, 1] - y0
    v = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
         + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)
    return np.where(inside, v, np.nan)
