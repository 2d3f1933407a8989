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

What it misses: an object whose rim slopes down into the cloth (a rounded hand lying flat
on it, fingertips) meets the cloth without a step and is taken for cloth, as before; so is
anything nearer than the predicted mesh by less than ``near_m``. The threshold is in metres
whatever the depth: a sensor whose noise at the cloth's distance approaches it (a stereo
camera at 2-3 m) wants a larger one. A flap folded over whose crease the sensor does not
measure steps down all round, and is taken for an object in front.

Arrays: vertices (N, 3) float metres in the camera frame; depth (H, W) float32 metres,
0 or NaN where unmeasured; masks (H, W) bool.
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.geometry import pixel_index, project
from perception.raster import locate_pixels
from perception.segmentation import SHADOW_PX, valid_depth

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


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)


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
    around = cv2.dilate(patches.astype(np.float32), _disc(radius)).astype(np.int32)
    ring = (around > 0) & ~inside & cloth
    k = (2 * radius + 1,) * 2
    near_sum = cv2.boxFilter(np.where(inside, depth, 0.0), -1, k, normalize=False)
    near_n = cv2.boxFilter(inside.astype(np.float64), -1, k, normalize=False)
    label = around[ring]
    stepped = depth[ring] - near_sum[ring] / near_n[ring] > step_m
    return (np.bincount(label, minlength=n + 1), np.bincount(label, weights=stepped, minlength=n + 1))


def occluders_in_front(depth_m: np.ndarray, vertices: np.ndarray, faces: np.ndarray, K: np.ndarray,
                       near_m: float, known: np.ndarray | None = None, before: np.ndarray | None = None,
                       min_px: int = 40) -> np.ndarray | None:
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
    """
    h, w = depth_m.shape
    uv = project(vertices, K)
    cols, rows, inside = pixel_index(uv, w, h)
    d = depth_m[rows, cols]
    # Cheap test first: an object in front of the cloth covers some vertices.
    covered = inside & valid_depth(d) & (d < vertices[:, 2] - near_m)
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
    z = np.where(drawn, z, cv2.dilate(np.where(drawn, z, 0.0), _disc(2)))
    on_mesh = valid & (z > 0)
    if known is not None:
        on_mesh &= ~known[y0:y1:STEP_PX, x0:x1:STEP_PX]
    offset = np.where(on_mesh, depth - z, 0.0)
    nearer = cv2.morphologyEx((on_mesh & (offset < -near_m)).view(np.uint8), cv2.MORPH_OPEN,
                              np.ones((3, 3), np.uint8)).view(bool)
    n, patches, stats, _ = cv2.connectedComponentsWithStats(nearer.view(np.uint8), connectivity=8)
    area = stats[:, cv2.CC_STAT_AREA]
    patches[(area < min_px / STEP_PX**2)[patches]] = 0
    if not (patches > 0).any():
        return None
    cloth = on_mesh & (np.abs(offset) <= near_m)  # where the data agrees with the prediction
    least = MIN_RING_PX / STEP_PX
    seen, stepped = _steps_all_round(patches, n - 1, depth, cloth, NEAR_RING_PX // STEP_PX, near_m)
    # Beside an object in front, the sensor often measures nothing for a few pixels: judge
    # those patches on the cloth beyond that band.
    far_seen, far_stepped = _steps_all_round(patches, n - 1, depth, cloth, FAR_RING_PX // STEP_PX, near_m)
    use_far = seen < least
    seen, stepped = np.where(use_far, far_seen, seen), np.where(use_far, far_stepped, stepped)
    front = (seen >= least) & (stepped >= ALL_ROUND * np.maximum(seen, 1))
    if before is not None:
        was = before[y0:y1:STEP_PX, x0:x1:STEP_PX]
        reach = cv2.dilate(patches.astype(np.float32), _disc(FAR_RING_PX // STEP_PX)).astype(np.int32)
        was_near = np.bincount(reach[was], minlength=n)  # the object found before, around each patch
        on_was = np.bincount(patches[cv2.dilate(was.view(np.uint8), _disc(FAR_RING_PX // STEP_PX)).view(bool)],
                             minlength=n)
        again = (on_was >= 0.5 * area) & (area <= GROWN * was_near)
        front |= again & (far_seen >= least) & (far_stepped >= STILL_ROUND * np.maximum(far_seen, 1))
    front[0] = False
    if not front.any():
        return None
    # Grown by a pixel or two: the object's own edge pixels, mixed with the cloth behind.
    found = cv2.dilate(front[patches].view(np.uint8), np.ones((3, 3), np.uint8))
    out = np.zeros((h, w), bool)
    out[y0:y1, x0:x1] = np.repeat(np.repeat(found, STEP_PX, axis=0), STEP_PX, axis=1)[:y1 - y0, :x1 - x0].view(bool)
    return out
