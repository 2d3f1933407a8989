"""Finding the object again anywhere in a frame, from how it looked when the mesh was made.

When the tracker's prediction is far off (a jump beyond what local search reaches) or the
estimate is lost, local matching has nothing to start from. Here descriptors found on the
object in the first frame, bound to the canonical mesh (paper eq. 11), are matched against
the whole new frame without the paper's spatial gate (nearest descriptor, Lowe's ratio
test), and a rigid motion is fitted to the matched 3D points by RANSAC: the mesh's
material points where a reference mesh has them, against the points the depth image puts
under the matches. The fit tolerates the cloth's deformation (``inlier_m``); the tracker's
minimisation then takes over from the placed mesh, with the inlier matches as its
correspondences.

Images are (H, W) uint8 grey; depth (H, W) float32 metres (0 or NaN: none); meshes
(N, 3) metres in the camera frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from perception.features import BoundFeatures, Detector, bind
from perception.geometry import backproject, pixel_index

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Registration:
    """A placement of the mesh found by global matching.

    rotation : (3, 3), translation : (3,): the rigid motion, reference mesh -> frame
    face_ids (P,) int, bary (P, 3), xy (P, 2) float32: the inlier matches (material point -> pixel)
    """

    rotation: np.ndarray
    translation: np.ndarray
    face_ids: np.ndarray
    bary: np.ndarray
    xy: np.ndarray

    def apply(self, vertices: np.ndarray) -> np.ndarray:
        """(N, 3) ``vertices`` moved by the rigid motion."""
        return vertices @ self.rotation.T + self.translation


def rigid_fit(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation R (3, 3) and translation t (3,) with R a + t ~ b, for (P, 3) points (Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


def ransac_rigid(a: np.ndarray, b: np.ndarray, inlier_m: float, rng: np.random.Generator, iterations: int = 300):
    """RANSAC of ``rigid_fit`` over matched (P, 3) points: (R, t, inliers (P,) bool) of the
    hypothesis with most inliers within ``inlier_m``, refitted on them; None under 3 points."""
    n = len(a)
    if n < 3:
        return None
    best = np.zeros(n, bool)
    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        if np.linalg.norm(np.cross(a[idx[1]] - a[idx[0]], a[idx[2]] - a[idx[0]])) < 1e-6:
            continue  # collinear sample
        R, t = rigid_fit(a[idx], b[idx])
        inl = np.linalg.norm(a @ R.T + t - b, axis=1) < inlier_m
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < 3:
        return None
    for _ in range(2):  # refit on the inliers, then take the inliers of the refit
        R, t = rigid_fit(a[best], b[best])
        refit = np.linalg.norm(a @ R.T + t - b, axis=1) < inlier_m
        if refit.sum() < 3:
            break
        best = refit
    return R, t, best


class GlobalRegistration:
    """Descriptors of the object as first seen, bound to the mesh, and their global matching.

    kind : detector ("sift", "orb" or "surf"); max_features : features kept per image
    ratio : Lowe's ratio test; inlier_m : RANSAC tolerance (deformation allowed), metres
    min_inliers : fewer inlier matches than this is no registration
    """

    def __init__(self, kind: str = "sift", max_features: int = 1500, ratio: float = 0.8, inlier_m: float = 0.05,
                 min_inliers: int = 12, rng: np.random.Generator | None = None):
        self.detector = Detector(kind, max_features)
        self.ratio = ratio
        self.inlier_m = inlier_m
        self.min_inliers = int(min_inliers)
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self.reference: BoundFeatures | None = None
        norm = cv2.NORM_HAMMING if self.detector.binary else cv2.NORM_L2
        self._matcher = cv2.BFMatcher(norm)
        # Local contrast equalisation: a cloth's weave or print is often faint, and SIFT's
        # contrast threshold then leaves a handful of features on it (tens instead of hundreds).
        self._clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))

    @property
    def usable(self) -> bool:
        """Whether the object showed enough features to be found by them."""
        return self.reference is not None and len(self.reference) >= self.min_inliers

    def build(self, grey: np.ndarray, mask: np.ndarray, vertices: np.ndarray, faces: np.ndarray, K: np.ndarray) -> None:
        """Detect and bind the reference features: the object ``mask`` (H, W) bool in ``grey``,
        under the mesh ``vertices`` (N, 3)."""
        self.reference = bind(self.detector.detect(self._clahe.apply(grey), mask), vertices, faces, K, grey.shape)
        log.debug("global registration: %d reference features", len(self.reference))

    def register(self, grey: np.ndarray, depth_m: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 K: np.ndarray, search_mask: np.ndarray | None = None) -> Registration | None:
        """Place the mesh ``vertices`` (N, 3; any shape of the same mesh, e.g. the last good
        estimate) in a new frame; None when too few matches agree on a rigid motion.

        search_mask : (H, W) bool where to look for the object (default: every pixel with depth)
        """
        if not self.usable:
            return None
        valid = np.isfinite(depth_m) & (depth_m > 0)
        where = valid if search_mask is None else (search_mask & valid)
        current = self.detector.detect(self._clahe.apply(grey), where)
        if len(current) < self.min_inliers:
            return None
        pairs = self._matcher.knnMatch(self.reference.keypoints.desc, current.desc, k=2)
        ref_idx, cur_idx = [], []
        for p in pairs:
            if len(p) == 2 and p[0].distance < self.ratio * p[1].distance:
                ref_idx.append(p[0].queryIdx)
                cur_idx.append(p[0].trainIdx)
        if len(ref_idx) < self.min_inliers:
            return None
        ref_idx, cur_idx = np.array(ref_idx), np.array(cur_idx)
        xy = current.xy[cur_idx]
        h, w = depth_m.shape
        cols, rows, inside = pixel_index(xy.astype(np.float64), w, h)
        d = np.where(inside, depth_m[rows, cols], 0.0)
        has = np.isfinite(d) & (d > 0)
        fid, bary = self.reference.face_ids[ref_idx], self.reference.bary[ref_idx]
        model = np.einsum("pk,pkj->pj", bary, vertices[faces[fid]])
        scene = backproject(xy.astype(np.float64), d, K)
        found = ransac_rigid(model[has], scene[has], self.inlier_m, self._rng)
        if found is None:
            return None
        R, t, inl = found
        if inl.sum() < self.min_inliers:
            return None
        keep = np.flatnonzero(has)[inl]
        log.debug("global registration: %d of %d matches agree", len(keep), len(ref_idx))
        return Registration(R, t, fid[keep], bary[keep], xy[keep])
