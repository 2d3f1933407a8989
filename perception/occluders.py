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
                       workspace: np.ndarray | None = None, support: SupportPlane | None = None) -> np.ndarray | None:
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
    if by_colour:
        rim = _rim_vertices(vertices, faces, d, measured, rgb[rows, cols], colour,
                            None if before is None else before[rows, cols] & inside)
        by_colour = np.count_nonzero(rim) >= MIN_UNLIKE_VERTICES
        if by_colour:  # the object is looked for around its rim (its pixels reach on beyond)
            covered |= rim
    if np.count_nonzero(covered) < 2:
        return None
    # The object lies within a face of the vertices it covers, and the cloth it is judged
    # against within FAR_RING_PX beyond: work in that box, on every STEP_PX-th pixel.
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
    unlike = None
    if by_colour:
        candidate = valid.copy()  # seeds lie on the mesh (offset 0 elsewhere); their objects anywhere
        if known is not None:
            candidate &= ~known[y0:y1:STEP_PX, x0:x1:STEP_PX]
        if workspace is not None:
            candidate &= ~workspace[y0:y1:STEP_PX, x0:x1:STEP_PX]
        if support is not None:
            candidate &= ~support.on_plane(depth, K, x0, y0, STEP_PX)
        unlike = _unlike(candidate, z > 0, offset, was, rgb[y0:y1:STEP_PX, x0:x1:STEP_PX], depth, colour, min_px)
    stepped = _stepped_patches(on_mesh, offset, depth, was, near_m, min_px)
    front = stepped if unlike is None else (unlike if stepped is None else stepped | unlike)
    if front is None or not front.any():
        return None
    # Grown by a pixel or two: the object's own edge pixels, mixed with the cloth behind.
    found = cv2.dilate(front.view(np.uint8), np.ones((3, 3), np.uint8))
    out = np.zeros((h, w), bool)
    out[y0:y1, x0:x1] = blow_up(found, STEP_PX, (y1 - y0, x1 - x0))
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
