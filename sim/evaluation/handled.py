"""Scoring a tracker on a cloth being handled: occluders, fast motion, dropped frames.

One ``HandledScore`` per tracking run on a ``sim.evaluation.SceneRecording`` of a handled
scene (``sim.scenes.HANDLED_SCENES``). Per frame it keeps:

- the material-point error of every vertex (``sim.ground_truth``): each estimated vertex is
  bound to the true surface in the run's first frame and followed as a material point (if
  the tracker rebuilds its mesh mid-run, a new canonical mesh, its vertices are bound again
  in that frame);
- which estimated vertices are truly hidden behind the occluder: their material point
  projects onto the occluder's exact mask and lies behind it;
- the occluded area ratio: the area of the estimated faces whose three vertices are truly
  hidden, over the same faces' area in the tracker's canonical mesh (1 = kept its size);
- the tracker's confidence, lost flag, per-vertex visibility (when it reports one) and time.

"Wrong" means a frame's mean vertex error exceeds ``WRONG_MM`` (30 mm); a wrong frame whose
confidence is at least ``CONFIDENT`` (0.5) is a confident wrong estimate, the defect a robot
cannot guard against. A wrong estimate should be flagged lost within ``LOST_WITHIN`` (3)
frames: a wrong frame not flagged lost after that many wrong frames in a row is late
(``wrong_unflagged_late_frames``). The occluded area ratio of a run is area-weighted over its
frames; its worst frame is taken among frames whose hidden faces make up at least
``WORST_AREA_MIN`` (2 %) of the mesh's canonical area, as one or two hidden faces say little.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from ipc.messages import MeshEstimate, RGBDFrame
from perception.geometry import face_areas
from perception.tracker import MeshTracker, TrackerConfig
from sim.evaluation.runs import SceneRecording
from sim.ground_truth import hidden_behind_occluder, material_point_tracks, occluded_area_ratio

log = logging.getLogger(__name__)

#: A frame whose mean vertex error exceeds this (millimetres) is wrong.
WRONG_MM = 30.0
#: A wrong frame with at least this confidence is a confident wrong estimate.
CONFIDENT = 0.5
#: A wrong estimate should be flagged lost within this many frames of going wrong.
LOST_WITHIN = 3
#: Frames whose hidden faces hold at least this fraction of the canonical mesh's area count
#: towards the worst occluded area ratio.
WORST_AREA_MIN = 0.02
#: A robot takes a mesh vertex as the one its closed gripper holds only when the vertex
#: lies this close to the fingertip centre (metres): between the jaws of the scenes'
#: grippers, which open 6-9 cm.
HOLD_REACH_M = 0.03


def unflagged_late(wrong: np.ndarray, lost: np.ndarray) -> np.ndarray:
    """(T,) bool: the frames of a run that are ``wrong`` (T,) bool and not flagged ``lost``
    (T,) bool although ``LOST_WITHIN`` wrong frames came right before them."""
    late = np.zeros(len(wrong), bool)
    streak = 0  # wrong frames in a row before this one
    for i, w in enumerate(wrong):
        late[i] = bool(w) and streak >= LOST_WITHIN and not bool(lost[i])
        streak = streak + 1 if w else 0
    return late


@dataclass
class HandledScore:
    """Per-frame ground-truth scores of one tracking run (T frames).

    errors_mm : list of T (N_t,) float64 arrays, each vertex's material-point error
    hidden : list of T (N_t,) bool, vertices truly hidden behind the occluder
    area_ratio : (T,) float64, occluded area ratio (nan where no face is hidden)
    hidden_area_m2 : (T,) float64, canonical area of the hidden faces
    mesh_area_m2 : (T,) float64, canonical area of the whole mesh
    confidence : (T,) float64; lost : (T,) bool; timing_ms : (T,) float64
    shown_hidden : (T,) int, truly hidden vertices the tracker reported visible (-1 when it
        reports no visibility)
    failure : "" or the one-line reason the run stopped early (frames up to it are scored)
    new_mesh : (T,) bool, frames whose estimate comes with a new canonical mesh (the tracker
        re-acquired the object by segmenting it again); its errors count from there, each
        vertex bound to the material point it was laid on; None: none
    """

    errors_mm: list
    hidden: list
    area_ratio: np.ndarray
    hidden_area_m2: np.ndarray
    mesh_area_m2: np.ndarray
    confidence: np.ndarray
    lost: np.ndarray
    timing_ms: np.ndarray
    shown_hidden: np.ndarray
    failure: str = ""
    new_mesh: np.ndarray | None = None
    estimates: list = field(default_factory=list, repr=False)

    @property
    def n_frames(self) -> int:
        return len(self.errors_mm)

    def frame_mean_mm(self) -> np.ndarray:
        """(T,) mean vertex error of each frame, millimetres."""
        return np.array([e.mean() for e in self.errors_mm])

    def wrong(self) -> np.ndarray:
        """(T,) bool, frames whose mean error exceeds ``WRONG_MM``."""
        return self.frame_mean_mm() > WRONG_MM

    def wrong_unflagged_late(self) -> np.ndarray:
        """(T,) bool, wrong frames not flagged lost after ``LOST_WITHIN`` wrong frames in a row."""
        return unflagged_late(self.wrong(), self.lost)

    def summary(self, frames: np.ndarray | None = None) -> dict:
        """Scores over all frames, or over the frame indices ``frames`` (int array)."""
        idx = np.arange(self.n_frames) if frames is None else np.asarray(frames, dtype=np.int64)
        idx = idx[idx < self.n_frames]
        if len(idx) == 0:
            return {"frames": 0, "failure": self.failure}
        errors = np.concatenate([self.errors_mm[i] for i in idx])
        hidden_err = np.concatenate([self.errors_mm[i][self.hidden[i]] for i in idx])
        area = self.hidden_area_m2[idx]
        ratio = self.area_ratio[idx]
        weighted = area > 0
        large = weighted & (area >= WORST_AREA_MIN * self.mesh_area_m2[idx])
        wrong = self.wrong()[idx]
        confident = self.confidence[idx] >= CONFIDENT
        known_visibility = self.shown_hidden[idx] >= 0
        n_hidden = np.array([self.hidden[i].sum() for i in idx])
        return {
            "frames": int(len(idx)),
            "mean_mm": float(errors.mean()),
            "p95_mm": float(np.percentile(errors, 95)),
            "hidden_mean_mm": float(hidden_err.mean()) if hidden_err.size else None,
            "frames_with_hidden_vertices": int((n_hidden > 0).sum()),
            # area-weighted over frames: the hidden part's total estimated area over its total rest area
            "occluded_area_ratio": float(np.sum(ratio[weighted] * area[weighted]) / area[weighted].sum())
            if weighted.any() else None,
            "occluded_area_ratio_worst": float(ratio[large][np.argmax(np.abs(ratio[large] - 1.0))])
            if large.any() else None,
            "lost_frames": int(self.lost[idx].sum()),
            "new_meshes": 0 if self.new_mesh is None else int(self.new_mesh[idx].sum()),
            "wrong_frames": int(wrong.sum()),
            "wrong_confident_frames": int((wrong & confident).sum()),
            "wrong_unflagged_late_frames": int(self.wrong_unflagged_late()[idx].sum()),
            "hidden_shown_visible": (float(self.shown_hidden[idx][known_visibility].sum() /
                                           max(n_hidden[known_visibility].sum(), 1))
                                     if known_visibility.any() else None),
            "median_ms": float(np.median(self.timing_ms[idx][idx > 0])) if np.any(idx > 0) else None,
            "failure": self.failure,
        }

    def series(self) -> dict:
        """Per-frame lists for a JSON report."""
        return {
            "mean_mm": [round(float(x), 2) for x in self.frame_mean_mm()],
            "confidence": [round(float(x), 3) for x in self.confidence],
            "lost": [bool(x) for x in self.lost],
            "new_mesh_frames": [] if self.new_mesh is None else [int(i) for i in np.flatnonzero(self.new_mesh)],
            "hidden_vertices": [int(h.sum()) for h in self.hidden],
            "area_ratio": [None if np.isnan(x) else round(float(x), 3) for x in self.area_ratio],
        }


def track_frames(frames: list, config: TrackerConfig, init_mask: np.ndarray, label: str = "tracker",
                 progress: bool = True, background: RGBDFrame | None = None,
                 grips: list | None = None) -> tuple[list, str]:
    """Run a fresh MeshTracker over ``frames`` (initialised on ``init_mask`` (H, W) bool).

    background : the empty workspace from the same camera, given at initialisation, or None
    grips : None, or per frame the robot's closed grippers (``SceneRecording.grips``): each
        holds the mesh vertex nearest to it when it closed, if that vertex lies within
        ``HOLD_REACH_M`` of it, and the frames say so (``RGBDFrame.held_vertices``), as a
        robot that knows what it holds and where its fingers are would send them. On a mesh
        the tracker builds anew (new vertex ids) a gripper is bound again the same way: a
        new mesh laid over the cloth that shows often ends centimetres short of the corner
        hidden in the fingers, and then no vertex of it is known to be held
    returns (MeshEstimates, failure): the estimates up to the first frame the tracker raised
    on, and that error as one line ("" when every frame was tracked)
    """
    tracker = MeshTracker(config)
    estimates: list = []
    held: dict[int, int] = {}  # gripper number -> mesh vertex it holds
    for i, frame in enumerate(tqdm(frames, desc=label, unit="frame", disable=not progress, leave=False)):
        try:
            if i == 0:
                estimates.append(tracker.initialise(frame, mask=init_mask, background=background))
                continue
            if grips:
                frame = _holding(frame, grips[i], held, estimates[-1])
            estimate = tracker.track(frame)
            if not np.array_equal(estimate.canonical, estimates[-1].canonical):
                held.clear()  # a new mesh: its vertex ids say nothing of the old one's
            estimates.append(estimate)
        except Exception as e:  # a tracker failure is a result to report, not a reason to stop the evaluation
            failure = f"frame {i}: {type(e).__name__}: {e}".splitlines()[0]
            log.warning("%s: %s", label, failure)
            return estimates, failure
    return estimates, ""


def _holding(frame: RGBDFrame, grips: dict, held: dict, previous: MeshEstimate) -> RGBDFrame:
    """``frame`` with the held vertices of the grippers in ``grips`` (binding in ``held`` each
    closed gripper not bound yet to the vertex of ``previous`` nearest to it, when that lies
    within ``HOLD_REACH_M``; a gripper with none so near stays unbound and is not sent)."""
    for gripper in list(held):
        if gripper not in grips:
            del held[gripper]  # opened
    for gripper, point in grips.items():
        if gripper not in held:
            distance = np.linalg.norm(previous.vertices - point, axis=1)
            if distance.min() <= HOLD_REACH_M:
                held[gripper] = int(np.argmin(distance))
    order = [g for g in sorted(grips) if g in held]
    if not order:
        return frame
    return dataclasses.replace(frame, held_vertices=np.array([held[g] for g in order], np.int32),
                               held_points_m=np.stack([grips[g] for g in order]).astype(np.float64))


def score_run(rec: SceneRecording, estimates: list, failure: str = "") -> HandledScore:
    """Score MeshEstimates of ``rec``'s first ``len(estimates)`` frames against its ground truth."""
    T = len(estimates)
    errors, hidden = [], []
    area_ratio, hidden_area, mesh_area = np.full(T, np.nan), np.zeros(T), np.zeros(T)
    shown_hidden = np.full(T, -1, np.int64)
    new_mesh = np.zeros(T, bool)
    K = rec.frames[0].camera.K if rec.frames else None
    start = 0
    while start < T:  # runs of one canonical mesh: a rebuilt mesh is bound to the truth again
        canonical = estimates[start].canonical
        n = len(canonical)
        stop = start + 1
        while stop < T and np.array_equal(estimates[stop].canonical, canonical):
            stop += 1
        new_mesh[start] = start > 0
        targets = material_point_tracks(estimates[start].vertices, rec.gt_vertices[start:stop], rec.gt_faces)
        for t in range(start, stop):
            est = estimates[t]
            errors.append(1000.0 * np.linalg.norm(est.vertices - targets[t - start], axis=1))
            if rec.occluder_masks:
                h = hidden_behind_occluder(targets[t - start], rec.occluder_masks[t], rec.occluder_depths[t], K)
            else:
                h = np.zeros(n, bool)
            hidden.append(h)
            area_ratio[t], hidden_area[t] = occluded_area_ratio(est.vertices, targets[t - start], est.faces, h)
            mesh_area[t] = face_areas(est.canonical, est.faces).sum()
            if est.visible is not None:
                shown_hidden[t] = int((est.visible & h).sum())
        start = stop
    return HandledScore(
        errors_mm=errors, hidden=hidden, area_ratio=area_ratio, hidden_area_m2=hidden_area, mesh_area_m2=mesh_area,
        confidence=np.array([e.confidence for e in estimates], dtype=np.float64),
        lost=np.array([e.lost for e in estimates], dtype=bool),
        timing_ms=np.array([e.timing_ms for e in estimates], dtype=np.float64),
        shown_hidden=shown_hidden, failure=failure, new_mesh=new_mesh, estimates=estimates)


def cloth_hidden_fraction(rec: SceneRecording) -> np.ndarray:
    """(T,) fraction of the true cloth's vertices hidden behind the occluder in each frame."""
    if not rec.occluder_masks:
        return np.zeros(len(rec.frames))
    K = rec.frames[0].camera.K
    return np.array([hidden_behind_occluder(v, m, d, K).mean()
                     for v, m, d in zip(rec.gt_vertices, rec.occluder_masks, rec.occluder_depths)])
