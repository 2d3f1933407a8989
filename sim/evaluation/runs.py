"""Running trackers on simulated scenes and scoring them against ground truth.

A ``SceneRecording`` is a scene's frames with the true cloth vertices per frame, made once
and then tracked by any number of tracker variants, so an ablation compares them on
identical input. Scores follow ``sim.ground_truth``: each estimated vertex is bound at
frame 0 to the closest point of the true cloth surface and followed as a material point.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from ipc.messages import RGBDFrame
from perception.tracker import MeshTracker, TrackerConfig
from sim.evaluation.cpd_peer import CPDTracker
from sim.ground_truth import bind_to_surface, error_summary, surface_points, vertex_errors

log = logging.getLogger(__name__)

# The paper's ablation (Fig. 4 and 5): which data terms each variant uses.
ABLATIONS = {
    "S+C": dict(use_correspondence=True, use_depth=False, use_boundary=False),
    "S+C+D": dict(use_correspondence=True, use_depth=True, use_boundary=False),
    "S+C+D+B": dict(use_correspondence=True, use_depth=True, use_boundary=True),
}


@dataclass
class SceneRecording:
    """A scene's frames and its ground truth.

    frames : list of RGBDFrame (without ``occluder_mask``; ``known_occluder_frames`` adds it)
    gt_vertices : (T, V, 3) float64 camera frame; gt_faces : (F, 3) int
    masks : list of (H, W) bool true cloth masks (noise-free)
    occluder_masks : list of (H, W) bool, where a drawn occluder is seen (exact); empty when
        the scene has no occluders or they were not drawn (a twin)
    occluder_depths : list of (H, W) float32 metres, the occluder's exact depth where it is
        seen, 0 elsewhere; empty as ``occluder_masks``
    frame_step : 1, or k when only every k-th simulated frame was kept (timestamps stay true)
    grips : list of dicts, per frame where the robot's closed grippers are (gripper number ->
        (3,) fingertip centre, camera frame; ``ClothScene.robot_grips``); empty when not kept
    background : RGBDFrame of the empty workspace from the same camera, or None
    """

    name: str
    seed: int
    noise: bool
    frames: list
    gt_vertices: np.ndarray
    gt_faces: np.ndarray
    masks: list = field(default_factory=list)
    occluder_masks: list = field(default_factory=list)
    occluder_depths: list = field(default_factory=list)
    frame_step: int = 1
    grips: list = field(default_factory=list)
    background: RGBDFrame | None = None

    def every(self, step: int) -> SceneRecording:
        """The same recording with only every ``step``-th frame (from the first), as a camera
        that drops frames or runs at 1/step of the rate would deliver it."""
        if isinstance(step, bool) or int(step) != step or step < 1:
            raise ValueError(f"SceneRecording.every: expected a positive integer step, got {step!r}")
        k = int(step)
        return SceneRecording(self.name, self.seed, self.noise, self.frames[::k], self.gt_vertices[::k],
                              self.gt_faces, self.masks[::k], self.occluder_masks[::k], self.occluder_depths[::k],
                              self.frame_step * k, self.grips[::k], self.background)

    def known_occluder_frames(self) -> list:
        """The frames carrying the exact occluder mask (``RGBDFrame.occluder_mask``), as a robot
        that knows where its gripper and arm are would send them."""
        if not self.occluder_masks:
            return list(self.frames)
        return [dataclasses.replace(f, occluder_mask=m) for f, m in zip(self.frames, self.occluder_masks)]


@dataclass
class TrackRun:
    """vertices : (T, N, 3) float64; timing_ms : (T,); lost : (T,) bool; the masks the tracker
    segmented and its MeshEstimates (empty for peers)."""

    label: str
    vertices: np.ndarray
    timing_ms: np.ndarray
    lost: np.ndarray
    masks: list = field(default_factory=list)
    estimates: list = field(default_factory=list)

    def errors(self, rec: SceneRecording) -> np.ndarray:
        """(T, N) metres, the ground-truth error of every vertex in every frame."""
        return vertex_errors(self.vertices, rec.gt_vertices, rec.gt_faces)

    def surface_distances(self, rec: SceneRecording) -> np.ndarray:
        """(T, N) metres from each vertex to the nearest point of the true cloth surface:
        the shape error alone, blind to vertices sliding along the surface."""
        out = np.empty(self.vertices.shape[:2])
        for t, (V, G) in enumerate(zip(self.vertices, rec.gt_vertices)):
            tri, bary = bind_to_surface(V, G, rec.gt_faces)
            out[t] = np.linalg.norm(V - surface_points(G, rec.gt_faces, tri, bary), axis=1)
        return out

    def summary(self, rec: SceneRecording) -> dict:
        out = error_summary(self.errors(rec))
        out["surface_mean_mm"] = float(1000 * self.surface_distances(rec).mean())
        out["median_ms"] = float(np.median(self.timing_ms[1:])) if len(self.timing_ms) > 1 else float("nan")
        out["lost_frames"] = int(self.lost.sum())
        return out


def record_scene(name: str, seed: int = 0, noise: bool = True, n_frames: int | None = 60, progress: bool = True,
                 occluders: bool = True) -> SceneRecording:
    """Run the registered scene ``name`` and keep every frame with its ground truth.

    n_frames : simulated frames (None: the scene's own script length)
    occluders : draw the scene's occluders (False: its twin); ``SceneRecording.every`` drops frames
    """
    from sim.scenes import make_scene  # PyBullet only when a scene is actually run

    frames, gts, masks, occluder_masks, occluder_depths, grips = [], [], [], [], [], []
    with make_scene(name, seed=seed, noise=noise, occluders=occluders) as scene:
        background = scene.render_empty()
        total = scene.n_frames if n_frames is None else int(n_frames)
        for frame in tqdm(scene.frames(total), total=total, desc=f"sim {name}", unit="frame",
                          disable=not progress, leave=False):
            frames.append(frame)
            gts.append(scene.cloth_vertices_cam())
            masks.append(scene.cloth_mask())
            grips.append(scene.robot_grips())
            if scene.has_occluders and occluders:  # a twin draws none: nothing to keep
                seen = scene.occluder_mask()
                occluder_masks.append(seen)
                occluder_depths.append(np.where(seen, scene.exact_depth_m(), np.float32(0.0)))
        faces = np.asarray(scene.faces)
    return SceneRecording(name, seed, noise, frames, np.stack(gts), faces, masks, occluder_masks, occluder_depths,
                          grips=grips, background=background)


def track_recording(rec: SceneRecording, config: TrackerConfig, label: str = "tracker",
                    init_mask: np.ndarray | None = None) -> TrackRun:
    """Track every frame of ``rec``; the first frame initialises (mask: given, else segmented)."""
    tracker = MeshTracker(config)
    verts, timing, lost, masks, estimates = [], [], [], [], []
    for i, frame in enumerate(rec.frames):
        est = tracker.initialise(frame, mask=init_mask) if i == 0 else tracker.track(frame)
        estimates.append(est)
        verts.append(est.vertices)
        timing.append(est.timing_ms)
        lost.append(est.lost)
        obs = tracker.last_observation
        masks.append(obs.mask if obs is not None else np.zeros(frame.depth_m.shape, bool))
    return TrackRun(label, np.stack(verts), np.asarray(timing), np.asarray(lost), masks, estimates)


def cpd_recording(rec: SceneRecording, start_vertices: np.ndarray, masks: list, label: str = "pycpd",
                  **cpd_options) -> TrackRun:
    """pycpd's deformable CPD frame to frame on the same frames and masks, from the same first mesh."""
    cpd = CPDTracker(**cpd_options)
    cpd.initialise(start_vertices)
    verts, timing = [np.array(start_vertices, dtype=np.float64)], [0.0]
    for frame, mask in zip(rec.frames[1:], masks[1:]):
        t0 = time.perf_counter()
        verts.append(cpd.track(_depth(frame), mask, frame.camera.K))
        timing.append((time.perf_counter() - t0) * 1000.0)
    return TrackRun(label, np.stack(verts), np.asarray(timing), np.zeros(len(verts), bool))


def _depth(frame: RGBDFrame) -> np.ndarray:
    return np.nan_to_num(frame.depth_m, nan=0.0)
