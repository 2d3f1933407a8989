"""Something in front of the cloth that nobody announced: a hand on it, a tool, an arm.

A known occluder (``RGBDFrame.occluder_mask``) is one the robot tells the tracker of. An
object it does not know of, close in front of the cloth (a hand touching it, a bar a few
centimetres in front), is nearer than the cloth by less than the occlusion margin, which
must stay wide enough for a mesh that lags behind a cloth moving fast. Its pixels then
count as the object's: the vertices behind it count as seen, the depth term pulls them
onto its front, their neighbours follow, and frame by frame the hidden part climbs onto
the object and is dragged along with it, while every cue of the confidence agrees.

What tells such an object from the cloth is a step in the measured depth: it is nearer
than the mesh predicted there, and nearer than the cloth around it by a step all round.
A part of the cloth the mesh lags behind is nearer than predicted too, but it runs on
into the cloth around it without a step (a flap folding over steps down along its free
edges and not along its crease); a cloth that moved as a whole has no cloth around it
where the mesh was predicted, and is left alone too.

The step must be wide (``near_m``, 3 cm) to tell it from the cloth's own folds by depth
alone. An object closer to the cloth than that (a bar 2 cm in front of it, a hand on it) is
found by its colour where the tracker's colour model tells the object from its surroundings
(``perception.colour_model``): a surface nearer than the predicted mesh by ``UNLIKE_NEAR_M``
(1 cm), whose hue is not the object's, and that stands out by as much all round from the
pixels of the object's hue around it. Hue, not brightness: a fold in the shade is darker
than any part of the cloth first seen, and is the cloth still; it also runs on into the
cloth beside it without a step. Found, such an object takes in the pixels of other hues
joined to it and no farther than it (its part beside the mesh hides the cloth's outline too)
and must so reach past the predicted mesh: an arm, a tool or a hand comes from beyond the
cloth, while a print the first frame did not show, on a fold's crest, lies within it. It is
kept while it stays ``KEEP_NEAR_M`` nearer than the mesh, since the mesh behind it, without
data, drifts towards it. What else can be nearer than a lagging mesh, and than the
cloth lifted beyond it, and not of the cloth's hue, is the table the cloth was lifted off:
pixels known to be the empty workspace (they do not differ from the ``background``, or lie
on the ``support`` plane, ``perception.support``) are never taken for an object found by
its colour.

An object too near the camera for its sensor to measure (a hand or an arm passing a few
tens of centimetres in front of the lens, inside a depth camera's minimum range) has no
depth at all, so no step. Where the colour model tells the cloth from its surroundings, a
patch over the predicted mesh that has no depth, is not of the cloth's hue, lies mostly
where the cloth was in the last few frames, is wider than a strip the cloth's own motion
bares along its edge (``BLIND_OPEN_PX``) and has around it cloth that agrees with the
prediction in depth (``BLIND_AGREE``) is taken for such an object, with its part beyond the
predicted mesh, where it hides the cloth's outline. The cloth's own pixels without depth
(seen at a grazing angle, along a crease) are of its hue, and are left alone. This is done
only where the sensor measured what surrounds the cloth when the tracker first saw it
(``MEASURED_SURROUNDINGS``): in front of a background beyond the sensor's range, where the
cloth moves away (a hanging towel's top edge sagging) the background shows through without
depth and not of the cloth's hue either, and cannot be told from an object in front. A
cloth's other side of another hue, turned towards the camera at a grazing angle, is taken
for such an object as it is for one close in front.

What it misses: an object whose rim slopes down into the cloth (a rounded hand lying flat
on it, fingertips) meets the cloth without a step and is taken for cloth, as before; so is
anything nearer than the predicted mesh by less than ``near_m`` where colour cannot tell (a
grey arm over a grey cloth, a cloth whose colours are not told from its surroundings'),
anything of the cloth's hue, and a hand whose arm lies beyond the search around it (a hand
in the middle of a large towel). A cloth whose other side differs in hue from the side
first seen, folding over, is taken for an object in front where it stands out from the
cloth around it. The thresholds are in metres whatever the depth: a sensor whose noise at
the cloth's distance approaches them (a stereo camera at 2-3 m) wants larger ones. A flap
folded over whose crease the sensor does not measure steps down all round, and is taken
for an object in front.

Arrays: vertices (N, 3) float metres in the camera frame; depth (H, W) float32 metres,
0 or NaN where unmeasured; masks (H, W) bool.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from perception.colour_model import ColourModel
from perception.geometry import directed_edges, pixel_index, project
from perception.raster import blow_up, disc, locate_pixels
from perception.segmentation import SHADOW_PX, valid_depth
from perception.support import SupportPlane

#: Share of the cloth around a nearer patch (measured next to it, where the mesh is predicted
#: and agrees with the data) that must lie farther than the patch by the step: a patch of the
#: cloth itself meets the cloth around it without a step somewhere (a crease, a lagging part).
ALL_ROUND = 0.85
#: The share of the cloth around a patch that must step down, for a patch where an object in
#: front was found in the frame before: once an object is in front, the mesh's edge next to
#: it may have been drawn a little towards it, and part of its rim then agrees with the mesh.
#: A patch of cloth the object left is released: the cloth runs on around it.
STILL_ROUND = 0.4
#: An object found in the frame before is that patch again only if the patch has not grown to
#: more than this many times its size: cloth it lifts, joined to it, must not ride along.
GROWN = 1.5
#: Pixels of the cloth around a patch, at least, that the step is judged on.
MIN_RING_PX = 12
#: How far around a patch (pixels) the cloth is looked at: next to it, and beyond a band
#: without depth as wide as a sensor leaves beside a depth discontinuity.
NEAR_RING_PX, FAR_RING_PX = 4, SHADOW_PX
#: The search reads every STEP_PX-th pixel in each direction: an object in front of the cloth
#: is many pixels wide, and a quarter of the pixels is a quarter of the work.
STEP_PX = 2
#: A surface nearer than the predicted mesh, and than the object's colour around it, by this
#: much (metres), not of the object's colour, is an object in front: above a sensor's noise
#: at a metre or two.
UNLIKE_NEAR_M = 0.01
#: An object found by its colour in the frame before is kept while this much nearer than the mesh.
KEEP_NEAR_M = 0.003
#: Vertices, at least, that an object found by its colour covers next to vertices of the
#: object's hue all measured farther by ``UNLIKE_NEAR_M``: checked on the vertices alone before
#: any pixel is looked at (a print's colours on a cloth the mesh lags behind run on without a step).
MIN_UNLIKE_VERTICES = 2
#: Below this probability of being the object by its hue (``ColourModel.chroma_probability``) a
#: pixel is not of the object's colour: the even odds the colour segmentation draws its line at.
UNLIKE_P = 0.5
#: Vertices, at least, of the predicted mesh on pixels without depth and not of the object's
#: hue, seen in the frame before or under the object found then, before an object too near to
#: measure is looked for.
MIN_BLIND_VERTICES = 8
#: Such an object is wider than this (image pixels) everywhere: opening its patch by it drops
#: the strips along the predicted mesh's edge that a cloth moving a few pixels bares (a
#: background beyond the sensor's range has no depth either).
BLIND_OPEN_PX = 12
#: Objects too near to measure are looked for only in front of surroundings that the sensor
#: measures: this share of the pixels within ``SURROUNDINGS_RING_PX`` of the object, when the
#: tracker first saw it (``measured_around``). In front of a background beyond the sensor's
#: range, a patch without depth where the mesh is predicted is as likely that background where
#: the cloth moved away (a hanging towel's top edge sagging) as something in front of it.
MEASURED_SURROUNDINGS = 0.9
SURROUNDINGS_RING_PX = 40
#: Share of such a patch that was the object in the last few frames, or the object in front
#: found in the frame before: it came in front of the cloth.
BLIND_CAME = 0.5
#: Share of the cloth around such a patch (within ``FAR_RING_PX``, where the mesh is predicted
#: and depth is measured) that must agree with the prediction: the cloth stayed where it was
#: and something came in front of it. Where the cloth itself moved away, baring what lies
#: behind, the cloth around the bare patch has moved too.
BLIND_AGREE = 0.5


def measured_around(depth_m: np.ndarray, mask: np.ndarray, ring_px: int = SURROUNDINGS_RING_PX) -> float:
    """Share of the pixels within ``ring_px`` around the object ``mask`` (H, W) bool that have
    measured depth in ``depth_m`` (H, W): near 1 where the cloth hangs or lies in front of
    surfaces the sensor measures, low in front of a background beyond its range."""
    ring = cv2.dilate(np.asarray(mask, np.uint8), disc(ring_px)).view(bool) & ~np.asarray(mask, bool)
    return float(valid_depth(depth_m[ring]).mean()) if ring.any() else 0.0


def _predicted_depth(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, shape) -> np.ndarray:
    """(h, w) float64 depth of the mesh's nearest face at each pixel, NaN off the mesh; ``uv``
    (N, 2) are the vertices' pixel coordinates in that (h, w) image."""
    rows, cols = np.indices(shape).reshape(2, -1)
    fid, bary = locate_pixels(np.column_stack([cols, rows]), uv, faces, vertices[:, 2], shape)
    seen = fid >= 0
    z = np.full(len(fid), np.nan)
    z[seen] = np.einsum("pk,pk->p", bary[seen], vertices[faces[fid[seen]], 2])
    return z.reshape(shape)


def _steps_all_round(patches: np.ndarray, n: int, depth: np.ndarray, cloth: np.ndarray, radius: int,
                     step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """For each patch label 1..n of ``patches`` (int32 image, 0 elsewhere): how many pixels of
    ``cloth`` lie within ``radius`` of it, and how many of those lie farther than the patch
    next to them (its mean depth within ``radius``) by more than ``step_m``; (n + 1,) each."""
    inside = patches > 0
    around = cv2.dilate(patches.astype(np.float32), disc(radius)).astype(np.int32)
    ring = (around > 0) & ~inside & cloth
    k = (2 * radius + 1,) * 2
    near_sum = cv2.boxFilter(np.where(inside, depth, 0.0), -1, k, normalize=False)
    near_n = cv2.boxFilter(inside.astype(np.float64), -1, k, normalize=False)
    label = around[ring]
    stepped = depth[ring] - near_sum[ring] / near_n[ring] > step_m
    return (np.bincount(label, minlength=n + 1), np.bincount(label, weights=stepped, minlength=n + 1))


def occluders_in_front(depth_m: np.ndarray, vertices: np.ndarray, faces: np.ndarray, K: np.ndarray,
                       near_m: float, known: np.ndarray | None = None, before: np.ndarray | None = None,
                       min_px: int = 40, rgb: np.ndarray | None = None, colour: ColourModel | None = None,
                       workspace: np.ndarray | None = None, support: SupportPlane | None = None,
                       object_before: tuple = (), seen_before: np.ndarray | None = None) -> np.ndarray | None:
    """(H, W) bool: objects in front of the cloth that the predicted mesh ``vertices``
    (N, 3), ``faces`` (M, 3) does not explain (see the module docstring); None when there is
    none.

    depth_m : (H, W) float32 metres; K : (3, 3) intrinsics
    near_m : how much nearer than the predicted mesh a surface must be, and how far it must
        stand out from the cloth around it (a step all round), to be taken for an object in
        front; more than the sensor's noise, less than the nearest such object is expected
    known : (H, W) bool, the known occluders (not looked for again, and not cloth), or None
    before : (H, W) bool, what this returned for the frame before, or None. A patch that is
        mostly that object, moved (half of it within ``FAR_RING_PX`` of it, and not grown to
        more than ``GROWN`` times its size there), needs the step on only ``STILL_ROUND`` of
        the cloth around it
    min_px : smaller patches (pixels) are left alone
    rgb, colour : the frame's (H, W, 3) uint8 colours and the object's colour model; with both,
        and a model that tells the object from its surroundings, an object in front closer
        than ``near_m`` is found by its colour
    workspace : (H, W) bool, pixels known to show the empty workspace, or None
    support : the plane the object rests on or stands in front of, or None
    Neither ``workspace`` nor ``support`` pixels are taken for an object found by its colour.
    object_before : (H, W) bool masks, the object as segmented in the last few frames; with
        them, ``seen_before``, ``rgb`` and an informative ``colour``, an object too near the
        camera to be measured is looked for where the object was (``_too_near``)
    seen_before : (N,) bool, the vertices seen in the frame before. Such an object is looked
        for only where it covers some of them, or lies where one was found in the frame before:
        a vertex without depth that was not seen before either (on the band a sensor leaves
        along the cloth's edge) says nothing new, and the search costs milliseconds a frame.
    """
    h, w = depth_m.shape
    uv = project(vertices, K)
    cols, rows, inside = pixel_index(uv, w, h)
    d = depth_m[rows, cols]
    measured = inside & valid_depth(d)
    # Cheap tests first: an object in front of the cloth covers some vertices; one found by its
    # colour covers some at pixels not of the object's hue.
    covered = measured & (d < vertices[:, 2] - near_m)
    by_colour = rgb is not None and colour is not None and colour.informative
    blind = None  # vertices without depth, of other hues, newly: under an object too near to measure?
    if by_colour and len(object_before) and seen_before is not None and len(seen_before) == len(vertices):
        blind = inside & ~measured & (seen_before if before is None else seen_before | before[rows, cols])
        blind[blind] = colour.chroma_probability_at(rgb[rows[blind], cols[blind]]) < UNLIKE_P
        blind = blind if np.count_nonzero(blind) >= MIN_BLIND_VERTICES else None
    if by_colour:
        rim = _rim_vertices(vertices, faces, d, measured, rgb[rows, cols], colour,
                            None if before is None else before[rows, cols] & inside)
        by_colour = np.count_nonzero(rim) >= MIN_UNLIKE_VERTICES
        if by_colour:  # the object is looked for around its rim (its pixels reach on beyond)
            covered |= rim
    found = None
    grid = _Grid.around(covered, depth_m, vertices, faces, uv, cols, rows, known, before) \
        if np.count_nonzero(covered) >= 2 else None
    if grid is not None:
        unlike = None
        if by_colour:
            candidate = grid.valid.copy()  # seeds lie on the mesh (offset 0 elsewhere); their objects anywhere
            if known is not None:
                candidate &= ~grid.cut(known)
            if workspace is not None:
                candidate &= ~grid.cut(workspace)
            if support is not None:
                candidate &= ~support.on_plane(grid.depth, K, grid.x0, grid.y0, STEP_PX)
            unlike = _unlike(candidate, grid.z > 0, grid.offset, grid.was, grid.cut(rgb), grid.depth, colour, min_px)
        stepped = _stepped_patches(grid.on_mesh, grid.offset, grid.depth, grid.was, near_m, min_px)
        found = grid.full(stepped if unlike is None else (unlike if stepped is None else stepped | unlike))
    grid = None if blind is None else _Grid.around(blind, depth_m, vertices, faces, uv, cols, rows, known, before)
    if grid is not None:
        excluded = np.zeros(grid.depth.shape, bool)
        for mask in (known, workspace):
            if mask is not None:
                excluded |= grid.cut(mask)
        came = np.logical_or.reduce([grid.cut(m) for m in object_before])
        if grid.was is not None:
            came = came | grid.was
        too_near = grid.full(_too_near(~grid.valid & ~excluded, grid.z > 0, came,
                                       grid.on_mesh & (np.abs(grid.offset) <= near_m), grid.on_mesh, grid.cut(rgb),
                                       colour, min_px))
        found = too_near if found is None else (found if too_near is None else found | too_near)
    return found


@dataclass
class _Grid:
    """The box an object in front is looked for in, read on every ``STEP_PX``-th pixel: where
    it covers vertices, padded by a face and by ``FAR_RING_PX``, the cloth it is judged against.

    shape : the image's (H, W); y0, y1, x0, x1 : the box in it (y0, x0 multiples of
    ``STEP_PX``); depth : measured depth, 0 where none; valid : where measured; z : the
    predicted mesh's depth, 0 off it; on_mesh : measured where the mesh is predicted, less the
    known occluders; offset : depth less z there, 0 elsewhere; was : the object in front found
    in the frame before, or None.
    """

    shape: tuple[int, int]
    y0: int
    y1: int
    x0: int
    x1: int
    depth: np.ndarray
    valid: np.ndarray
    z: np.ndarray
    on_mesh: np.ndarray
    offset: np.ndarray
    was: np.ndarray | None

    @classmethod
    def around(cls, covered, depth_m, vertices, faces, uv, cols, rows, known, before) -> _Grid | None:
        """The grid around the vertices ``covered`` (N,) bool; None when no face projects."""
        h, w = depth_m.shape
        edges = np.linalg.norm(uv[faces[:, 0]] - uv[faces[:, 1]], axis=1)
        edges = edges[np.isfinite(edges)]  # a vertex behind the camera projects nowhere
        if not len(edges):
            return None
        pad = int(FAR_RING_PX + 2 * min(float(np.median(edges)), max(h, w))) + STEP_PX
        y0 = max(0, int(rows[covered].min()) - pad) // STEP_PX * STEP_PX
        x0 = max(0, int(cols[covered].min()) - pad) // STEP_PX * STEP_PX
        y1, x1 = min(h, int(rows[covered].max()) + 1 + pad), min(w, int(cols[covered].max()) + 1 + pad)
        depth = np.asarray(depth_m[y0:y1:STEP_PX, x0:x1:STEP_PX], np.float64)
        valid = valid_depth(depth)
        depth = np.where(valid, depth, 0.0)
        uv_box = (uv - [x0, y0]) / STEP_PX
        corners = uv_box[faces]
        near_box = np.all(np.isfinite(corners).reshape(len(faces), -1), axis=1)
        near_box &= np.all(corners.max(axis=1) >= -1, axis=1) & np.all(corners.min(axis=1) <= depth.shape[::-1], axis=1)
        z = _predicted_depth(vertices, faces[near_box], uv_box, depth.shape)
        # The mesh's rim vertices lie on its drawn edge, which sparse pixels may miss: the
        # prediction is carried a pixel or two beyond it.
        drawn = np.isfinite(z)
        z = np.where(drawn, z, cv2.dilate(np.where(drawn, z, 0.0), disc(2)))
        on_mesh = valid & (z > 0)
        if known is not None:
            on_mesh &= ~known[y0:y1:STEP_PX, x0:x1:STEP_PX]
        offset = np.where(on_mesh, depth - z, 0.0)
        was = None if before is None else before[y0:y1:STEP_PX, x0:x1:STEP_PX]
        return cls((h, w), y0, y1, x0, x1, depth, valid, z, on_mesh, offset, was)

    def cut(self, image: np.ndarray) -> np.ndarray:
        """``image`` (H, W, ...) read on the grid."""
        return image[self.y0:self.y1:STEP_PX, self.x0:self.x1:STEP_PX]

    def full(self, front: np.ndarray | None) -> np.ndarray | None:
        """(H, W) bool of ``front`` (the grid's shape) grown by a pixel or two (the object's own
        edge pixels, mixed with the cloth behind); None when it is None or empty."""
        if front is None or not front.any():
            return None
        found = cv2.dilate(front.view(np.uint8), np.ones((3, 3), np.uint8))
        out = np.zeros(self.shape, bool)
        out[self.y0:self.y1, self.x0:self.x1] = blow_up(found, STEP_PX, (self.y1 - self.y0, self.x1 - self.x0))
        return out


def _rim_vertices(vertices: np.ndarray, faces: np.ndarray, d: np.ndarray, measured: np.ndarray, rgb: np.ndarray,
                  colour: ColourModel, was: np.ndarray | None) -> np.ndarray:
    """(N,) bool: the vertices an object found by its colour would show first. Each is nearer
    than the depth ``d`` (N,) measured at its pixel (where ``measured``) by ``UNLIKE_NEAR_M``
    (``KEEP_NEAR_M`` where ``was``, the object found the frame before), sees a colour (``rgb``
    (N, 3)) not of the object's hue, and has neighbours along ``faces`` of the object's hue,
    all measured farther than it by ``UNLIKE_NEAR_M``, as the pixels will be all round the
    object (on a slope, some neighbours are nearer)."""
    unlike = measured.copy()
    unlike[measured] = colour.chroma_probability_at(rgb[measured]) < UNLIKE_P
    near = np.where(was, KEEP_NEAR_M, UNLIKE_NEAR_M) if was is not None else UNLIKE_NEAR_M
    closer = unlike & (d < vertices[:, 2] - near)
    a, b = directed_edges(faces).T  # an edge inside the mesh comes twice: the counts below are shares
    a, b = np.concatenate([a, b]), np.concatenate([b, a])
    to_cloth = closer[a] & measured[b] & ~unlike[b]
    n_cloth = np.bincount(a[to_cloth], minlength=len(vertices))
    n_step = np.bincount(a[to_cloth & (d[b] - d[a] > UNLIKE_NEAR_M)], minlength=len(vertices))
    return (n_cloth > 0) & (n_step == n_cloth)


def _patches(candidate: np.ndarray, min_px: int) -> tuple[int, np.ndarray, np.ndarray]:
    """(n, labels, areas) of the connected patches of ``candidate`` (h, w) bool, read on
    every ``STEP_PX``-th pixel, opened 3x3, with those under ``min_px`` image pixels dropped
    (labelled 0); ``n`` counts label 0, ``areas`` (n,) are in box pixels."""
    opened = cv2.morphologyEx(candidate.view(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, patches, stats, _ = cv2.connectedComponentsWithStats(opened, connectivity=8)
    area = stats[:, cv2.CC_STAT_AREA]
    patches[(area < min_px / STEP_PX**2)[patches]] = 0
    return n, patches, area


def _unlike(candidate: np.ndarray, on_mesh: np.ndarray, offset: np.ndarray, was: np.ndarray | None, rgb: np.ndarray,
            depth: np.ndarray, colour: ColourModel, min_px: int) -> np.ndarray | None:
    """(h, w) bool on the box's grid: objects in front found by their colour, or None.

    Seeds are patches of ``candidate`` nearer than the mesh (``offset`` metres, measured minus
    predicted) by ``UNLIKE_NEAR_M`` (``KEEP_NEAR_M`` where ``was``, an object found in the
    frame before) whose colour in ``rgb`` (h, w, 3) is not the object's, and that stand out
    by ``UNLIKE_NEAR_M`` from the pixels of the object's colour around them (``depth`` (h, w)
    metres, 0 where unmeasured): a part of the cloth darkened by a fold, nearer than a mesh
    lagging behind it, runs on into the cloth beside it. Each is grown over the pixels of
    ``candidate`` joined to it that are not of the object's colour either and lie no farther
    than it: an object's part beside the predicted mesh, where it is not nearer than anything
    predicted, hides the object's outline as much as its part in front of the mesh does. An
    object is kept only if it so reaches past the predicted mesh (``on_mesh`` (h, w) bool)."""
    near = offset < -UNLIKE_NEAR_M
    if was is not None:
        near |= was & (offset < -KEEP_NEAR_M)
    near &= candidate
    if np.count_nonzero(near) < min_px / STEP_PX**2:
        return None
    unlike = candidate & (colour.chroma_probability(np.ascontiguousarray(rgb)) < UNLIKE_P)
    n, patches, area = _patches(near & unlike, min_px)
    if not (patches > 0).any():
        return None
    # The object's colour, less a band along other colours: the probabilities are smoothed
    # over 3x3, so that a patch's own rim passes for the object's colour.
    cloth = cv2.erode((candidate & ~unlike & (depth > 0)).view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    front = _standing_out(patches, n, area, depth, cloth, UNLIKE_NEAR_M, was)
    seeded = front[patches]
    if not seeded.any():
        return None
    farthest = float(depth[seeded].max())
    n, region = cv2.connectedComponents((unlike & (depth > 0) & (depth <= farthest)).view(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[region[seeded]] = True
    # An arm, a tool or a hand comes from beyond the cloth: its object reaches past the
    # predicted mesh. A print the first frame did not show, on a fold's crest (nearer than
    # everything around it), lies within the mesh.
    keep &= np.bincount(region[~on_mesh], minlength=n) >= min_px / STEP_PX**2
    keep[0] = False
    return keep[region] if keep.any() else None


def _too_near(unmeasured: np.ndarray, predicted: np.ndarray, came: np.ndarray, agrees: np.ndarray,
              measured_on_mesh: np.ndarray, rgb: np.ndarray, colour: ColourModel, min_px: int) -> np.ndarray | None:
    """(h, w) bool on the box's grid: objects too near the camera to be measured, or None.

    unmeasured : pixels without depth that may be such an object (not a known occluder, not
        the empty workspace); predicted : where the mesh is predicted; came : where such an
        object may have come: the object's pixels in the last few frames, and the object in
        front found in the frame before; agrees : pixels of the predicted mesh whose depth
        agrees with it; measured_on_mesh : those with depth at all; rgb : (h, w, 3) the box's
        colours.
    Seeds are the patches of ``unmeasured`` not of the object's hue over the prediction, opened
    by ``BLIND_OPEN_PX``, of ``min_px`` at least, ``BLIND_CAME`` of them where such an object
    came (a background beyond the sensor's range never was the object, even where a mesh a
    little too large is predicted over it), with ``BLIND_AGREE`` of the cloth around them
    agreeing with the prediction (see the module docstring). Each takes in the pixels of other
    hues without depth within ``FAR_RING_PX`` of it, as far as the outline's test looks for
    what hides the object (not farther: the sensor's bands without depth along the cloth's
    edges, or a background beyond its range, would carry it round the whole outline)."""
    unlike = unmeasured & (colour.chroma_probability(np.ascontiguousarray(rgb)) < UNLIKE_P)
    seeds = cv2.morphologyEx((unlike & predicted).view(np.uint8), cv2.MORPH_OPEN, disc(BLIND_OPEN_PX // (2 * STEP_PX)))
    n, patches, stats, _ = cv2.connectedComponentsWithStats(seeds, connectivity=8)
    area = stats[:, cv2.CC_STAT_AREA]
    big = (area >= min_px / STEP_PX**2) & (np.bincount(patches[came], minlength=n) >= BLIND_CAME * area)
    big[0] = False
    if not big.any():
        return None
    radius = FAR_RING_PX // STEP_PX
    around = cv2.dilate(np.where(big[patches], patches, 0).astype(np.float32), disc(radius)).astype(np.int32)
    ring = (around > 0) & measured_on_mesh
    seen = np.bincount(around[ring], minlength=n)
    agree = np.bincount(around[ring & agrees], minlength=n)
    front = big & (seen >= MIN_RING_PX / STEP_PX) & (agree >= BLIND_AGREE * np.maximum(seen, 1))
    if not front.any():
        return None
    # Its part beyond the predicted mesh, as far as the outline's test looks (SHADOW_PX).
    return cv2.dilate(front[patches].view(np.uint8), disc(radius)).view(bool) & unlike


def _stepped_patches(on_mesh: np.ndarray, offset: np.ndarray, depth: np.ndarray, was: np.ndarray | None,
                     near_m: float, min_px: int) -> np.ndarray | None:
    """(h, w) bool on the box's grid: patches nearer than the mesh by ``near_m`` that stand out
    from the cloth around them by a step (see the module docstring); None if none."""
    n, patches, area = _patches(on_mesh & (offset < -near_m), min_px)
    if not (patches > 0).any():
        return None
    cloth = on_mesh & (np.abs(offset) <= near_m)  # where the data agrees with the prediction
    front = _standing_out(patches, n, area, depth, cloth, near_m, was)
    return front[patches] if front.any() else None


def _standing_out(patches: np.ndarray, n: int, area: np.ndarray, depth: np.ndarray, cloth: np.ndarray,
                  step_m: float, was: np.ndarray | None) -> np.ndarray:
    """(n,) bool by label of ``patches`` (0 never): those that stand out from ``cloth`` (h, w)
    bool around them by ``step_m`` on ``ALL_ROUND`` of it, or on ``STILL_ROUND`` of it for a
    patch that is mostly ``was``, the object found in the frame before, moved and not grown
    by more than ``GROWN`` (see ``occluders_in_front``); ``area`` (n,) box pixels per label."""
    least = MIN_RING_PX / STEP_PX
    seen, stepped = _steps_all_round(patches, n - 1, depth, cloth, NEAR_RING_PX // STEP_PX, step_m)
    # Beside an object in front, the sensor often measures nothing for a few pixels: judge
    # those patches on the cloth beyond that band.
    far_seen, far_stepped = _steps_all_round(patches, n - 1, depth, cloth, FAR_RING_PX // STEP_PX, step_m)
    use_far = seen < least
    seen, stepped = np.where(use_far, far_seen, seen), np.where(use_far, far_stepped, stepped)
    front = (seen >= least) & (stepped >= ALL_ROUND * np.maximum(seen, 1))
    if was is not None:
        reach = cv2.dilate(patches.astype(np.float32), disc(FAR_RING_PX // STEP_PX)).astype(np.int32)
        was_near = np.bincount(reach[was], minlength=n)  # the object found before, around each patch
        on_was = np.bincount(patches[cv2.dilate(was.view(np.uint8), disc(FAR_RING_PX // STEP_PX)).view(bool)],
                             minlength=n)
        again = (on_was >= 0.5 * area) & (area <= GROWN * was_near)
        front |= again & (far_seen >= least) & (far_stepped >= STILL_ROUND * np.maximum(far_seen, 1))
    front[0] = False
    return front
