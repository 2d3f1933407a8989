"""Feature correspondences for the correspondence term (paper, section III-B).

Features found on the object in the first frame are bound to the canonical mesh by
barycentric coordinates (eq. 11-12). In later frames they are matched with the paper's
rules: nearest descriptor by distance, only among features within a gate around the
location predicted from the previous estimate, keeping the best half. Matching against
the first frame's features keeps correspondences from drifting over long sequences; the
previous frame's features (bound through the previous estimate) are matched as well, so
the term survives appearance changes such as rotation out of the image plane.

Detectors: SURF (the paper's) when this OpenCV build has it, else SIFT; ORB for speed.
Pyramidal KLT tracking of the bound points is the fastest option (``KLTCorrespondences``).

Images are (H, W) uint8 grey; points are (P, 2) float32 pixel coordinates (u, v).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from perception.geometry import pixel_index, project
from perception.raster import bounding_box, locate_pixels
from perception.trackable import MIN_TEXTURE_SNR, trackable
from perception.visibility import FACE_OUT_OF_VIEW, FACE_VISIBLE

log = logging.getLogger(__name__)

FEATURE_KINDS = ("auto", "surf", "sift", "orb", "klt")
#: Pyramidal Lucas-Kanade for points followed from one image into another: 15 px windows,
#: two pyramid levels (KLT points, ``perception.anchors``)
LK_PARAMS = dict(winSize=(15, 15), maxLevel=2, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
#: a followed point is kept when following it back lands this close to where it started, pixels
FB_MAX_PX = 1.0


def surf_available() -> bool:
    """True when this OpenCV build ships the (patented) SURF detector."""
    try:
        cv2.xfeatures2d.SURF_create()  # type: ignore[attr-defined]
        return True
    except (AttributeError, cv2.error):
        return False


def resolve_kind(kind: str) -> str:
    """The detector actually used for ``kind``: 'auto' means SURF if available, else SIFT."""
    if kind not in FEATURE_KINDS:
        raise ValueError(f"features: expected one of {FEATURE_KINDS}, got {kind!r}")
    if kind == "auto":
        return "surf" if surf_available() else "sift"
    if kind == "surf" and not surf_available():
        raise ValueError("features: SURF is not in this OpenCV build (it is patented); use sift, orb or klt")
    return kind


@dataclass
class Keypoints:
    """Detected features: xy (P, 2) float32 pixels; desc (P, D) float32 or uint8 (binary)."""

    xy: np.ndarray
    desc: np.ndarray
    binary: bool

    def __len__(self):
        return len(self.xy)

    def subset(self, idx) -> Keypoints:
        return Keypoints(self.xy[idx], self.desc[idx], self.binary)


class Detector:
    """Wraps an OpenCV detector/descriptor; ``detect(grey, mask)`` returns Keypoints."""

    def __init__(self, kind: str, max_features: int):
        self.kind = resolve_kind(kind)
        if self.kind == "klt":
            raise ValueError("features: klt tracks points, it has no descriptor detector")
        self.max_features = int(max_features)
        if self.kind == "surf":
            self._cv = cv2.xfeatures2d.SURF_create(hessianThreshold=300)  # type: ignore[attr-defined]
        elif self.kind == "sift":
            self._cv = cv2.SIFT_create(nfeatures=self.max_features, contrastThreshold=0.02)
        else:
            self._cv = cv2.ORB_create(nfeatures=self.max_features, fastThreshold=10, edgeThreshold=15, patchSize=15)
        self.binary = self.kind == "orb"

    def detect(self, grey: np.ndarray, mask: np.ndarray) -> Keypoints:
        descriptors = np.zeros((0, 32 if self.binary else 64), np.uint8 if self.binary else np.float32)
        empty = Keypoints(np.zeros((0, 2), np.float32), descriptors, self.binary)
        box = bounding_box(mask, pad=16)  # detect in the object's box only: most of a frame is background
        if box is None:
            return empty
        y0, y1, x0, x1 = box
        roi_mask = mask[y0:y1, x0:x1].astype(np.uint8) * 255
        kps, desc = self._cv.detectAndCompute(np.ascontiguousarray(grey[y0:y1, x0:x1]), roi_mask)
        if desc is None or len(kps) == 0:
            return empty
        if len(kps) > self.max_features:
            order = np.argsort([-k.response for k in kps])[: self.max_features]
            kps = [kps[i] for i in order]
            desc = desc[order]
        xy = np.array([k.pt for k in kps], np.float32) + np.array([x0, y0], np.float32)
        return Keypoints(xy, desc if self.binary else desc.astype(np.float32), self.binary)


def pair_distances(a: np.ndarray, b: np.ndarray, binary: bool) -> np.ndarray:
    """(K,) float32 distances between descriptor rows a[k] and b[k]: Hamming for binary, else Euclidean."""
    if binary:
        return np.unpackbits(np.bitwise_xor(a, b), axis=1).sum(axis=1).astype(np.float32)
    d = a - b
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def match_gated(model: Keypoints, predicted_xy: np.ndarray, current: Keypoints, gate_px: float,
                keep_fraction: float = 0.5, max_candidates: int = 32):
    """The paper's putative matching.

    For each model feature, the nearest current descriptor among current features lying
    within ``gate_px`` of its predicted location; each current feature is used once (by
    its closest model feature); then the best ``keep_fraction`` by descriptor distance.

    predicted_xy : (P, 2) float predicted pixel of each model feature (NaN: not predicted)
    returns (model_idx (K,), current_idx (K,)) int arrays
    """
    none = np.zeros(0, np.int64), np.zeros(0, np.int64)
    ok = np.all(np.isfinite(predicted_xy), axis=1)
    if len(model) == 0 or len(current) == 0 or not ok.any():
        return none
    # Candidate pairs from the spatial gate first (the nearest ``max_candidates`` current
    # features within the gate): descriptors are compared only there.
    tree = cKDTree(current.xy)
    m_ok = np.flatnonzero(ok)
    k = min(max_candidates, len(current))
    gap, cand = tree.query(predicted_xy[m_ok], k=k, distance_upper_bound=gate_px)
    gap, cand = gap.reshape(len(m_ok), k), cand.reshape(len(m_ok), k)
    inside = np.isfinite(gap)
    if not inside.any():
        return none
    m_pair = np.broadcast_to(m_ok[:, None], cand.shape)[inside]
    c_pair = cand[inside]
    d_pair = pair_distances(model.desc[m_pair], current.desc[c_pair], model.binary)
    # nearest descriptor per model feature
    order = np.lexsort((d_pair, m_pair))
    first = np.ones(len(order), bool)
    first[1:] = m_pair[order][1:] != m_pair[order][:-1]
    best = order[first]
    m_idx, c_idx, d = m_pair[best], c_pair[best], d_pair[best]
    # One model feature per current feature: the closest in descriptor space wins.
    order = np.lexsort((d, c_idx))
    first = np.ones(len(order), bool)
    first[1:] = c_idx[order][1:] != c_idx[order][:-1]
    sel = order[first]
    m_idx, c_idx, d = m_idx[sel], c_idx[sel], d[sel]
    n_keep = max(1, int(np.ceil(keep_fraction * len(d))))
    top = np.argsort(d, kind="stable")[:n_keep]
    return m_idx[top], c_idx[top]


@dataclass
class BoundFeatures:
    """Features bound to the mesh: keypoints plus face id (P,) and barycentric (P, 3)."""

    keypoints: Keypoints
    face_ids: np.ndarray
    bary: np.ndarray

    def __len__(self):
        return len(self.face_ids)


def bind_points(xy: np.ndarray, V: np.ndarray, faces: np.ndarray, K: np.ndarray, shape: tuple[int, int]):
    """Bind pixels to the mesh V as seen in an image of ``shape`` (H, W) (paper eq. 11).

    Where the projected mesh overlaps itself, a pixel is bound to the face nearest the camera.
    returns (face_ids (P,) int64 with -1 where no face covers the pixel, bary (P, 3))
    """
    return locate_pixels(xy, project(V, K), faces, V[:, 2], shape)


def bind(kp: Keypoints, V: np.ndarray, faces: np.ndarray, K: np.ndarray, shape) -> BoundFeatures:
    face_ids, bary = bind_points(kp.xy, V, faces, K, shape)
    ok = face_ids >= 0
    return BoundFeatures(kp.subset(ok), face_ids[ok], bary[ok])


def predict_xy(bound: BoundFeatures, V: np.ndarray, faces: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(P, 2) predicted pixels of bound features for mesh V (paper eq. 12, then projection)."""
    pts = np.einsum("pk,pkj->pj", bound.bary, V[faces[bound.face_ids]])
    return project(pts, K)


def on_mask(xy: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(P,) bool: pixel (P, 2) lies in the image and on ``mask`` (H, W) bool."""
    h, w = mask.shape
    cols, rows, inside = pixel_index(np.asarray(xy, np.float64), w, h)
    return inside & mask[rows, cols]


class DescriptorCorrespondences:
    """Matches features of each frame to the first frame's and the previous frame's bound features."""

    def __init__(self, kind: str, max_features: int, gate_px: float, keep_fraction: float, match_previous: bool):
        self.detector = Detector(kind, max_features)
        self.gate_px = gate_px
        self.keep_fraction = keep_fraction
        self.match_previous = match_previous
        self.first: BoundFeatures | None = None
        self.previous: BoundFeatures | None = None
        self._current: Keypoints | None = None

    @property
    def n_model(self) -> int:
        return len(self.first) if self.first is not None else 0

    def initialise(self, grey, mask, V, faces, K):
        self.first = bind(self.detector.detect(grey, mask), V, faces, K, grey.shape)
        self.previous = None
        log.debug("bound %d first-frame features", len(self.first))

    def prepare(self, grey, V_pred, faces, K, predicted_mask=None):
        """Nothing: detection needs the object mask (a feature's descriptor must describe the
        object, not what lies beyond its edge), so it happens in ``match``."""
        return None

    def match(self, grey, mask, V_pred, faces, K, prepared=None, face_state=None):
        """Matches for a new frame: (face_ids (P,), bary (P, 3), xy (P, 2) pixels in this frame).
        face_state : (M,) int, ``perception.visibility.face_states`` of the prediction; features
        bound to faces predicted out of view are not matched. Those predicted hidden are: the
        object mask holds no occluder, and a match there means the face has come out from behind it."""
        cur = self.detector.detect(grey, mask)
        self._current = cur
        faces_out, bary_out, xy_out = [], [], []
        used = np.zeros(len(cur), bool)
        for model in (self.first, self.previous if self.match_previous else None):
            if model is None or len(model) == 0:
                continue
            pred = predict_xy(model, V_pred, faces, K)
            if face_state is not None:
                pred[face_state[model.face_ids] == FACE_OUT_OF_VIEW] = np.nan
            mi, ci = match_gated(model.keypoints, pred, cur, self.gate_px, self.keep_fraction)
            fresh = ~used[ci]
            mi, ci = mi[fresh], ci[fresh]
            used[ci] = True
            faces_out.append(model.face_ids[mi])
            bary_out.append(model.bary[mi])
            xy_out.append(cur.xy[ci])
        if not faces_out:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2), np.float32)
        return np.concatenate(faces_out), np.concatenate(bary_out), np.concatenate(xy_out)

    def update(self, grey, mask, V, faces, K):
        """After solving a frame: bind its features through the estimate, for the next frame."""
        if self.match_previous and self._current is not None:
            self.previous = bind(self._current, V, faces, K, grey.shape)


@dataclass
class _TrackedPoints:
    """Points bound to the mesh that optical flow follows.

    face_ids (P,) int64, bary (P, 3) float64: the binding; xy (P, 2) float32: where each
    point is now (for dormant points: where it was last seen); ref (P,) int64: the
    reference image it was found in, ref_xy (P, 2) float32: its position there.
    """

    face_ids: np.ndarray
    bary: np.ndarray
    xy: np.ndarray
    ref: np.ndarray
    ref_xy: np.ndarray

    @classmethod
    def empty(cls) -> _TrackedPoints:
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2), np.float32), np.zeros(0, np.int64),
                   np.zeros((0, 2), np.float32))

    def __len__(self):
        return len(self.face_ids)

    def take(self, keep) -> _TrackedPoints:
        return _TrackedPoints(self.face_ids[keep], self.bary[keep], self.xy[keep], self.ref[keep], self.ref_xy[keep])

    def join(self, other: _TrackedPoints) -> _TrackedPoints:
        return _TrackedPoints(*(np.concatenate([getattr(self, f), getattr(other, f)])
                                for f in ("face_ids", "bary", "xy", "ref", "ref_xy")))


class KLTCorrespondences:
    """Pyramidal Lucas-Kanade tracking of points bound to the mesh.

    Points are found (Shi-Tomasi corners) and bound in the first frame, tracked frame to
    frame starting from where the previous estimate predicts them, and kept only when
    tracking back lands within ``fb_max_px`` of the start. When fewer than half remain,
    new points are found and bound through the current estimate.

    A point that is lost (hidden behind an occluder, off the object, or failing the
    forward-backward check) goes dormant instead of being forgotten: once the estimate
    predicts its face to be seen again, it is looked for from the reference image it was
    found in, at most ``revive_per_frame`` points a frame. That is how a region that was
    hidden for a while is found again where it really is, not where the motion prior put
    it. The most recent ``max_references`` reference images are kept. The search runs in
    every frame for a second after a point was hidden, otherwise every ``revive_every`` frames:
    it costs about as much as the frame's own optical flow.
    """

    def __init__(self, max_features: int, min_texture_snr: float = MIN_TEXTURE_SNR, fb_max_px: float = FB_MAX_PX,
                 max_references: int = 4, revive_per_frame: int = 100, revive_every: int = 3):
        self.max_features = int(max_features)
        self.min_texture_snr = float(min_texture_snr)
        self.fb_max_px = fb_max_px
        self.max_references = int(max_references)
        self.revive_per_frame = int(revive_per_frame)
        self.revive_every = int(revive_every)
        self._frames = 0
        self._since_hidden = np.inf  # frames since a point last went dormant behind an occluder
        self.active = _TrackedPoints.empty()
        self.dormant = _TrackedPoints.empty()
        self._refs: dict[int, np.ndarray] = {}
        self._next_ref = 0
        self._grey = None
        self._target = 0

    @property
    def n_model(self) -> int:
        return len(self.active)

    def _seed(self, grey, mask, V, faces, K, count: int, keep_away: np.ndarray | None = None) -> _TrackedPoints:
        """Find and bind up to ``count`` new corners in ``mask``, 5 px or more from ``keep_away``
        (P, 2); ``grey`` becomes their reference image. Only where the texture stands
        ``min_texture_snr`` times above the image's noise (``perception.trackable``): corners of
        noise on smooth shading would be followed with the shading, not with the material."""
        if self.min_texture_snr > 0:
            mask = trackable(grey, mask, LK_PARAMS["winSize"][0], self.min_texture_snr)
        allowed = mask.astype(np.uint8) * 255
        if keep_away is not None:
            for u, v in np.rint(keep_away).astype(int):
                cv2.circle(allowed, (int(u), int(v)), 5, 0, -1)
        pts = cv2.goodFeaturesToTrack(grey, max(1, count), 0.01, 5, mask=allowed)
        xy = np.zeros((0, 2), np.float32) if pts is None else pts.reshape(-1, 2).astype(np.float32)
        face_ids, bary = bind_points(xy, V, faces, K, grey.shape)
        ok = face_ids >= 0
        ref = self._next_ref
        self._next_ref += 1
        self._refs[ref] = grey
        for old in sorted(self._refs)[: -self.max_references]:  # forget the oldest references and their points
            del self._refs[old]
            self.dormant = self.dormant.take(self.dormant.ref != old)
        return _TrackedPoints(face_ids[ok], bary[ok], xy[ok], np.full(int(ok.sum()), ref, np.int64), xy[ok].copy())

    def initialise(self, grey, mask, V, faces, K):
        self._refs.clear()
        self.dormant = _TrackedPoints.empty()
        self.active = self._seed(grey, mask, V, faces, K, self.max_features)
        self._target = len(self.active)
        self._grey = grey

    def _predicted(self, points: _TrackedPoints, V, faces, K) -> np.ndarray:
        pts = np.einsum("pk,pkj->pj", points.bary, V[faces[points.face_ids]])
        return project(pts, K).astype(np.float32)

    def _flow(self, before, now, p0, guess):
        """LK from ``before`` at p0 (P, 2) to ``now`` starting at ``guess`` (P, 2), checked
        backwards: (xy (P, 2) float32, ok (P,) bool). Runs on the crop that holds the points,
        their guesses and the coarsest level's search window (OpenCV's Python binding builds
        both pyramids afresh on every call)."""
        h, w = now.shape
        ends = np.concatenate([p0, guess])
        pad = LK_PARAMS["winSize"][0] * 2 ** LK_PARAMS["maxLevel"]
        x0, y0 = (max(0, int(v) - pad) for v in np.floor(ends.min(axis=0)))
        x1, y1 = (int(v) + pad for v in np.ceil(ends.max(axis=0)))
        x1, y1 = min(w, max(x1, x0 + 1)), min(h, max(y1, y0 + 1))
        a, b, shift = before[y0:y1, x0:x1], now[y0:y1, x0:x1], np.float32([x0, y0])
        q0 = (p0 - shift).reshape(-1, 1, 2)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(a, b, q0, (guess - shift).reshape(-1, 1, 2),
                                             flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **LK_PARAMS)
        pb, stb, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, q0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **LK_PARAMS)
        fb = np.linalg.norm((pb - q0).reshape(-1, 2), axis=1)
        return p1.reshape(-1, 2) + shift, (st.ravel() == 1) & (stb.ravel() == 1) & (fb < self.fb_max_px)

    def prepare(self, grey, V_pred, faces, K, predicted_mask=None):
        """Optical flow of the active points into ``grey``, checked forwards and backwards:
        (xy (P, 2) float32, ok (P,) bool). Needs no object mask and changes no state, so it
        can run on another thread while the frame is segmented."""
        if len(self.active) == 0 or self._grey is None:
            return np.zeros((0, 2), np.float32), np.zeros(0, bool)
        guess = self._predicted(self.active, V_pred, faces, K)
        guess = np.where(np.isfinite(guess), guess, self.active.xy)
        return self._flow(self._grey, grey, self.active.xy, guess)

    def _revive(self, grey, mask, V_pred, faces, K, face_state) -> _TrackedPoints:
        """Dormant points whose faces are predicted in view, looked for from their reference
        images (those predicted hidden too: a part that was hidden comes out from behind the
        occluder a little away from where the motion prior carried it); returns those found on
        the object (and removes them from the dormant set)."""
        seen = face_state[self.dormant.face_ids] != FACE_OUT_OF_VIEW if face_state is not None \
            else np.ones(len(self.dormant), bool)
        candidates = np.flatnonzero(seen)[: self.revive_per_frame]
        if len(candidates) == 0:
            return _TrackedPoints.empty()
        pts = self.dormant.take(candidates)
        guess = self._predicted(pts, V_pred, faces, K)
        found = np.zeros(len(pts), bool)
        for ref in np.unique(pts.ref):
            sel = np.flatnonzero((pts.ref == ref) & np.all(np.isfinite(guess), axis=1))
            if len(sel):
                xy, ok = self._flow(self._refs[ref], grey, pts.ref_xy[sel], guess[sel])
                ok &= on_mask(xy, mask)
                pts.xy[sel[ok]] = xy[ok]
                found[sel[ok]] = True
        # Points tried and not found go to the back of the queue, so every dormant point gets its turn.
        rest = np.setdiff1d(np.arange(len(self.dormant)), candidates)
        self.dormant = self.dormant.take(rest).join(pts.take(~found))
        return pts.take(found)

    def match(self, grey, mask, V_pred, faces, K, prepared, face_state=None):
        """The points on the object in this frame: (face_ids (P,), bary (P, 3), xy (P, 2)).
        prepared : what ``prepare`` returned for this frame
        face_state : (M,) int, ``perception.visibility.face_states`` of the prediction; points
            on faces not predicted visible go dormant (optical flow cannot follow a point
            through an occluder: it slides along the occluder's edge)."""
        if self._grey is None:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 2), np.float32)
        xy, ok = prepared
        if len(self.active):
            ok = ok & on_mask(xy, mask)
            if face_state is not None:
                hidden = face_state[self.active.face_ids] != FACE_VISIBLE
                if (hidden & ok).any():
                    self._since_hidden = 0
                ok &= ~hidden
            self.active.xy = xy.astype(np.float32)
            lost = self.active.take(~ok)
            self.dormant = self.dormant.join(lost.take(np.isin(lost.ref, list(self._refs))))  # revivable ones
            self.active = self.active.take(ok)
        self._frames += 1
        self._since_hidden += 1
        if len(self.dormant) and (self._since_hidden <= 30 or self._frames % self.revive_every == 0):
            self.active = self.active.join(self._revive(grey, mask, V_pred, faces, K, face_state))
        self._grey = grey
        return self.active.face_ids, self.active.bary, self.active.xy

    def update(self, grey, mask, V, faces, K):
        self._grey = grey
        if len(self.active) < 0.5 * self._target:
            fresh = self._seed(grey, mask, V, faces, K, self.max_features - len(self.active), keep_away=self.active.xy)
            self.active = self.active.join(fresh)


class CombinedCorrespondences:
    """Descriptor matches and KLT points together, for an object whose texture gives the
    descriptors too little to hold on to (a foam tube, a faintly printed cloth): the
    descriptors keep the mesh from drifting, the points keep it dense."""

    def __init__(self, descriptors: DescriptorCorrespondences, points: KLTCorrespondences):
        self.descriptors, self.points = descriptors, points

    @property
    def n_model(self) -> int:
        return self.descriptors.n_model + self.points.n_model

    def initialise(self, grey, mask, V, faces, K):
        self.descriptors.initialise(grey, mask, V, faces, K)
        self.points.initialise(grey, mask, V, faces, K)

    def prepare(self, grey, V_pred, faces, K, predicted_mask=None):
        return self.points.prepare(grey, V_pred, faces, K, predicted_mask)

    def match(self, grey, mask, V_pred, faces, K, prepared, face_state=None):
        found = [self.descriptors.match(grey, mask, V_pred, faces, K, None, face_state),
                 self.points.match(grey, mask, V_pred, faces, K, prepared, face_state)]
        return tuple(np.concatenate(parts) for parts in zip(*found))

    def update(self, grey, mask, V, faces, K):
        self.descriptors.update(grey, mask, V, faces, K)
        self.points.update(grey, mask, V, faces, K)


def make_correspondences(kind: str, max_features: int, gate_px: float, keep_fraction: float, match_previous: bool,
                         min_texture_snr: float = MIN_TEXTURE_SNR):
    """The correspondence source for a feature kind (see FEATURE_KINDS); ``min_texture_snr``
    is KLT's (``KLTCorrespondences``)."""
    kind = resolve_kind(kind)
    if kind == "klt":
        return KLTCorrespondences(max_features, min_texture_snr)
    return DescriptorCorrespondences(kind, max_features, gate_px, keep_fraction, match_previous)
