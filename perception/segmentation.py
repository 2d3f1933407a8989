"""Depth-based foreground segmentation of the tracked object.

Works on depth images (H, W) float32 metres with 0/NaN for missing. Two situations:

- First frame, no mask given (``find_object``): remove the large planes that touch the
  image border (floor, table, wall), split what is left into regions of continuous depth,
  and take the largest region that is not itself background.
- Tracking (``segment_tracked``): the object is the union of the depth-continuous regions
  that overlap the mesh predicted from the previous frame, searched only within a margin
  around that prediction and a depth band around the mesh. A hand or gripper holding the
  cloth is cut off at the margin; a wall or floor beyond the band never joins. With the
  empty workspace known, what differs from it and joins that object is the object too,
  with or without depth (``_joined_differing``); without it, what has the object's colour
  where depth could not place it and joins that object (``_joined_unplaced``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from perception.colour_model import ColourModel
from perception.geometry import backproject
from perception.raster import blow_up, bounding_box, disc, reached_from

log = logging.getLogger(__name__)


#: a tracked object's extent is looked for within the prediction's bounding box grown by
#: this many search margins
EXTENT_REACH = 4
#: gaps without depth up to this wide (pixels) do not part the extent, when the surface has
#: about the same depth on both sides
BRIDGE_PX = 8


@dataclass(frozen=True)
class Segment:
    """The object found around a prediction.

    mask : (H, W) bool, the object
    unsearched : (H, W) bool, the pixels beyond the search (the search margin; with the
        empty workspace known, the prediction's box grown by ``EXTENT_REACH`` margins): the
        mask stops there because the search did, so its outline there is not the object's edge
    leak : in [0, 1], the fraction of the mask's edge that runs along the unsearched pixels
        (near 0 when the object lies within the search; high when it is continuous with a
        surface that goes on, such as a table the cloth lies on)
    extent : (H, W) bool, the mask and the pixels of the object's colour joined to it beyond
        the search (within the prediction's box grown by ``EXTENT_REACH`` margins); None when colour cannot tell the
        object from its surroundings. A mesh that lost part of the object (squeezed into what
        it still covers while the rest moved on) predicts a search that misses that part, and
        only the extent still sees it.
    """

    mask: np.ndarray
    unsearched: np.ndarray
    leak: float = 0.0
    extent: np.ndarray | None = None


@dataclass(frozen=True)
class SegmentationConfig:
    """Tuning of the depth segmentation (metres and pixels).

    edge_jump_m, edge_jump_rel : neighbouring pixels belong to one surface when their depths
        differ by less than ``edge_jump_m + edge_jump_rel * depth``
    search_margin_px : how far beyond the predicted mesh outline the object may have moved
    depth_band_m : how far in front of / behind the predicted mesh the object may be
    min_region_px : regions smaller than this are noise
    plane_inlier_m : RANSAC plane tolerance when removing support planes
    plane_min_fraction : a plane must hold this fraction of valid pixels to be background
    """

    edge_jump_m: float = 0.02
    edge_jump_rel: float = 0.02
    search_margin_px: int = 30
    depth_band_m: float = 0.15
    min_region_px: int = 150
    plane_inlier_m: float = 0.012
    plane_min_fraction: float = 0.12
    max_planes: int = 3


def valid_depth(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) bool: finite and positive depth."""
    return np.isfinite(depth_m) & (depth_m > 0)


def depth_edges(depth_m: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(H, W) bool: pixels next to a depth discontinuity (or to missing depth)."""
    return _steps(depth_m, cfg, into_missing=True)


def _jumps(depth_m: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(H, W) bool: pixels with depth next to a pixel with depth on another surface."""
    return _steps(depth_m, cfg, into_missing=False)


def _steps(depth_m: np.ndarray, cfg: SegmentationConfig, into_missing: bool) -> np.ndarray:
    """The pixels on both sides of each step in depth between neighbours of more than
    ``edge_jump_m + edge_jump_rel * depth``; with ``into_missing``, a step from missing depth
    (left or above) to measured depth counts too."""
    d = np.where(valid_depth(depth_m), depth_m, 0.0).astype(np.float32)
    tol = cfg.edge_jump_m + cfg.edge_jump_rel * d
    dx = (np.abs(np.diff(d, axis=1)) > np.minimum(tol[:, 1:], tol[:, :-1])) & (d[:, 1:] > 0)
    dy = (np.abs(np.diff(d, axis=0)) > np.minimum(tol[1:, :], tol[:-1, :])) & (d[1:, :] > 0)
    if not into_missing:
        dx &= d[:, :-1] > 0
        dy &= d[:-1, :] > 0
    edge = np.zeros(d.shape, bool)
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    return edge


def _regions(candidate: np.ndarray, depth_m: np.ndarray, cfg: SegmentationConfig, edges: np.ndarray | None = None):
    """Connected regions of continuous depth inside ``candidate`` (H, W) bool; ``edges`` is
    ``depth_edges(depth_m, cfg)`` when the caller has it already."""
    fg = candidate & ~(depth_edges(depth_m, cfg) if edges is None else edges)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8), connectivity=4)
    return n, labels, stats


def _grow(region: np.ndarray, candidate: np.ndarray) -> np.ndarray:
    """Give back the one-pixel rims that the edge test shaved off a region."""
    grown = cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return region | (grown & candidate)


def segment_tracked(depth_m: np.ndarray, predicted_mask: np.ndarray, z_range: tuple[float, float],
                    cfg: SegmentationConfig = SegmentationConfig(), hidden_mask: np.ndarray | None = None,
                    rgb: np.ndarray | None = None, colour: ColourModel | None = None,
                    not_object: np.ndarray | None = None, with_extent: bool = True,
                    differs: np.ndarray | None = None) -> Segment:
    """Object mask in a frame, given where the object is predicted to be.

    depth_m : (H, W) float32 metres, 0/NaN missing
    predicted_mask : (H, W) bool, the predicted mesh drawn into the image
    z_range : (z_min, z_max) metres, depth extent of the predicted mesh
    hidden_mask : (H, W) bool, where the prediction has parts hidden behind something nearer,
        or None. A region in the search margin next to them joins even without overlapping
        the prediction: a hidden part comes out from behind its occluder a little away from
        where the motion prior carried it.
    rgb : (H, W, 3) uint8 and colour : the object's ColourModel, or None. When the object
        found by depth runs on beyond the search (a cloth on a table is continuous in depth
        with the table) and colour tells the object from its surroundings, pixels that look
        like the surroundings are left out: outside the prediction
        unless they are more likely the object than not, inside it only where they are
        clearly not, in areas wider than a print's patches or joined to the surroundings
        outside it (``_uncovered``). Where a real part of the prediction went unfound and
        the empty workspace is not known, the pixels of the object's colour that depth could
        not place join the object (``_joined_unplaced``). With colour, the Segment also has
        the object's extent beyond the search (``Segment.extent``).
    not_object : (H, W) bool, pixels that cannot be the object (a known occluder, the empty
        workspace), or None; they are left out of the mask, and the extent does not reach
        across them
    with_extent : False leaves ``Segment.extent`` None, for a caller that looks it up itself
        (``object_extent``), e.g. on another thread
    differs : (H, W) bool, the pixels that differ from the empty workspace
        (``perception.background.differs_from_background``), or None when it is not known.
        With it, the object also takes in the differing pixels joined to what depth found,
        beyond the search (within the prediction's box grown by ``EXTENT_REACH`` margins),
        with or without depth (``_joined_differing``); the search then reaches that box.
    returns Segment; its mask is empty when nothing of the object is seen
    """
    out = np.zeros(predicted_mask.shape, bool)
    unsearched = np.ones(predicted_mask.shape, bool)
    # Work in the prediction's bounding box grown by the search margin: the rest of the
    # image cannot hold the object.
    box = bounding_box(predicted_mask, pad=cfg.search_margin_px + 1)
    if box is None:
        return Segment(out, unsearched)
    y0, y1, x0, x1 = box
    pred = predicted_mask[y0:y1, x0:x1]
    depth = depth_m[y0:y1, x0:x1]
    valid = valid_depth(depth)
    dist = cv2.distanceTransform((~pred).astype(np.uint8), cv2.DIST_L2, 3)
    search = dist <= cfg.search_margin_px
    unsearched[y0:y1, x0:x1] = ~search
    d = np.where(valid, depth, 0.0)
    candidate = valid & search & (d > z_range[0] - cfg.depth_band_m) & (d < z_range[1] + cfg.depth_band_m)
    edges = depth_edges(depth, cfg)
    regions = _regions(candidate, depth, cfg, edges)
    region, leak = _object_regions(regions, candidate, pred, dist, hidden_mask, y0, x0, cfg)
    by_colour = colour is not None and rgb is not None and colour.informative
    p = None
    if by_colour and leak > 0.1:
        # Depth runs on beyond the search: the object lies on something of its own depth
        # (a table). Colour may tell them apart.
        p = colour.probability(rgb[y0:y1, x0:x1])
        candidate &= (p >= 0.5) | (pred & ~_uncovered(pred, p))
        regions = _regions(candidate, depth, cfg, edges)
        region, leak = _object_regions(regions, candidate, pred, dist, hidden_mask, y0, x0, cfg)
    if by_colour and differs is None and np.count_nonzero(pred & ~region) >= cfg.min_region_px:
        # A real part of the prediction went unfound: perhaps a part depth could not place.
        if p is None:
            p = colour.probability(rgb[y0:y1, x0:x1])
        _, labels, stats = regions
        placed = stats[:, cv2.CC_STAT_AREA] >= cfg.min_region_px
        placed[0] = False
        specks = candidate & ~placed[labels]  # on a step in depth (label 0) or in too small a region
        region = _joined_unplaced(region, (~valid & pred) | specks, p, search)
    out[y0:y1, x0:x1] = region
    excluded = None if not_object is None else np.asarray(not_object, bool)
    if excluded is not None:
        out &= ~excluded
    if differs is not None:
        allowed = np.asarray(differs, bool)
        if excluded is not None:
            allowed = allowed & ~excluded
        out &= allowed  # what does not differ from the empty workspace is not the object
        if out.any():
            out, unsearched, leak = _joined_differing(out, allowed, depth_m, predicted_mask, z_range, cfg)
    if not by_colour:
        return Segment(out, unsearched, leak)
    extent = object_extent(out, depth_m, predicted_mask, rgb, colour, cfg, not_object) if with_extent else None
    return Segment(out, unsearched, leak, extent)


def _joined_unplaced(region: np.ndarray, unplaced: np.ndarray, p: np.ndarray, search: np.ndarray) -> np.ndarray:
    """``region`` with the pixels of ``unplaced`` in the ``search`` that have the object's
    colour (``p`` >= 0.5), joined to it through each other's 8 neighbours. Box-sized arrays.

    ``unplaced`` are the pixels depth could not place: those without depth where the object
    was predicted, and those with depth in the search's band on a step in depth or in a speck
    of continuous depth smaller than a region. A part of the cloth turned steeply away from
    the camera (the near slope of a cloth lifted off a table, a fold seen edge-on) loses most
    of its depth and breaks the rest into specks between steps; it is still the cloth's
    colour, and the mesh still covers it. Beyond the prediction a pixel without depth says
    nothing: many sensors measure little but the object (a grey shirt behind a grey foam
    tube, all without depth, stays out); nor does a surface that depth places join, other
    than its rim."""
    return reached_from(region, region | (search & (p >= 0.5) & unplaced))


def _joined_differing(mask: np.ndarray, differs: np.ndarray, depth_m: np.ndarray, predicted_mask: np.ndarray,
                      z_range: tuple[float, float], cfg: SegmentationConfig):
    """The object ``mask`` (H, W) bool that depth found, with the pixels of ``differs`` (H, W)
    bool (what differs from the empty workspace and may be the object) joined to it.

    Depth alone misses much of a cloth lying on a table: the sensor loses a surface seen at
    a grazing angle, and what it measures is continuous with the table, while colour models
    take a pale cloth on a grey table for the table. Against the empty workspace such a
    part still differs. A differing pixel joins through its 8 neighbours, within the
    prediction's box grown by ``EXTENT_REACH`` search margins. One with depth joins only
    within the search's depth band of the prediction and not on a step in depth (another
    surface); pixels of ``mask`` on a step stay in it but join nothing through it. One
    without depth joins freely: a surface seen at a grazing angle changes depth by a
    centimetre or more a pixel, so no test of its neighbours' depths tells it from the band
    the sensor loses beside a nearer object, and an object in front that differs and lies
    beyond such a band joins, unless it is masked (a known occluder, or one the tracker
    found in front, ``perception.occluders``).

    Returns (mask, unsearched, leak) as ``Segment``'s: unsearched is what lies outside the
    box, leak the fraction of the mask's edge on the box's rim inside the image.
    """
    h, w = mask.shape
    y0, y1, x0, x1 = bounding_box(predicted_mask, pad=EXTENT_REACH * cfg.search_margin_px)
    found = mask[y0:y1, x0:x1]
    depth = depth_m[y0:y1, x0:x1]
    valid = valid_depth(depth)
    d = np.where(valid, depth, 0.0)
    with_depth = (d > z_range[0] - cfg.depth_band_m) & (d < z_range[1] + cfg.depth_band_m) & ~_jumps(depth, cfg)
    passable = (found | differs[y0:y1, x0:x1]) & (with_depth | ~valid)
    grown = reached_from(found, passable) | found
    out = np.zeros((h, w), bool)
    out[y0:y1, x0:x1] = grown
    unsearched = np.ones((h, w), bool)
    unsearched[y0:y1, x0:x1] = False
    edge = grown & ~cv2.erode(grown.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                              borderValue=0).astype(bool)
    rim = np.zeros_like(grown)  # the box's sides that are not the image's
    rim[0, :] |= y0 > 0
    rim[-1, :] |= y1 < h
    rim[:, 0] |= x0 > 0
    rim[:, -1] |= x1 < w
    leak = float((edge & rim).sum() / max(1, edge.sum()))
    return out, unsearched, leak


def object_extent(mask: np.ndarray, depth_m: np.ndarray, predicted_mask: np.ndarray, rgb: np.ndarray,
                  colour: ColourModel, cfg: SegmentationConfig = SegmentationConfig(),
                  not_object: np.ndarray | None = None) -> np.ndarray:
    """``Segment.extent`` of the object ``mask`` (H, W) bool that ``segment_tracked`` found
    around ``predicted_mask`` (H, W) bool: the mask and the pixels of the object's colour
    joined to it, within the prediction's box grown by ``EXTENT_REACH`` search margins, not
    across ``not_object``. ``colour`` must be informative."""
    Y0, Y1, X0, X1 = bounding_box(predicted_mask, pad=EXTENT_REACH * cfg.search_margin_px)
    # Looked up afresh rather than shared with segment_tracked's colour step: the lookup works
    # at half resolution from its box's corner, and the step keeps its own box's pixels.
    p_wide = colour.probability(rgb[Y0:Y1, X0:X1])
    allowed = None if not_object is None else ~not_object[Y0:Y1, X0:X1]
    extent = mask.copy()
    extent[Y0:Y1, X0:X1] |= _colour_extent(mask[Y0:Y1, X0:X1], depth_m[Y0:Y1, X0:X1], p_wide, cfg, allowed)
    return extent


def _colour_extent(region: np.ndarray, depth_m: np.ndarray, p: np.ndarray, cfg: SegmentationConfig,
                   allowed: np.ndarray | None = None) -> np.ndarray:
    """The pixels of the object's colour (``p`` >= 0.5) with depth that join ``region``,
    through no depth jump, across gaps without depth up to about ``BRIDGE_PX`` wide with
    the surface at about the same depth on both sides (the sensor loses depth along creases
    and where a surface turns away; a band without depth beside a nearer hand is a jump),
    and only over ``allowed`` pixels (None: all). Found at half resolution (it is a measure
    of how much of the object there is, not of its edge) and returned at full. Box-sized
    arrays."""
    h, w = region.shape
    region, depth_m, p = region[::2, ::2], depth_m[::2, ::2], p[::2, ::2]
    if allowed is not None:
        allowed = allowed[::2, ::2]
        region = region & allowed
    valid = valid_depth(depth_m)
    like = valid & (p >= 0.5) & ~_jumps(depth_m, cfg)
    if allowed is not None:
        like &= allowed
    # A gap pixel passes when the object's colour with depth lies within reach of it, all
    # at about one depth: the nearest and farthest such depths around it differ by less
    # than a jump.
    reach = BRIDGE_PX // 4  # each side's half of the gap, at half resolution
    window = np.ones((2 * reach + 1,) * 2, np.uint8)
    d = np.where(like, depth_m, 0.0).astype(np.float32)
    farthest = cv2.dilate(d, window)
    nearest = cv2.erode(np.where(like, d, np.float32(np.inf)), window)
    level = farthest - nearest < cfg.edge_jump_m + cfg.edge_jump_rel * farthest
    gap = ~valid & level & np.isfinite(nearest)
    if allowed is not None:
        gap &= allowed
    passable = like | gap | region
    half = reached_from(region, passable) & like
    return blow_up(half, 2, (h, w))


def _uncovered(pred: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Where the prediction ``pred`` lies over the surroundings, given ``p``, each pixel's
    probability of being the object by its colour: areas clearly of the surroundings' colour
    inside it that are wider than a print's patches (where the cloth was before it moved),
    or that join the surroundings' colour outside it (a corner lifted and folded back bares
    the table under where it lay, often in a strip narrower than a patch), each with its
    blurred rim, where its colour is more the surroundings' than not; not a print's patches
    of a similar colour inside the cloth. A patch of the table's colour on the cloth's very
    edge joins the table too and goes. Box-sized bool."""
    unlike = p < 0.15
    inside = pred & unlike
    wide = cv2.morphologyEx(inside.astype(np.uint8), cv2.MORPH_OPEN, np.ones((15, 15), np.uint8)).astype(bool)
    # Open a little first, so that a patch touching the cloth's edge joins the outside only
    # through a band at least that wide, not through the few pixels of its rim.
    solid = cv2.morphologyEx(unlike.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8)).astype(bool)
    n, labels = cv2.connectedComponents(solid.astype(np.uint8), connectivity=4)
    outside = np.bincount(labels[~pred & solid], minlength=n)
    within = np.bincount(labels[inside & solid], minlength=n)
    joined = outside >= np.maximum(within, 25)  # a real share of it lies outside the prediction
    joined[0] = False
    uncovered = wide | (inside & joined[labels])
    # The colour lookup blurs over a few pixels: take the rim, as far as it looks more like
    # the surroundings than the object.
    rim = pred & (p < 0.5)
    for _ in range(3):
        uncovered |= rim & cv2.dilate(uncovered.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return uncovered


def _object_regions(regions, candidate, pred, dist, hidden_mask, y0, x0, cfg):
    """The regions of ``candidate`` (box-sized bool) that belong to the object, and the
    fraction of their edge on the search's rim (``Segment.leak``); box-sized arrays.
    ``regions``: ``_regions(candidate, depth, cfg)``."""
    n, labels, stats = regions
    if n <= 1:
        return np.zeros_like(candidate), 0.0
    overlap = np.bincount(labels[pred], minlength=n)
    area = stats[:, cv2.CC_STAT_AREA]
    # A region belongs to the object when a real part of it lies where the mesh was predicted,
    # or when it fills most of the prediction: an object small in the image, touched by a hand
    # or lying on something at its own depth, is a small part of a region that fills the search
    # around it, and it is still there.
    keep = ((overlap >= np.maximum(cfg.min_region_px // 3, 0.2 * area)) | (overlap >= 0.5 * pred.sum())) \
        & (area >= cfg.min_region_px)
    if hidden_mask is not None:
        h, w = candidate.shape
        near_hidden = cv2.dilate(hidden_mask[y0:y0 + h, x0:x0 + w].astype(np.uint8), disc(cfg.search_margin_px)) > 0
        keep |= (np.bincount(labels[near_hidden], minlength=n) >= cfg.min_region_px // 3) & (area >= cfg.min_region_px)
    keep[0] = False
    region = _grow(keep[labels], candidate)
    edge = region & ~cv2.erode(region.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE).astype(bool)
    along = edge & (dist >= cfg.search_margin_px - 1.5)
    return region, float(along.sum() / max(1, edge.sum()))


def find_by_colour(depth_m: np.ndarray, rgb: np.ndarray, colour: ColourModel,
                   cfg: SegmentationConfig = SegmentationConfig()) -> np.ndarray:
    """The object anywhere in a frame by its colour: (H, W) bool, empty if none.

    Of the depth-continuous regions of pixels more likely the object than its surroundings
    (``colour.probability`` >= 0.5), the one holding the most object probability."""
    h, w = depth_m.shape
    if not colour.informative:
        return np.zeros((h, w), bool)
    p = colour.probability(rgb)
    candidate = valid_depth(depth_m) & (p >= 0.5)
    n, labels, stats = _regions(candidate, depth_m, cfg)
    if n <= 1:
        return np.zeros((h, w), bool)
    mass = np.bincount(labels.ravel(), weights=p.ravel(), minlength=n)
    mass[0] = 0.0
    mass[stats[:, cv2.CC_STAT_AREA] < cfg.min_region_px] = 0.0
    best = int(np.argmax(mass))
    if mass[best] == 0.0:
        return np.zeros((h, w), bool)
    return _grow(labels == best, candidate)


def fit_plane_ransac(points: np.ndarray, tol: float, rng: np.random.Generator, iters: int = 200):
    """Best plane (n, d) with n.p + d = 0 by RANSAC on (P, 3) points; returns (n, d, inlier count)."""
    best = (None, 0.0, 0)
    if len(points) < 3:
        return best
    idx = rng.integers(0, len(points), size=(iters, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n = n[ok] / norm[ok, None]
    d = -np.einsum("ij,ij->i", n, a[ok])
    sample = points[rng.integers(0, len(points), size=min(len(points), 2000))]
    counts = (np.abs(sample @ n.T + d) < tol).sum(axis=0)
    if len(counts) == 0:
        return best
    i = int(np.argmax(counts))
    inl = np.abs(points @ n[i] + d[i]) < tol
    if inl.sum() >= 3:  # refine on all inliers by least squares
        p = points[inl]
        c0 = p.mean(axis=0)
        nn = np.linalg.svd(p - c0, full_matrices=False)[2][2]
        dd = -nn @ c0
        inl = np.abs(points @ nn + dd) < tol
        return nn, dd, int(inl.sum())
    return n[i], d[i], int(inl.sum())


def touches_border(mask: np.ndarray) -> int:
    """How many of the image's four sides ``mask`` reaches: comes within a band of 3 % of the
    image (16 px or more) of, since a sensor's depth often stops short of the edges (a
    registered Kinect image has no depth in its first dozen columns)."""
    h, w = mask.shape
    bh, bw = max(16, int(0.03 * h)), max(16, int(0.03 * w))
    return (int(mask[:bh].any()) + int(mask[-bh:].any()) + int(mask[:, :bw].any()) + int(mask[:, -bw:].any()))


def find_object(depth_m: np.ndarray, K: np.ndarray, cfg: SegmentationConfig = SegmentationConfig(),
                rng: np.random.Generator | None = None) -> np.ndarray:
    """Find the object in a frame with no prior: (H, W) bool mask, empty if none.

    Large planes that touch at least two image borders (floor, table, wall) are removed,
    then the largest depth-continuous region that touches at most two borders is taken.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    valid = valid_depth(depth_m)
    h, w = depth_m.shape
    vv, uu = np.nonzero(valid)
    if len(vv) < cfg.min_region_px:
        return np.zeros((h, w), bool)
    z = depth_m[vv, uu].astype(np.float64)
    pts = backproject(np.column_stack([uu, vv]), z, K)
    background = np.zeros((h, w), bool)
    remaining = np.ones(len(pts), bool)
    for _ in range(cfg.max_planes):
        idx = np.flatnonzero(remaining)
        n, d, count = fit_plane_ransac(pts[idx], cfg.plane_inlier_m, rng)
        if n is None or count < cfg.plane_min_fraction * len(pts):
            break
        inl = idx[np.abs(pts[idx] @ n + d) < cfg.plane_inlier_m]
        plane = np.zeros((h, w), bool)
        plane[vv[inl], uu[inl]] = True
        # A support plane is large and runs off the image; a flat poster filling the
        # middle of the view is not background.
        if touches_border(plane) < 2:
            break
        background |= plane
        remaining[inl] = False
    candidate = valid & ~background
    candidate = cv2.morphologyEx(candidate.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)
    n, labels, stats = _regions(candidate, depth_m, cfg)
    best, best_area = 0, 0
    for i in range(1, n):
        area = stats[i, cv2.CC_STAT_AREA]
        if area < cfg.min_region_px or area <= best_area:
            continue
        if touches_border(labels == i) > 2:
            continue
        best, best_area = i, area
    if best == 0:
        return np.zeros((h, w), bool)
    return _grow(labels == best, candidate)


#: how far past the object's contour, over pixels without depth, a nearer surface still hides
#: it: a depth sensor loses the pixels beside a depth discontinuity (the emitter's shadow,
#: mixed pixels), so the contour behind a hand or a gripper often borders a band without
#: depth a few pixels wide, and the nearer surface lies beyond it
SHADOW_PX = 16


def contour_parts(mask: np.ndarray, depth_m: np.ndarray, occlusion_margin_m: float = 0.03,
                  occluder_mask: np.ndarray | None = None, shadow_px: int = SHADOW_PX):
    """The object's contour in two parts: (outline, hidden), each the sorted flat indices
    (into the (H, W) image, row by row) of its pixels.

    The contour is the pixels of ``mask`` with a 4-neighbour outside it. ``outline`` is
    where the object ends; ``hidden`` is the rest, which says nothing about where it ends:
    the object cut by the image border, or hidden behind something nearer (an occluding hand
    or gripper, found by depth or given as ``occluder_mask`` (H, W) bool). Which it is, the
    first thing met going out of the object from the contour pixel says: a surface nearer
    than the object by ``occlusion_margin_m``, a known occluder or the image border hide it;
    a farther surface, or none within ``shadow_px`` pixels without depth (``SHADOW_PX``),
    is where the object ends.
    """
    m = mask.astype(bool)
    h, w = m.shape
    # flat views, read by flat pixel index; depth is checked only where it is read
    inside, depth = m.ravel(), np.asarray(depth_m).ravel()
    occluder = np.zeros(h * w, bool) if occluder_mask is None else occluder_mask.astype(bool).ravel()

    def measured(at):
        d = depth[at]
        return valid_depth(d), d

    # (pixel, outward step) pairs: each contour pixel once for each 4-neighbour outside the object
    inner = cv2.erode(m.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0)
    rows, cols = np.divmod(np.flatnonzero(inside & ~inner.view(bool).ravel()), w)
    steps = np.array([(-1, 0), (1, 0), (0, -1), (0, 1)])
    at, off = _ray(rows[:, None], cols[:, None], steps[:, 0], steps[:, 1], 1, h, w)
    which, step = np.nonzero(off | ~inside[at])
    rows, cols, dr, dc = rows[which], cols[which], steps[step, 0], steps[step, 1]
    first_at, first_off = at[which, step], off[which, step]  # the first step out, for the walk below
    # The object's depth there. The sensor often loses it at the object's own edge: then
    # the first depth measured going into the object, within 2 pixels.
    ok, near = measured(rows * w + cols)
    near = np.where(ok, near, np.inf)
    lost = np.flatnonzero(~ok)
    if len(lost):
        at, _ = _ray(rows[lost, None], cols[lost, None], -dr[lost, None], -dc[lost, None], np.arange(1, 3), h, w)
        seen, d = measured(at)
        seen &= inside[at]
        first = np.argmax(seen, axis=1)
        pick = np.arange(len(lost))
        near[lost] = np.where(seen[pick, first], d[pick, first], np.inf)
    near = near - occlusion_margin_m
    # Going out of the object a pixel a step, the first pixel that decides: beyond the image's
    # border, a known occluder or a nearer surface hide the contour; a farther surface, or the
    # object again, end it. A walk that meets only pixels without depth ends it too. Most
    # walks end at the first step; only those that start on a pixel without depth go on.
    seen, d = measured(first_at)
    is_hidden = first_off | occluder[first_at] | (seen & (d < near))
    go = np.flatnonzero(~is_hidden & ~seen)
    if len(go) and shadow_px > 0:
        at, off = _ray(rows[go, None], cols[go, None], dr[go, None], dc[go, None], np.arange(2, int(shadow_px) + 2),
                       h, w)
        seen, d = measured(at)
        cut = off | occluder[at] | (seen & (d < near[go, None]))
        first = np.argmax(cut | seen | inside[at], axis=1)
        is_hidden[go] = cut[np.arange(len(go)), first]
    # marked on the image and read back in order: sorted and unique, without sorting
    at = rows * w + cols
    own = np.zeros(h * w, bool)
    own[at[~is_hidden]] = True
    hidden = np.zeros(h * w, bool)
    hidden[at[is_hidden]] = True
    return np.flatnonzero(own), np.flatnonzero(hidden & ~own)


def _ray(rows: np.ndarray, cols: np.ndarray, dr, dc, k, h: int, w: int):
    """Flat indices into an (h, w) image of the pixels k steps (dr, dc) from (rows, cols),
    broadcast together, and where the steps left the image (bool, same shape; index 0 there)."""
    r, c = rows + dr * k, cols + dc * k
    off = (r < 0) | (r >= h) | (c < 0) | (c >= w)
    at = r * w + c
    at[off] = 0
    return at, off
