"""Reference masks of an object through a recording, for scoring a tracker where no
annotated masks exist (a depth band and a colour model, followed frame to frame).

The procedure, for frames of registered colour and depth:

1. Seed (first frame): a given mask (e.g. drawn by hand), or found automatically: the
   measured pixels that are not skin-coloured (YCrCb rule, ``skin_mask``), largest
   connected region. Hands holding the object are what this excludes.
2. Colour model, from the first frame only (so it cannot drift): two Gaussians over the
   chroma (a*, b* of CIE Lab; lightness is left out, so the object's own shadows and
   shading stay object), one over the seed (eroded, away from its edge) and one over the
   other measured pixels of the depth band around it (hands, arms, anything else at the
   object's depth). An object of the same hue as what holds it cannot be told apart.
3. Every frame: candidates are pixels with depth inside the band of the previous frame's
   mask (its 2nd..98th depth percentile widened by ``depth_margin_m``), within
   ``max_motion_px`` of the previous mask, whose colour is likelier under the object's
   Gaussian. An opening removes speckle.
4. Colour alone misses the object's rim where depth and colour are not quite registered
   (a few pixels on a Kinect v1) and where its chroma is off (reflections, shadows). So the
   mask grows by up to ``grow_px`` into pixels of the band that are joined to it without a
   depth step (no 8-neighbour differs by more than ``depth_step_m``) and are not
   skin-coloured: a hand behind or in front of the object is cut off by its depth step or
   its colour, the object's own rim is not. A closing
   and hole filling mend depth dropouts; regions smaller than ``min_area_px`` go.

Everything is deterministic: the same frames and seed give the same masks. Pure numerics
on arrays; reading and writing masks is the caller's business.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from perception.raster import disc, reached_from

log = logging.getLogger(__name__)


class ReferenceMaskError(ValueError):
    """The frames cannot give a reference mask (no seed, object lost); one line."""


@dataclass(frozen=True)
class MaskConfig:
    """Knobs of the procedure (module docstring).

    depth_margin_m : widening of the previous mask's depth range, metres
    max_motion_px : how far the object's outline may move between frames, pixels
    min_area_px : smaller regions are dropped, pixels
    open_px, close_px : sizes of the cleaning opening and closing, pixels
    edge_px : the colour model learns the object from its seed eroded by this, pixels
    grow_px : how far the mask may grow into depth-continuous pixels, pixels
    depth_step_m : a depth difference between neighbours that separates surfaces, metres
    """

    depth_margin_m: float = 0.05
    max_motion_px: int = 40
    min_area_px: int = 150
    open_px: int = 3
    close_px: int = 7
    edge_px: int = 3
    grow_px: int = 6
    depth_step_m: float = 0.012

    def __post_init__(self):
        for name in ("depth_margin_m", "depth_step_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"MaskConfig.{name}: expected a positive number, got {v!r}")
        for name in ("max_motion_px", "min_area_px", "open_px", "close_px", "edge_px", "grow_px"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"MaskConfig.{name}: expected an integer >= 1, got {v!r}")

    def to_dict(self) -> dict:
        return asdict(self)


def skin_mask(rgb: np.ndarray) -> np.ndarray:
    """(H, W) bool: skin-coloured pixels of rgb (H, W, 3) uint8, by the classic YCrCb box
    (133 <= Cr <= 180, 77 <= Cb <= 127, Chai and Ngan 1999) with a brightness floor."""
    ycrcb = cv2.cvtColor(rgb, cv2.COLOR_RGB2YCrCb)
    y, cr, cb = ycrcb[..., 0], ycrcb[..., 1], ycrcb[..., 2]
    return (y > 40) & (cr >= 133) & (cr <= 180) & (cb >= 77) & (cb <= 127)


def largest_region(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the largest 8-connected region of ``mask`` (empty if there is none)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, bool)
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: ``mask`` with every hole (background not connected to the border) filled."""
    h, w = mask.shape
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = mask
    flood = padded.copy()
    cv2.floodFill(flood, np.zeros((h + 4, w + 4), np.uint8), (0, 0), 1)
    return mask | (flood[1:-1, 1:-1] == 0)


def automatic_seed(rgb: np.ndarray, depth_m: np.ndarray, config: MaskConfig = MaskConfig()) -> np.ndarray:
    """First-frame seed: the largest region of measured, non-skin pixels. rgb (H, W, 3) uint8,
    depth_m (H, W) float32 metres (0 or NaN = none). Returns (H, W) bool."""
    measured = np.isfinite(depth_m) & (depth_m > 0)
    candidate = measured & ~skin_mask(rgb)
    candidate = cv2.morphologyEx(candidate.astype(np.uint8), cv2.MORPH_OPEN, disc(config.open_px)).astype(bool)
    seed = largest_region(candidate)
    if seed.sum() < config.min_area_px:
        raise ReferenceMaskError("no automatic seed: no region of measured, non-skin pixels is large enough; "
                                 "give a seed mask")
    return seed


def _chroma(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 2) float64: a*, b* of CIE Lab (OpenCV's 8-bit scale, 128 = grey)."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB)[..., 1:].astype(np.float64)


class ColourModel:
    """Object against surroundings: a Gaussian over (a*, b*) chroma for each (module docstring, step 2)."""

    def __init__(self, object_lab: np.ndarray, other_lab: np.ndarray):
        self._gaussians = [self._fit(object_lab, "object"), self._fit(other_lab, "surroundings")]

    @staticmethod
    def _fit(samples: np.ndarray, what: str):
        if len(samples) < 10:
            raise ReferenceMaskError(f"colour model: too few {what} pixels ({len(samples)})")
        mean = samples.mean(axis=0)
        cov = np.cov(samples, rowvar=False) + np.eye(samples.shape[1]) * 4.0  # a floor: a flat patch is not a point
        inv = np.linalg.inv(cov)
        return mean, inv, 0.5 * np.linalg.slogdet(cov)[1]

    @classmethod
    def learn(cls, rgb: np.ndarray, depth_m: np.ndarray, seed: np.ndarray, config: MaskConfig) -> ColourModel:
        lab = _chroma(rgb)
        inner = cv2.erode(seed.astype(np.uint8), disc(config.edge_px)).astype(bool)
        if inner.sum() < 10:
            inner = seed
        band = depth_band(depth_m, seed, config.depth_margin_m)
        outer = band & ~cv2.dilate(seed.astype(np.uint8), disc(config.edge_px)).astype(bool)
        if outer.sum() < 10:  # nothing else at the object's depth: contrast it with everything else
            outer = ~cv2.dilate(seed.astype(np.uint8), disc(config.edge_px)).astype(bool)
        return cls(lab[inner], lab[outer])

    def is_object(self, rgb: np.ndarray, where: np.ndarray) -> np.ndarray:
        """(H, W) bool: pixels in ``where`` whose colour is likelier the object's."""
        out = np.zeros(where.shape, bool)
        lab = _chroma(rgb)[where]
        scores = []
        for mean, inv, half_logdet in self._gaussians:
            d = lab - mean
            scores.append(-0.5 * np.einsum("ij,jk,ik->i", d, inv, d) - half_logdet)
        out[where] = scores[0] > scores[1]
        return out


def depth_band(depth_m: np.ndarray, previous: np.ndarray, margin_m: float) -> np.ndarray:
    """(H, W) bool: measured pixels within the depth range of ``previous`` (its 2nd..98th
    percentile) widened by ``margin_m`` on both sides."""
    measured = np.isfinite(depth_m) & (depth_m > 0)
    z = depth_m[previous & measured]
    if len(z) == 0:
        raise ReferenceMaskError("the previous mask has no measured depth")
    lo, hi = np.percentile(z, [2, 98])
    return measured & (depth_m >= lo - margin_m) & (depth_m <= hi + margin_m)


def depth_steps(depth_m: np.ndarray, step_m: float) -> np.ndarray:
    """(H, W) bool: pixels with no depth or with an 8-neighbour whose depth differs by more than
    ``step_m`` (or has none): the seams between surfaces."""
    z = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, np.nan).astype(np.float32)
    filled = np.where(np.isnan(z), np.float32(-1e3), z)  # no depth: a step to everything
    kernel = np.ones((3, 3), np.uint8)
    high = cv2.dilate(filled, kernel) - filled
    low = filled - cv2.erode(filled, kernel)
    return np.isnan(z) | (high > step_m) | (low > step_m)


def grow_along_surface(core: np.ndarray, allowed: np.ndarray, depth_m: np.ndarray, config: MaskConfig) -> np.ndarray:
    """(H, W) bool: ``core`` and the pixels of ``allowed`` within ``grow_px`` of it that join it
    without crossing a depth step (4-connected, so a diagonal of noise does not bridge a seam)."""
    reach = cv2.dilate(core.astype(np.uint8), disc(config.grow_px)).astype(bool)
    smooth = allowed & reach & ~depth_steps(depth_m, config.depth_step_m)
    return reached_from(core, smooth | core, connectivity=4)


def next_mask(rgb: np.ndarray, depth_m: np.ndarray, previous: np.ndarray, model: ColourModel,
              config: MaskConfig) -> np.ndarray:
    """The object's mask in a frame, given the previous frame's (module docstring, step 3)."""
    near = cv2.dilate(previous.astype(np.uint8), disc(config.max_motion_px)).astype(bool)
    where = depth_band(depth_m, previous, config.depth_margin_m) & near
    core = model.is_object(rgb, where)
    core = cv2.morphologyEx(core.astype(np.uint8), cv2.MORPH_OPEN, disc(config.open_px)).astype(bool)
    mask = grow_along_surface(core, where & ~skin_mask(rgb), depth_m, config).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, disc(config.close_px)) & near.astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= config.min_area_px
    return fill_holes(keep[labels])


def follow_object(frames: Iterable[tuple[np.ndarray, np.ndarray]], seed: np.ndarray | None = None,
                  config: MaskConfig = MaskConfig()) -> Iterator[np.ndarray]:
    """Reference masks through a recording.

    frames : iterable of (rgb (H, W, 3) uint8 RGB, depth_m (H, W) float32 metres, 0/NaN = none)
    seed : (H, W) bool object mask in the first frame, or None for ``automatic_seed``
    yields (H, W) bool per frame (the first is the seed refined like every other frame)
    raises ReferenceMaskError when the object vanishes (empty mask)
    """
    model = None
    previous = None
    for i, (rgb, depth_m) in enumerate(frames):
        if model is None:
            if seed is None:
                seed = automatic_seed(rgb, depth_m, config)
            seed = np.asarray(seed, bool)
            if seed.shape != depth_m.shape or not seed.any():
                raise ReferenceMaskError(f"seed mask: expected a non-empty {depth_m.shape} mask, got "
                                         f"{seed.shape} with {int(seed.sum())} pixels")
            model = ColourModel.learn(rgb, depth_m, seed, config)
            previous = seed
        try:
            mask = next_mask(rgb, depth_m, previous, model, config)
        except ReferenceMaskError as exc:
            raise ReferenceMaskError(f"frame {i}: {exc}") from None
        if not mask.any():
            raise ReferenceMaskError(f"frame {i}: the object's mask is empty (lost it)")
        log.debug("frame %d: %d pixels", i, int(mask.sum()))
        previous = mask
        yield mask
