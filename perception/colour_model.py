"""Telling the cloth from what surrounds it by colour, where depth cannot.

A cloth lying on a table, or held against a shirt, is continuous in depth with what is
under or behind it, so depth segmentation grows into the table. Their colours usually
differ. From the first frame the tracker knows both: the object's pixels (its mask) and
the surroundings' (a ring around the mask). ``ColourModel`` keeps a colour histogram of
each (CIE Lab, quantised) and gives each pixel the probability that it is the object.
Where the two histograms barely differ (a grey cloth on a grey table) the model says it
cannot tell (``informative`` False) and the tracker segments by depth alone. A second pair
of histograms leaves brightness out (``chroma_probability``): a fold turned away from the
light darkens a cloth's colours beyond any brightness it showed first, not their hue.

Images are (H, W, 3) uint8 RGB; masks (H, W) bool; probabilities (H, W) float32 in [0, 1].
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

from perception.raster import disc

#: bins of L, a and b: brightness more coarsely (shading changes it) than chroma (cloth and
#: table are often both near grey, a few units of a and b apart)
BINS = (8, 32, 32)
#: Bhattacharyya distance between the two histograms above which colour separates them
MIN_SEPARATION = 0.35


def _bin_index(rgb: np.ndarray) -> np.ndarray:
    """(h, w) int: each pixel's bin in the quantised Lab histogram."""
    lab = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2LAB)
    idx = [(lab[..., c].astype(np.int32) * n) >> 8 for c, n in enumerate(BINS)]
    return (idx[0] * BINS[1] + idx[1]) * BINS[2] + idx[2]


def _object_share(obj: np.ndarray, bg: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """(bins,) float32 lookup table of the probability that a colour is the object's, from the
    normalised histograms ``obj`` and ``bg`` of ``shape``: each spread over neighbouring bins
    (a little shading or noise moves a colour by a bin); a colour neither showed counts as
    not the object."""
    obj = gaussian_filter(obj.reshape(shape), 1.0, mode="nearest").ravel()
    bg = gaussian_filter(bg.reshape(shape), 1.0, mode="nearest").ravel()
    return ((obj + 1e-6) / (obj + bg + 1e-4)).astype(np.float32)


class ColourModel:
    """Colour histograms of an object and of its surroundings in one frame.

    rgb : (H, W, 3) uint8; mask : (H, W) bool, the object; ring_px : width of the ring
    around the mask that stands for the surroundings
    """

    def __init__(self, rgb: np.ndarray, mask: np.ndarray, ring_px: int = 40):
        n = int(np.prod(BINS))
        bins = _bin_index(rgb)
        ring = cv2.dilate(mask.astype(np.uint8), disc(ring_px))
        ring = ring.astype(bool) & ~mask
        obj = np.bincount(bins[mask], minlength=n).astype(np.float64)
        bg = np.bincount(bins[ring], minlength=n).astype(np.float64)
        obj /= max(obj.sum(), 1.0)
        bg /= max(bg.sum(), 1.0)
        self.separation = float(np.sqrt(max(0.0, 1.0 - np.sum(np.sqrt(obj * bg)))))  # Bhattacharyya (Hellinger) distance
        self.informative = bool(ring.any() and self.separation >= MIN_SEPARATION)
        self._table = _object_share(obj, bg, BINS)
        chroma = (BINS[0], BINS[1] * BINS[2])
        self._chroma_table = _object_share(obj.reshape(chroma).sum(axis=0), bg.reshape(chroma).sum(axis=0), BINS[1:])

    def probability(self, rgb: np.ndarray) -> np.ndarray:
        """(h, w) float32: probability that each pixel of ``rgb`` (h, w, 3) is the object,
        smoothed over a few pixels (sensor noise flips single pixels' bins). Looked up at
        half resolution: a quarter of the colour conversions, and the smoothing blurs
        finer detail away anyway. Halved by OpenCV's area average to exactly half the size,
        rounded up, as the result is brought back: at an odd size its slow path (0.6 ms on a
        401 x 301 crop), but the block means of ``perception.raster.shrink`` moved the real
        foam tube's coverage from 0.82 to 0.79 at worst, under the 0.8 it must keep (3 of its 80
        frames; docs/results.md, "Real recordings")."""
        h, w = rgb.shape[:2]
        half = cv2.resize(rgb, ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA)
        p = cv2.blur(self._table[_bin_index(half)], (3, 3))
        return cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR)

    def chroma_probability(self, rgb: np.ndarray) -> np.ndarray:
        """(h, w) float32: the same by hue and saturation alone (Lab's a and b), whatever the
        brightness (a cloth in the shade is still the cloth), looked up on every pixel of
        ``rgb`` (h, w, 3) and smoothed over 3x3 (pass an image already read on every other
        pixel for the cost of ``probability``)."""
        return cv2.blur(self.chroma_probability_at(rgb), (3, 3))

    def chroma_probability_at(self, rgb: np.ndarray) -> np.ndarray:
        """(...) float32: ``chroma_probability`` of each colour of ``rgb`` (..., 3) uint8 (a few
        pixels' colours, or an image), each alone, unsmoothed."""
        rgb = np.asarray(rgb, np.uint8)
        if not rgb.size:
            return np.zeros(rgb.shape[:-1], np.float32)
        bins = _bin_index(rgb.reshape(1, -1, 3)).reshape(rgb.shape[:-1]) % (BINS[1] * BINS[2])
        return self._chroma_table[bins]
