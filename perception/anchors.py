"""Points of the first frame's texture found again in each frame: correspondences that do not drift.

KLT points (``perception.features.KLTCorrespondences``) are tracked from frame to frame, and
once too few remain new ones are bound to the mesh through the current estimate. Wherever the
estimate has slid, as on a printed cloth lifted by a corner and turned, the new points are
bound to the wrong material points and hold the mesh where it slid.

The frame the mesh was laid on says how each material point looks. Drawn as the predicted mesh
would show it (at each pixel the mesh covers, the first frame's grey value at the position
that pixel's material point had then), that texture is where the cloth should look the same as
in the new frame. Corners of the drawn view are followed into the new frame by pyramidal
Lucas-Kanade, checked backwards. Each one found joins a material point known exactly (the face
and barycentric coordinates of its pixel in the drawn view) to where the frame shows it, with no
estimate in between. Only faces seen in the first frame are drawn, and the drawn view takes the
frame's brightness and contrast over the mesh (a turned cloth is lit differently). Meant for a
textured cloth: on a plain one Lucas-Kanade has nothing to hold.

Images are (H, W) uint8 grey; vertices (N, 3) metres in the camera frame; faces (M, 3).
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.features import FB_MAX_PX, LK_PARAMS
from perception.geometry import project
from perception.mesh import barycentric_2d
from perception.raster import face_index_image

#: corners are looked for this far inside the drawn mesh (its rim mixes in the background), pixels
RIM_PX = 3
#: fewer drawn pixels than this inside the rim: too little of the mesh in view to look for corners
MIN_DRAWN_PX = 50
REMAP_ROW = 1024


def _sample(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(P,) ``image`` (H, W) float32 at pixels ``xy`` (P, 2), bilinear. The points go to
    OpenCV as rows of ``REMAP_ROW`` (it takes maps under 32767 pixels a side)."""
    n = len(xy)
    padded = np.zeros((-(-n // REMAP_ROW) * REMAP_ROW, 2), np.float32)
    padded[:n] = xy
    maps = padded.reshape(-1, REMAP_ROW, 2)
    return cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR).ravel()[:n]


class TextureAnchors:
    """The first frame's texture on the mesh; ``match`` finds it again in a later frame.

    grey : (H, W) uint8, the frame the mesh was laid on; vertices : (N, 3) the mesh in it;
    faces : (M, 3) int; seen : (N,) bool, the vertices seen in it; K : (3, 3)
    max_points : corners of the drawn view followed each frame
    """

    def __init__(self, grey: np.ndarray, vertices: np.ndarray, faces: np.ndarray, seen: np.ndarray, K: np.ndarray,
                 max_points: int):
        self._grey = np.asarray(grey, np.float32)
        self._uv0 = project(np.asarray(vertices, np.float64), K)
        self._faces = np.asarray(faces, np.int64)
        self._drawn = np.all(np.asarray(seen, bool)[self._faces], axis=1)
        self.max_points = int(max_points)
        self.last_found = 0  # points found in the last frame

    def _view(self, uv: np.ndarray, depth: np.ndarray, shape: tuple[int, int]):
        """The first frame's texture drawn at the mesh's image positions ``uv`` (N, 2) in a
        crop of ``shape``: (view (h, w) float32, face id image (h, w) int32, drawn (h, w) bool)."""
        face_ids = face_index_image(uv, self._faces, depth, shape)
        drawn = face_ids >= 0
        drawn[drawn] = self._drawn[face_ids[drawn]]
        rows, cols = np.nonzero(drawn)
        view = np.zeros(shape, np.float32)
        if len(rows):
            f = face_ids[rows, cols]
            bary = barycentric_2d(np.column_stack([cols, rows]).astype(np.float64), uv[self._faces[f]])
            then = np.einsum("pk,pkj->pj", bary, self._uv0[self._faces[f]]).astype(np.float32)
            view[rows, cols] = _sample(self._grey, then)
        return view, face_ids, drawn

    def match(self, grey: np.ndarray, mask: np.ndarray, vertices: np.ndarray, K: np.ndarray):
        """Material points of the first frame's texture found in ``grey`` near where the mesh
        ``vertices`` (N, 3) predicts them, on ``mask`` (H, W) bool:
        (face_ids (P,) int64, bary (P, 3), xy (P, 2) float32)."""
        none = np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2), np.float32)
        h, w = grey.shape
        uv = project(np.asarray(vertices, np.float64), K)
        finite = np.all(np.isfinite(uv), axis=1)
        if self.max_points < 1 or finite.sum() < 3:
            return none
        x0, y0 = np.maximum(np.floor(uv[finite].min(axis=0)).astype(int) - RIM_PX, 0)
        x1, y1 = np.minimum(np.ceil(uv[finite].max(axis=0)).astype(int) + RIM_PX + 1, [w, h])
        if x1 - x0 < 2 * RIM_PX + 3 or y1 - y0 < 2 * RIM_PX + 3:
            return none
        shift = np.array([x0, y0], np.float64)
        view, face_ids, drawn = self._view(uv - shift, vertices[:, 2], (y1 - y0, x1 - x0))
        inner = cv2.erode(drawn.astype(np.uint8), np.ones((2 * RIM_PX + 1,) * 2, np.uint8)).astype(bool)
        if inner.sum() < MIN_DRAWN_PX:
            return none
        now = grey[y0:y1, x0:x1].astype(np.float32)
        # the frame's brightness and contrast over the mesh; beyond it the frame itself, so that
        # Lucas-Kanade windows on the rim see the same surroundings in both
        gain = (now[inner].std() + 1e-3) / (view[inner].std() + 1e-3)
        view = np.where(drawn, (view - view[inner].mean()) * gain + now[inner].mean(), now)
        a = np.clip(view, 0, 255).astype(np.uint8)
        b = now.astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(a, self.max_points, 0.01, 5, mask=inner.astype(np.uint8) * 255)
        if corners is None:
            self.last_found = 0
            return none
        there, st, _ = cv2.calcOpticalFlowPyrLK(a, b, corners, None, **LK_PARAMS)
        back, st_back, _ = cv2.calcOpticalFlowPyrLK(b, a, there, None, **LK_PARAMS)
        p, q = corners.reshape(-1, 2), there.reshape(-1, 2)
        ok = (st.ravel() == 1) & (st_back.ravel() == 1) & (np.linalg.norm(back.reshape(-1, 2) - p, axis=1) < FB_MAX_PX)
        xy = q + shift
        cols, rows = np.rint(xy[:, 0]).astype(np.int64), np.rint(xy[:, 1]).astype(np.int64)
        ok &= (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        ok[ok] &= mask[rows[ok], cols[ok]]
        p, xy = p[ok], xy[ok]
        f = face_ids[np.rint(p[:, 1]).astype(np.int64), np.rint(p[:, 0]).astype(np.int64)].astype(np.int64)
        bary = barycentric_2d(p.astype(np.float64), (uv - shift)[self._faces[f]])
        self.last_found = len(f)
        return f, bary, xy.astype(np.float32)
