"""Drawing a projected mesh into image-sized arrays (masks, face ids), and the resampling
and region helpers the image steps share.

uv : (N, 2) float pixel coordinates of the vertices; faces : (M, 3) int; shape : (H, W).
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.mesh import barycentric_2d


def disc(radius: int) -> np.ndarray:
    """(2 radius + 1, 2 radius + 1) uint8 disc-shaped structuring element, for growing or
    shrinking a mask by ``radius`` pixels in every direction."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)


def bounding_box(mask: np.ndarray, pad: int = 0):
    """(y0, y1, x0, x1) half-open box around the True pixels of ``mask``, grown by ``pad`` and
    clipped to the image; None when the mask is empty. Cheaper than np.nonzero on a full frame."""
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    return (max(0, rows[0] - pad), min(h, rows[-1] + 1 + pad), max(0, cols[0] - pad), min(w, cols[-1] + 1 + pad))


def blow_up(mask: np.ndarray, factor: int, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: each pixel of ``mask`` (h, w) bool repeated ``factor`` times down and
    across, cut to ``shape`` (H, W) (at most h * factor by w * factor). As ``np.repeat``
    twice, but by OpenCV, which lets go of the interpreter's lock: the tracker runs this
    beside its main thread, which then need not wait."""
    h, w = mask.shape
    big = cv2.resize(mask.view(np.uint8), (w * factor, h * factor), interpolation=cv2.INTER_NEAREST_EXACT)
    return big[: shape[0], : shape[1]].view(bool)


def shrink(image: np.ndarray, factor: int) -> np.ndarray:
    """``image`` (H, W) or (H, W, C) reduced ``factor`` times in each direction: each pixel the
    mean of a ``factor`` x ``factor`` block, the image's last row and column repeated to fill
    the blocks at its far edges; (ceil(H / factor), ceil(W / factor)[, C]), ``image``'s dtype.
    OpenCV averages whole blocks fast, but spreads a size that is not a multiple of the
    factor over the whole image at a small fraction of that speed (0.61 against 0.03 ms on
    a 401 x 301 colour crop halved)."""
    f = int(factor)
    if f < 1:
        raise ValueError(f"shrink: factor must be a positive integer, got {factor!r}")
    if f == 1:
        return image
    h, w = image.shape[:2]
    bottom, right = -h % f, -w % f
    if bottom or right:
        image = cv2.copyMakeBorder(image, 0, bottom, 0, right, cv2.BORDER_REPLICATE)
    return cv2.resize(image, ((w + right) // f, (h + bottom) // f), interpolation=cv2.INTER_AREA)


def reached_from(seed: np.ndarray, passable: np.ndarray, connectivity: int = 8) -> np.ndarray:
    """(H, W) bool: the connected regions of ``passable`` (H, W) bool that hold a pixel of
    ``seed`` (H, W) bool, neighbours taken ``connectivity`` (4 or 8) ways; seed pixels outside
    ``passable`` reach nothing and are not in it."""
    n, labels = cv2.connectedComponents(passable.astype(np.uint8), connectivity=connectivity)
    reached = np.bincount(labels[seed], minlength=n) > 0
    reached[0] = False
    return reached[labels]


def _pixel_points(uv: np.ndarray, shape) -> np.ndarray:
    """``uv`` (..., 2) finite pixel coordinates rounded to int32 for OpenCV's drawing, clipped
    to ten image sizes: far-off corners would overflow its fixed-point maths."""
    lim = 10 * max(shape)
    return np.clip(np.rint(uv), -lim, lim).astype(np.int32)


def _pixel_triangles(uv: np.ndarray, faces: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray]:
    """Integer triangles (K, 3, 2) of the faces whose corners are all finite, and their ids (K,)."""
    ok = np.all(np.isfinite(uv[faces]).reshape(len(faces), -1), axis=1)
    return _pixel_points(uv[faces[ok]], shape), np.flatnonzero(ok)


def faces_mask(uv: np.ndarray, faces: np.ndarray, shape: tuple[int, int], outline: list | None = None) -> np.ndarray:
    """(H, W) bool: pixels covered by the projected triangles.

    outline : ``perception.geometry.boundary_chains(faces)``, or None (or empty). With it, a
    mesh whose projected faces all turn the same side to the camera (nothing folded over in
    the image) and all project is drawn by its outline's loops in one call: the same pixels
    (the loops' edges are the triangles' outer edges, and even-odd filling leaves the holes
    out) at a fraction of the cost of drawing hundreds of triangles."""
    if outline:
        corners = uv[faces]
        if np.all(np.isfinite(corners)):
            e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
            area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
            if np.all(area > 0) or np.all(area < 0):
                mask = np.zeros(shape, np.uint8)
                pts = _pixel_points(uv, shape)
                cv2.fillPoly(mask, [pts[chain] for chain in outline], 1)
                return mask.view(bool)
    tri, _ = _pixel_triangles(uv, faces, shape)
    mask = np.zeros(shape, np.uint8)
    # fillPoly fills by the even-odd rule, so overlapping triangles would cancel; the two
    # triangle orientations of the hexagonal grid never overlap among themselves unless folded.
    for half in (tri[0::2], tri[1::2]):
        if len(half):
            layer = np.zeros_like(mask)
            cv2.fillPoly(layer, list(half), 1)
            mask |= layer
    return mask.astype(bool)


def face_index_image(uv: np.ndarray, faces: np.ndarray, depth: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) int32: id of the face seen at each pixel, -1 for none.

    depth : (N,) float per-vertex depth; where faces overlap, the nearer one is kept
    (painter's order by mean depth, exact for a mesh that does not interpenetrate).
    """
    tri, ids = _pixel_triangles(uv, faces, shape)
    img = np.full(shape, -1, np.int32)
    order = np.argsort(-depth[faces[ids]].mean(axis=1), kind="stable")
    # One OpenCV call per face: Python lists, not NumPy scalars, keep the loop's own cost below the drawing's.
    for t, i in zip(list(tri[order]), ids[order].tolist()):
        cv2.fillConvexPoly(img, t, i)
    return img


def locate_pixels(xy: np.ndarray, uv: np.ndarray, faces: np.ndarray, depth: np.ndarray, shape):
    """Face seen at each pixel (P, 2) and the point's barycentric coordinates in it.

    returns (face_ids (P,) int64, -1 where no face is seen; bary (P, 3) float64)
    """
    xy = np.asarray(xy, np.float64)
    h, w = shape
    img = face_index_image(uv, faces, depth, shape)
    cols = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
    rows = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
    fid = img[rows, cols].astype(np.int64)
    bary = np.zeros((len(xy), 3))
    hit = fid >= 0
    if hit.any():
        bary[hit] = barycentric_2d(xy[hit], uv[faces[fid[hit]]])
    return fid, bary
