"""MeshTracker: the paper's 3D deformable surface tracker on RGB-D frames.

Usage::

    tracker = MeshTracker(TrackerConfig())
    estimate = tracker.initialise(first_frame, mask=None)   # mask: (H, W) bool, optional
    for frame in frames:
        estimate = tracker.track(frame)                      # ipc.MeshEstimate

Each frame:

1. predict the mesh from the previous estimates (constant velocity; turned with the
   gripper holding it when the robot turns its wrist: ``perception.held_turn``), and where
   that does not explain the frame, from the image motion or a global registration
   (``perception.coarse``, ``perception.registration``);
2. classify each vertex as visible, hidden behind something nearer, out of view or
   without depth (``perception.visibility``);
3. segment the object by depth around the prediction (by colour too where depth runs on
   into a table), leaving out known occluders (``RGBDFrame.occluder_mask``);
4. match features, then minimise ``Psi_S + lambda_C Psi_C + lambda_D Psi_D + lambda_B Psi_B``
   over the visible vertices, with a motion prior ``lambda_M Psi_M`` carrying the hidden
   ones, by the semi-implicit solver. Correspondences are re-weighted between solver
   stages with a shrinking inlier radius (as Pilet et al.), so a few wrong matches cannot
   tear the mesh; between stages, the hidden part's prior is moved and turned as the cloth
   seen around it moved (``perception.hidden_motion``);
5. weigh the evidence for the result (``perception.confidence``); a lost tracker looks
   for the object again by itself.

Pure numerics: frames in, estimates out; no files, sockets or simulators.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache

import cv2
import numpy as np
from threadpoolctl import ThreadpoolController

from ipc.messages import MeshEstimate, RGBDFrame
from perception.anchors import TextureAnchors
from perception.appearance import AppearanceModel
from perception.background import check_background, differs_from_background, seen_through
from perception.coarse import MIN_RESPONSE, FrameMemory
from perception.colour_model import ColourModel
from perception.confidence import Assessment, assess, matches_cap, material_cap, reach_ratio, reshaping, within_reach
from perception.energy import (
    DEPTH_RESIDUALS,
    BoundaryTerm,
    CorrespondenceTerm,
    DepthTerm,
    HoldTerm,
    MotionPriorTerm,
    OutsideTerm,
    PlaneDepthTerm,
    StretchTerm,
    measured_surface,
)
from perception.features import (
    FEATURE_KINDS,
    CombinedCorrespondences,
    DescriptorCorrespondences,
    KLTCorrespondences,
    make_correspondences,
    resolve_kind,
)
from perception.frame_checks import check_frame
from perception.geometry import (
    Undistorter,
    backproject,
    boundary_chains,
    face_areas,
    face_normals,
    lens_coefficients,
    pixel_index,
    project,
    rays,
    same_optics,
)
from perception.held_turn import HeldTurns, Turn
from perception.hidden_motion import carried_prior
from perception.initial_mesh import InitialisationError, mesh_from_mask, object_area_m2, place_mesh, spacing_for
from perception.mesh import CanonicalMesh, barycentric_matrix, material_reach
from perception.observation import Observation, grey_of, observe
from perception.occluders import MEASURED_SURROUNDINGS, measured_around, occluders_in_front
from perception.raster import faces_mask
from perception.registration import GlobalRegistration
from perception.segmentation import (
    SegmentationConfig,
    find_by_colour,
    find_object,
    object_extent,
    segment_tracked,
    touches_border,
    valid_depth,
)
from perception.solver import METHODS, SemiImplicitSolver
from perception.support import SupportPlane, fit_support
from perception.tether import Tethers
from perception.trackable import MIN_TEXTURE_SNR
from perception.visibility import NO_DEPTH, OCCLUDED, VISIBLE, classify_vertices, face_states

log = logging.getLogger(__name__)

#: A vertex behind a fold of the mesh is hidden when the fold and the measured surface are
#: at least half a mesh spacing in front of it, and never less than this: on a small object's
#: fine mesh half a spacing is within a depth sensor's noise (a 5 cm foam tube's mesh, 8 mm
#: spacing, lost coverage of the tube to noise-made folds).
FOLD_MARGIN_MIN_M = 0.005

#: A lost tracker whose print the registration matches, but onto a placement the confidence
#: rejects, keeps its mesh for this many lost frames before it builds a new one on the object
#: segmented again (a new mesh loses the material coordinates; a frame or two of bad data pass)
KEEP_MESH_LOST_FRAMES = 3

#: The least area, as a share of the mesh first laid, of an object segmented afresh for a new
#: mesh: a cloth folds, so less of it may show (``PARTIAL_AREA``); but an object the image's
#: border cuts shows only what is in view, and a mesh laid on that part would stay a part after
#: the object came back into view (a cloth carried out of view and back kept a mesh on the
#: sixth of it that stayed in view), so it needs ``CUT_AREA``
PARTIAL_AREA, CUT_AREA = 0.15, 0.8

#: Frames whose segmented object an object too near the camera to measure must mostly cover to
#: be taken for one (``perception.occluders``): a third of a second at 30 Hz, time for a hand
#: to come in over the cloth, too short for the cloth to have swept the background beside it.
OBJECT_BEFORE_FRAMES = 10

#: An initialisation mask may cover at most this share of the frame: the object's outline and
#: some of its surroundings must be in view (a mask of the whole frame, given by mistake, lays
#: one sheet over everything seen and reports it confidently)
MAX_MASK_SHARE = 0.95


@lru_cache(maxsize=1)
def _blas() -> ThreadpoolController:
    return ThreadpoolController()


def _one_blas_thread():
    """A context in which BLAS runs on the calling thread only.

    The tracker's dense products are small (a few hundred vertices): handing them to
    BLAS worker threads costs more than it gives, and on a busy two-core machine the
    workers' spinning took a third of the frame time (benchmarks/bench_tracker.py).
    """
    return _blas().limit(limits=1, user_api="blas")


class _Done:
    """A finished result with the two methods of a Future that the tracker uses."""

    def __init__(self, value):
        self._value = value

    def result(self):
        return self._value

    def exception(self):
        return None


def _camera_text(camera) -> str:
    """A camera's size and intrinsics, as a frame-check message names them."""
    K = camera.K
    return f"{camera.width}x{camera.height} fx {K[0, 0]:g} fy {K[1, 1]:g} cx {K[0, 2]:g} cy {K[1, 2]:g}"


class TrackingError(ValueError):
    """A frame or mask the tracker cannot use; the message names what was wrong."""


@dataclass(frozen=True)
class TrackerConfig:
    """Every knob of the tracker. The paper's four weights default to the paper's values; the
    terms added here (motion prior, stretch, hold) have defaults measured in docs/results.md.

    spacing_m : canonical mesh edge length, metres (0.03 gives ~370 vertices on a 60x45 cm cloth);
        0 (default) chooses it from the object in the first frame, for about ``target_vertices``
    target_vertices : how many vertices an automatically spaced mesh gets (a 5 cm wide tube
        gets a usable mesh as a towel does)
    lambda_c, lambda_d, lambda_b : weights of the correspondence, depth and boundary terms
    use_correspondence, use_depth, use_boundary : switch terms off for ablations
    alpha : adaptation rate of the semi-implicit scheme (larger = smaller, safer steps)
    solver : "conjugate" (default) or "semi-implicit" (the paper's plain iteration); see perception.solver
    max_iterations : solver iterations per frame, shared by the outlier-rejection stages
    cg_iterations : conjugate-gradient steps per solver iteration (conjugate solver)
    tolerance_m : stop when no vertex moves more than this in an iteration
    min_predicted_decrease : stop when the next step is predicted to lower the energy by
        less than this fraction of it (0: never; saves time on noisy data)
    features : "auto" (SURF if available, else SIFT), "surf", "sift", "orb" or "klt"
    max_features : features detected per frame
    min_descriptor_features : when the first frame shows fewer descriptor features on the
        object than this (a plain or faintly textured object), KLT points track it as well
    min_texture_snr : KLT points are laid only where the image's texture has this many times
        the gradient energy its own noise would give (``perception.trackable``); on a plain
        cloth the strongest corners are noise over shading, which KLT follows with the light,
        not with the material (0: wherever Shi-Tomasi finds a corner)
    match_gate_px : a match must lie within this distance of its predicted location
    match_keep_fraction : the paper keeps the best half of the matches
    match_previous_frame : also match the previous frame's features (bound through the estimate)
    anchor_points : on a textured object, corners of the first frame's texture drawn at the
        predicted mesh that are followed into each frame (``perception.anchors``): material
        points found without binding through an estimate, so the mesh cannot drift off the
        print (0, the default: none)
    feature_thread : track or detect features on a second thread while the frame is segmented,
        and find the object's extent for the confidence there while the mesh is minimised
        (the same results either way; off keeps the tracker on one core)
    outlier_radii_m : inlier radius of each solver stage; a match farther from its mesh point is ignored
    depth_window_px : depth is averaged over this window on the object (noise)
    depth_outlier_m : depth residuals larger than this are ignored (occlusion, edges)
    depth_residual : "ray" (the paper's: distance along the vertex's camera ray) or "plane"
        (along the measured surface's normal, ``perception.energy.PlaneDepthTerm``: a surface
        seen edge-on is not slid along)
    occlusion_margin_m : a vertex is hidden when the measured surface at its pixel is this much nearer
    unknown_occluder_m : a surface this much nearer than the predicted mesh, standing out from
        the cloth around it by as much all round, is taken for an object in front of the cloth
        (a hand on it, a tool) and treated as a known occluder, though no occluder mask names
        it (``perception.occluders``; where colour tells the cloth from its surroundings, a
        smaller step and a hue not the cloth's will do); 0 switches both off
    lambda_m : weight of the motion prior that carries hidden and unobserved vertices, moved and
        turned with the cloth seen near them (``perception.hidden_motion``); 0: none
    lambda_l : weight of the stretch term that keeps the mesh's edge lengths (0: none, as in the
        paper, whose smoothness lets a mesh shrink onto the part of the object still seen)
    lambda_h : weight of the hold term: vertices the robot holds (``RGBDFrame.held_vertices``)
        stay at its grippers (``RGBDFrame.held_points_m``)
    tether : while the robot holds the object, no vertex may be farther from a held point
        than (1 + ``tether_slack``) times its distance to it along the mesh as laid on the
        object (``perception.tether``: cloth hardly stretches); applied to the prediction
        and to the result of each frame (independently of ``lambda_h``)
    tether_slack : how much farther than along the mesh a vertex may be from a held point,
        as a fraction (the mesh's own stretch; a path along edges is a little longer than on
        the cloth)
    coarse_motion : before each frame's minimisation, also consider the last mesh unmoved and
        moved by the image translation measured around it (large motions, dropped frames)
    self_occlusion : a vertex that another part of the mesh hides (a fold) is occluded too,
        when the measured surface is in front of it as well, so that the data does not pull
        the layer behind onto the one in front
    lambda_o : weight of the outside term: vertices seen where the segmented object is not
        (the table a lifted cloth has left) are pulled to its outline (0, the default: off; it
        needs a segmentation to trust, such as the one a ``background`` gives)
    lambda_f : weight of the free-space term, used when ``lambda_o`` is 0 (whose term pulls
        these vertices too): vertices seen where the segmented object is not, and which the
        camera sees past (the surface measured at their pixel lies more than
        ``depth_outlier_m`` behind them, so the depth term ignores them), are pulled to the
        object's outline (``perception.energy.OutsideTerm`` with ``free_space_m``); needs no
        background. 0: off
    boundary_gate_m : boundary vertices farther than this from the outline are left alone
    velocity_prediction : fraction of the last inter-frame motion added to predict the next frame
    init_iterations : smoothing iterations when the mesh is laid on the first frame
    confidence_tol_m : a vertex is supported when its depth agrees within this
    carried_tol_m : a hidden vertex that has moved this far since the camera (or the robot's
        hold) last placed it is a guess; a large share of such vertices lowers confidence
        (``perception.confidence``, cue ``followed``)
    lost_confidence : below this confidence the estimate is flagged lost
    reacquire_every : once lost, the tracker looks for the object again in each of the first
        three lost frames, then in every this many (a search of the whole frame costs time);
        0 never looks
    """

    spacing_m: float = 0.0
    target_vertices: int = 400
    lambda_c: float = 1.3
    lambda_d: float = 0.6
    lambda_b: float = 0.8
    use_correspondence: bool = True
    use_depth: bool = True
    use_boundary: bool = True
    alpha: float = 0.5
    solver: str = field(default="conjugate", metadata={"choices": METHODS})
    max_iterations: int = 10
    cg_iterations: int = 8
    tolerance_m: float = 1e-4
    min_predicted_decrease: float = 0.0
    features: str = field(default="auto", metadata={"choices": FEATURE_KINDS})
    max_features: int = 500
    min_descriptor_features: int = 60
    min_texture_snr: float = MIN_TEXTURE_SNR
    match_gate_px: float = 40.0
    match_keep_fraction: float = 0.5
    match_previous_frame: bool = True
    anchor_points: int = 0
    feature_thread: bool = True
    outlier_radii_m: tuple = (0.05, 0.02)
    depth_window_px: int = 5
    depth_outlier_m: float = 0.08
    depth_residual: str = field(default="ray", metadata={"choices": DEPTH_RESIDUALS})
    occlusion_margin_m: float = 0.08
    unknown_occluder_m: float = 0.03
    lambda_m: float = 1.0
    lambda_l: float = 5.0
    lambda_h: float = 100.0
    tether: bool = True
    tether_slack: float = 0.05
    coarse_motion: bool = True
    self_occlusion: bool = True
    lambda_o: float = 0.0
    lambda_f: float = 0.3
    boundary_gate_m: float = 0.06
    velocity_prediction: float = 0.5
    init_iterations: int = 10
    confidence_tol_m: float = 0.03
    carried_tol_m: float = 0.05
    lost_confidence: float = 0.4
    reacquire_every: int = 10
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)

    def __post_init__(self):
        positive = ("alpha", "tolerance_m", "match_gate_px", "depth_outlier_m", "boundary_gate_m",
                    "confidence_tol_m", "occlusion_margin_m", "carried_tol_m")
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"TrackerConfig.{name}: expected a positive number, got {v!r}")
        for name in ("spacing_m", "lambda_c", "lambda_d", "lambda_b", "lambda_m", "lambda_l", "lambda_h", "lambda_o",
                     "lambda_f", "tether_slack", "velocity_prediction",
                     "min_predicted_decrease", "min_texture_snr"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"TrackerConfig.{name}: expected a non-negative number, got {v!r}")
        if int(self.anchor_points) < 0:
            raise ValueError(f"TrackerConfig.anchor_points: expected an integer >= 0, got {self.anchor_points!r}")
        if not 0 < self.match_keep_fraction <= 1:
            raise ValueError(f"TrackerConfig.match_keep_fraction: expected (0, 1], got {self.match_keep_fraction}")
        counts = ("max_iterations", "cg_iterations", "max_features", "depth_window_px", "target_vertices")
        for name in counts:
            if int(getattr(self, name)) < 1:
                raise ValueError(f"TrackerConfig.{name}: expected an integer >= 1, got {getattr(self, name)!r}")
        if not self.outlier_radii_m or any(not r > 0 for r in self.outlier_radii_m):
            raise ValueError(f"TrackerConfig.outlier_radii_m: expected positive radii, got {self.outlier_radii_m}")
        if int(self.reacquire_every) < 0:
            raise ValueError(f"TrackerConfig.reacquire_every: expected an integer >= 0, got {self.reacquire_every!r}")
        resolve_kind(self.features)
        if self.depth_residual not in DEPTH_RESIDUALS:
            raise ValueError(f"TrackerConfig.depth_residual: expected one of {DEPTH_RESIDUALS}, got {self.depth_residual!r}")

    @classmethod
    def realtime(cls, **overrides) -> TrackerConfig:
        """A preset for 30 Hz on two CPU cores: KLT points instead of descriptors, fewer and
        shorter iterations that stop once a step is predicted to gain under 5 % of the energy."""
        base = dict(features="klt", max_features=300, max_iterations=6, cg_iterations=4,
                    min_predicted_decrease=0.05, outlier_radii_m=(0.04, 0.02), init_iterations=6)
        base.update(overrides)
        return cls(**base)

    def to_dict(self) -> dict:
        return asdict(self)


class MeshTracker:
    """Tracks one deformable object; see the module docstring."""

    def __init__(self, config: TrackerConfig | None = None, rng: np.random.Generator | None = None):
        self.config = config if config is not None else TrackerConfig()
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self._executor: ThreadPoolExecutor | None = None
        self.reset()

    def _worker(self) -> ThreadPoolExecutor:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tracker-features")
        return self._executor

    # -- state ---------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the object; ``initialise`` must be called again."""
        self.mesh: CanonicalMesh | None = None
        self._V = None
        self._V_prev = None
        self._held_turns = HeldTurns()
        self._turned: Turn | None = None  # the gripper's turn predicted from the frame of _V_prev to that of _V
        self._camera = None
        self._undistort = None
        self._solver = None
        self._corr = None
        self._g0 = None
        self._faces_out = None
        self._edges = None
        self._outline = []  # the mesh's outline loops, to draw its prediction (``faces_mask``)
        self._visible = None  # (N,) bool, the vertices seen in the last frame
        self._laid_V = None
        self._unknown_occluder = None  # (H, W) bool, the objects in front found in the last frame
        # (H, W) bool, the object as segmented in the last frames: an object too near the camera
        # to be measured is looked for where the cloth was (perception.occluders)
        self._object_before: deque = deque(maxlen=OBJECT_BEFORE_FRAMES)
        self._surroundings_measured = False  # the sensor measured what surrounds the object when first seen
        self._occluded_before = None  # (H, W) bool, what was in front of the mesh in the last frame: known or found
        self._memory = FrameMemory()
        self.coarse_corrections = 0  # frames predicted otherwise than by constant velocity
        self.last_motion_scores: dict = {}
        self._appearance: AppearanceModel | None = None
        self._registration: GlobalRegistration | None = None
        self._anchors: TextureAnchors | None = None
        self._colour: ColourModel | None = None
        self._background: RGBDFrame | None = None  # the empty workspace, undistorted
        self._unmeasured_before: np.ndarray | None = None  # its pixels without depth (``_open``)
        self._support_plane: SupportPlane | None = None  # the plane the object rests on, seen in the first frame
        self._background_given: RGBDFrame | None = None
        self._good_V = None  # (N, 3) the last estimate that was not lost
        self._last_seen = None  # (N, 3) where each vertex was when last seen or held
        self._rest_lengths = None  # (E,) edge lengths, metres, of the mesh as laid on the object
        self._stretch: StretchTerm | None = None  # the stretch term of those lengths
        self._tethers: Tethers | None = None  # each vertex's distance along the mesh from a held one
        self.lost_streak = 0  # consecutive lost frames
        self.reacquisitions = 0  # times the object was found again after being lost
        self._cloth_area_m2 = None  # the mesh's area as ``initialise`` laid it, kept through re-acquisitions
        self.last_assessment: Assessment | None = None
        self.last_observation: Observation | None = None
        self.last_feature_xy = np.zeros((0, 2))  # (P, 2) pixels of the last frame's correspondences

    @property
    def initialised(self) -> bool:
        return self.mesh is not None

    @property
    def vertices(self) -> np.ndarray:
        """(N, 3) float64 current estimate, metres, camera frame."""
        if self._V is None:
            raise TrackingError("the tracker is not initialised")
        return self._V.copy()

    def set_config(self, config: TrackerConfig) -> None:
        """Change parameters; those that shape the mesh apply from the next ``initialise``."""
        old = self.config
        self.config = config
        if self.initialised:
            if (config.alpha, config.solver, config.cg_iterations) != (old.alpha, old.solver, old.cg_iterations):
                self._solver = self._make_solver(self.mesh)
            if (config.features, config.max_features, config.anchor_points, config.min_texture_snr) != \
                    (old.features, old.max_features, old.anchor_points, old.min_texture_snr):
                log.warning("feature settings change at the next initialise")

    # -- checks --------------------------------------------------------------------------

    def _check_frame(self, frame: RGBDFrame) -> RGBDFrame:
        if not isinstance(frame, RGBDFrame):
            raise TrackingError(f"expected an RGBDFrame, got {type(frame).__name__}")
        if self._camera is not None:
            c = frame.camera
            if (c.width, c.height) != (self._camera.width, self._camera.height) or not np.allclose(c.K, self._camera.K):
                raise TrackingError(f"frame camera changed: initialised on {_camera_text(self._camera)}, got "
                                    f"{_camera_text(c)} (re-initialise for a new camera)")
            first = self._undistort.camera  # as the first frame gave it, lens distortion included
            if not same_optics(c, first):
                raise TrackingError(f"frame camera changed: initialised in frame {first.frame_id!r} with distortion "
                                    f"{lens_coefficients(first.D).tolist()}, got {c.frame_id!r} with "
                                    f"{lens_coefficients(c.D).tolist()} (re-initialise for a new camera)")
        held = frame.held_vertices
        if held is not None and held.size and self.mesh is not None and int(held.max()) >= self.mesh.n_vertices:
            raise TrackingError(f"RGBDFrame.held_vertices: vertex {int(held.max())} is not in the tracked mesh "
                                f"of {self.mesh.n_vertices} vertices")
        return frame

    # -- initialise ----------------------------------------------------------------------

    def initialise(self, frame: RGBDFrame, mask: np.ndarray | None = None,
                   mesh: CanonicalMesh | None = None, background: RGBDFrame | None = None) -> MeshEstimate:
        """Lay the canonical mesh over the object in ``frame`` and bind its features.

        mask : (H, W) bool or uint8 (non-zero on the object); found by depth segmentation if None
        mesh : an off-line canonical mesh (e.g. ``rectangle_mesh``); built from the mask if None
        background : the empty workspace seen by the same fixed camera, or None; from then on
            only what differs from it can be the object (``perception.background``), so a
            cloth lifted off a table is not held to the table by its depth, and what differs
            from it and joins the object is the object, where depth alone misses it (a cloth
            on a table seen at a grazing angle, ``segment_tracked``)
        raises TrackingError with a one-line reason when the frame cannot carry a mesh; the
        tracker then keeps the object it was tracking before
        """
        saved = dict(self.__dict__)
        try:
            with _one_blas_thread():
                estimate = self._initialise(frame, mask, mesh, background)
        except Exception:
            self.__dict__.update(saved)
            raise
        self._cloth_area_m2 = self._mesh_area_m2()
        return estimate

    def _initialise(self, frame, mask, mesh, background) -> MeshEstimate:
        t0 = time.perf_counter()
        self.reset()
        frame = self._check_frame(frame)
        if frame.held_vertices is not None:
            # They name vertices of the mesh tracked before, if any: the new one has none held yet.
            frame = replace(frame, held_vertices=None, held_points_m=None, held_quats_xyzw=None)
        problem = check_frame(frame)  # a camera or depth no sensor gives: its numbers would overflow the mesh's
        if problem is not None:
            raise TrackingError(problem[1])
        if background is not None:
            try:
                check_background(background, frame)
            except ValueError as e:
                raise TrackingError(str(e)) from None
        self._undistort = Undistorter(frame.camera)
        frame = self._undistort(frame)
        self._background_given = background  # as given, for a re-acquisition's new mesh
        self._background = None if background is None else self._undistort(background)
        self._unmeasured_before = None if background is None else ~valid_depth(self._background.depth_m)
        cfg = self.config
        h, w = frame.depth_m.shape
        if mask is None:
            mask = find_object(frame.depth_m, frame.camera.K, cfg.segmentation, self._rng)
            if not mask.any():
                raise TrackingError("no object found by depth segmentation in the first frame; pass a mask")
        else:
            mask = np.asarray(mask)
            if mask.shape != (h, w):
                raise TrackingError(f"mask: expected shape ({h}, {w}) like the frame, got {mask.shape}")
            mask = mask.astype(bool)
            if not mask.any():
                raise TrackingError("mask is empty: it must be non-zero on the object")
            if mask.mean() > MAX_MASK_SHARE:
                raise TrackingError(f"mask covers {100 * mask.mean():.1f} % of the frame: it must be the object's, "
                                    f"with some of its surroundings in view")
        obs = observe(frame, mask, cfg.depth_window_px)
        try:
            if mesh is None:
                spacing = cfg.spacing_m or spacing_for(obs, cfg.target_vertices)
                mesh, V0 = mesh_from_mask(obs, spacing)
            else:
                V0 = place_mesh(mesh, obs)
        except InitialisationError as e:
            raise TrackingError(str(e)) from None
        if mesh.n_vertices < 3:
            raise TrackingError("the object is too small for the mesh spacing")
        self.mesh = mesh
        self._camera = frame.camera
        self._solver = self._make_solver(mesh)
        self._edges = mesh.edges()
        self._outline = boundary_chains(mesh.faces)
        self._faces_out = self._orient_faces(mesh.faces, V0)

        boundary = self._boundary_term(obs, np.zeros(len(mesh.boundary)))
        s, *_ = boundary.signed_distance(V0)
        self._g0 = np.clip(s, 0.0, mesh.spacing_m)
        terms = self._data_terms(obs, correspondences=None)
        res = self._solver.minimise(V0, terms, cfg.init_iterations, cfg.tolerance_m)
        V = res.vertices
        self._V, self._V_prev = V, V.copy()
        self._turned = None
        self._held_turns.forget()

        feature_mask = self._feature_mask(obs.mask)
        if cfg.use_correspondence:
            self._corr = make_correspondences(cfg.features, cfg.max_features, cfg.match_gate_px,
                                              cfg.match_keep_fraction, cfg.match_previous_frame, cfg.min_texture_snr)
            self._corr.initialise(obs.grey, feature_mask, V, mesh.faces, obs.K)
            if isinstance(self._corr, DescriptorCorrespondences) and self._corr.n_model < cfg.min_descriptor_features:
                log.info("%d descriptor features on the object: KLT points track it as well", self._corr.n_model)
                self._corr = CombinedCorrespondences(self._corr, KLTCorrespondences(cfg.max_features,
                                                                                  cfg.min_texture_snr))
                self._corr.points.initialise(obs.grey, feature_mask, V, mesh.faces, obs.K)
        self.last_observation = obs
        self._memory.push(self._memory.small(obs.grey))
        self._occluded_before = frame.occluder_mask
        visible = self._states(V, frame) == VISIBLE
        self._appearance = AppearanceModel(frame.rgb, V, mesh.faces, frame.camera.K, visible, mesh.spacing_m,
                                           mesh.boundary, mesh.canonical)
        self._anchors = TextureAnchors(obs.grey, V, mesh.faces, visible, obs.K, cfg.anchor_points) \
            if cfg.use_correspondence and cfg.anchor_points > 0 and self._appearance.textured else None
        self._colour = ColourModel(frame.rgb, obs.mask)
        self._surroundings_measured = measured_around(frame.depth_m, obs.mask) >= MEASURED_SURROUNDINGS
        self._support_plane = fit_support(frame.depth_m, obs.mask, frame.camera.K)
        self._registration = GlobalRegistration(resolve_kind("auto"), rng=self._rng)
        self._registration.build(obs.grey, feature_mask, V, mesh.faces, obs.K)
        self._good_V = V
        self._laid_V = V  # the shape the mesh was laid in (``perception.confidence.material_cap``)
        self._rest_lengths = np.linalg.norm(V[self._edges[:, 0]] - V[self._edges[:, 1]], axis=1)
        self._stretch = StretchTerm(self._edges, self._rest_lengths, n_vertices=len(V))
        self._tethers = Tethers(V, mesh.faces)
        self._last_seen = V.copy()
        assessment = self._assess(V, frame, visible, obs.mask, differs=self._differs(frame))
        log.info("initialised mesh: %d vertices, %d faces, %d boundary, %d features", mesh.n_vertices,
                 len(mesh.faces), len(mesh.boundary), self._corr.n_model if self._corr else 0)
        return self._estimate(frame, V, res.energies, res.iterations, assessment, t0, visible)

    def _states(self, V: np.ndarray, frame: RGBDFrame) -> np.ndarray:
        """(N,) int8 visibility state of each vertex of ``V`` (N, 3) in ``frame``
        (``perception.visibility``), the mesh's own folds included when configured."""
        cfg = self.config
        faces = self.mesh.faces if cfg.self_occlusion else None
        return classify_vertices(V, frame.depth_m, frame.camera.K, cfg.occlusion_margin_m, frame.occluder_mask,
                                 faces, max(FOLD_MARGIN_MIN_M, 0.5 * self.mesh.spacing_m))

    def _make_solver(self, mesh: CanonicalMesh) -> SemiImplicitSolver:
        cfg = self.config
        return SemiImplicitSolver(mesh.stiffness(), cfg.alpha, cfg.solver, cg_iterations=cfg.cg_iterations)

    @staticmethod
    def _orient_faces(faces: np.ndarray, V: np.ndarray) -> np.ndarray:
        """Faces ordered so their normals face the camera at frame 0 (counter-clockwise as seen)."""
        normal = face_normals(V, faces).sum(axis=0)
        if normal @ (-V.mean(axis=0)) < 0:
            return faces[:, [0, 2, 1]].copy()
        return faces.copy()

    # -- terms ---------------------------------------------------------------------------

    @staticmethod
    def _feature_mask(mask: np.ndarray) -> np.ndarray:
        # Features on the object's very edge describe the background as much as the object.
        return cv2.erode(mask.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)

    def _open(self, frame: RGBDFrame) -> np.ndarray:
        """(H, W) bool, the pixels of ``frame`` the outside term may pull a vertex seen on: those
        with measured depth, and those without where the empty workspace had none either (the
        far background: nothing lost its depth there). A pixel whose depth the sensor lost now
        may be the cloth seen at a grazing angle, which the segmentation missed."""
        measured = valid_depth(frame.depth_m)
        return measured if self._unmeasured_before is None else measured | self._unmeasured_before

    def _boundary_term(self, obs: Observation, g0: np.ndarray, observed: np.ndarray | None = None) -> BoundaryTerm:
        """The boundary term over the boundary vertices that are ``observed`` ((N,) bool; all if None)."""
        ids = self.mesh.boundary
        keep = np.ones(len(ids), bool) if observed is None else observed[ids]
        return BoundaryTerm(ids[keep], g0[keep], obs.outline_cam, obs.mask, obs.K, self.config.boundary_gate_m,
                            obs.hidden_contour_cam)

    def _data_terms(self, obs: Observation, correspondences: CorrespondenceTerm | None,
                    observed: np.ndarray | None = None, prior: np.ndarray | None = None, frame: RGBDFrame | None = None):
        """(weight, term) pairs for one frame. observed : (N,) bool, the vertices the data may
        pull (all if None); the others are held by the motion prior around ``prior`` (N, 3).
        ``frame``'s held vertices, if any, are kept at the robot's grippers."""
        cfg = self.config
        terms = []
        if correspondences is not None and cfg.use_correspondence and len(correspondences.targets):
            terms.append((cfg.lambda_c, correspondences))
        if cfg.use_depth and cfg.depth_residual == "plane":
            terms.append((cfg.lambda_d, PlaneDepthTerm(*measured_surface(obs.depth_m, obs.K), obs.K, cfg.depth_outlier_m,
                                                       vertex_mask=observed)))
        elif cfg.use_depth:
            terms.append((cfg.lambda_d, DepthTerm(obs.range_m, obs.K, cfg.depth_outlier_m, vertex_mask=observed)))
        if cfg.use_boundary and len(obs.outline_cam):
            terms.append((cfg.lambda_b, self._boundary_term(obs, self._g0, observed)))
        if observed is not None and len(obs.outline_cam):
            if cfg.lambda_o > 0:
                terms.append((cfg.lambda_o, OutsideTerm(obs.outline_cam, obs.mask, obs.K, observed,
                                                        None if frame is None else self._open(frame),
                                                        hidden_points=obs.hidden_contour_cam)))
            elif cfg.lambda_f > 0 and frame is not None:  # the outside term's pull covers these vertices too
                terms.append((cfg.lambda_f, OutsideTerm(obs.outline_cam, obs.mask, obs.K, observed,
                                                        depth_m=frame.depth_m, free_space_m=cfg.depth_outlier_m,
                                                        hidden_points=obs.hidden_contour_cam, name="free_space")))
        if observed is not None and prior is not None and cfg.lambda_m > 0 and not observed.all():
            terms.append((cfg.lambda_m, MotionPriorTerm.around(self._edges, ~observed, prior)))
        if cfg.lambda_l > 0 and self._stretch is not None:
            terms.append((cfg.lambda_l, self._stretch))
        if frame is not None and frame.held_vertices is not None and frame.held_vertices.size and cfg.lambda_h > 0:
            terms.append((cfg.lambda_h, HoldTerm(frame.held_vertices.astype(np.int64), frame.held_points_m)))
        return terms

    # -- track ---------------------------------------------------------------------------

    def predict(self, turn: Turn | None = None) -> np.ndarray:
        """(N, 3) the mesh expected in the next frame: the last estimate moved on by a
        fraction of its last motion (constant velocity, damped), then turned by ``turn``, the
        turn of the gripper holding it since the last frame (``perception.held_turn``). The
        last motion is counted less the gripper's own turn then, which this one repeats."""
        V_prev = self._V_prev if self._turned is None else self._turned.apply(self._V_prev)
        V_pred = self._V + self.config.velocity_prediction * (self._V - V_prev)
        return V_pred if turn is None else turn.apply(V_pred)

    def track(self, frame: RGBDFrame) -> MeshEstimate:
        """Estimate the mesh in a new frame. Raises TrackingError before ``initialise`` or on a bad frame."""
        with _one_blas_thread():
            return self._track(frame)

    def _track(self, frame: RGBDFrame) -> MeshEstimate:
        t0 = time.perf_counter()
        if not self.initialised:
            raise TrackingError("track() called before initialise()")
        frame = self._undistort(self._check_frame(frame))
        cfg = self.config
        K = frame.camera.K
        faces = self.mesh.faces
        grey = grey_of(frame)
        small = self._memory.small(grey)
        turn = self._held_turns.turn(frame)
        V_pred = self.predict(turn)
        if turn is not None and self._last_seen is not None:
            # What the robot turns turns with it, seen or not: a vertex hidden by the turn is
            # not unconfirmed for being where the turn took it (``_carried``).
            self._last_seen = turn.apply(self._last_seen)
        if cfg.coarse_motion:
            V_pred = self._coarse_prediction(V_pred, small, frame)
        self._memory.push(small)
        h, w = frame.depth_m.shape
        uv = project(V_pred, K)
        pred_mask = faces_mask(uv, faces, (h, w), self._outline)
        prepared = None
        if cfg.use_correspondence and self._corr is not None:
            # Optical flow or feature detection needs no object mask: it runs on a second
            # core while this thread segments the frame (OpenCV and NumPy release the GIL).
            args = (grey, V_pred, faces, K, pred_mask)
            prepared = self._worker().submit(self._corr.prepare, *args) if cfg.feature_thread \
                else _Done(self._corr.prepare(*args))
        try:
            estimate = self._solve_frame(frame, V_pred, pred_mask, grey, prepared, t0)
            # The mesh was solved from the turned prediction, unless the object was not seen
            # (then it stays where it was).
            self._turned = turn if self.last_observation is not None else None
        finally:
            if prepared is not None:
                prepared.exception()  # waits: the worker never uses the feature state after this frame
        if not estimate.lost:
            self.lost_streak = 0
            self._good_V = estimate.vertices
            return estimate
        self.lost_streak += 1
        every = cfg.reacquire_every
        if every and (self.lost_streak <= 3 or self.lost_streak % every == 0):
            found = self._reacquire(frame, grey, t0)
            if found is not None:
                return found
        return estimate

    def _reacquire(self, frame: RGBDFrame, grey: np.ndarray, t0: float) -> MeshEstimate | None:
        """Look for the object anywhere in ``frame``; the estimate if it is found and not lost
        (the tracker then goes on from it), else None.

        By global registration of the first frame's features (``perception.registration``)
        the canonical mesh is placed where its material points are, and the frame is solved
        from there with the registration's matches as correspondences. Where that fails (a
        cloth without enough texture, a print turned over), or from the
        ``KEEP_MESH_LOST_FRAMES``-th lost frame on where the confidence rejects the placement
        (a print matched on a cloth that has folded since), the object is segmented again
        (by its colour, else by depth) and a new mesh is built on it, as at initialisation:
        which material point lies where cannot be known then, so the estimate comes with a
        new canonical mesh rather than one whose material coordinates would be a guess."""
        cfg = self.config
        K = frame.camera.K
        faces = self.mesh.faces
        occluder = frame.occluder_mask
        search = None if occluder is None else ~occluder
        found = self._registration.register(grey, frame.depth_m, self._good_V, faces, K, search) \
            if self._registration is not None else None
        if found is None:
            return self._reinitialise_on_segment(frame, t0)
        V0 = found.apply(self._good_V)
        h, w = frame.depth_m.shape
        z = V0[:, 2]
        differs = self._differs(frame)
        segment = segment_tracked(frame.depth_m, faces_mask(project(V0, K), faces, (h, w), self._outline),
                                  (float(z.min()), float(z.max())), cfg.segmentation, rgb=frame.rgb, colour=self._colour,
                                  not_object=self._not_object(frame, differs), differs=differs)
        mask = segment.mask
        if not mask.any():
            return self._placement_failed(frame, t0)
        obs = observe(frame, mask, cfg.depth_window_px, grey=grey, unsearched=segment.unsearched)
        corr = None
        if found is not None:
            pts, has = obs.points_at(found.xy)
            if has.sum() >= 3:
                B = barycentric_matrix(found.face_ids[has], found.bary[has], faces, self.mesh.n_vertices)
                corr = CorrespondenceTerm(B, pts[has], np.ones(int(has.sum())))
        observed = self._states(V0, frame) != OCCLUDED
        res = self._solver.minimise(V0, self._data_terms(obs, corr, observed, V0), 2 * cfg.init_iterations, cfg.tolerance_m)
        V = res.vertices
        visible = self._states(V, frame) == VISIBLE
        carried, last_seen = self._carried(V, visible, frame)
        assessment = self._assess(V, frame, visible, mask, segment.leak, carried, segment.extent, differs)
        if assessment.lost(cfg.lost_confidence):
            log.debug("frame %d: registration's placement rejected (%s)", frame.seq, assessment.as_dict())
            return self._placement_failed(frame, t0)
        self._V, self._V_prev, self._good_V = V, V.copy(), V
        self._turned = None
        self._last_seen = last_seen
        self.last_observation = obs
        if self._corr is not None:
            self._corr.initialise(obs.grey, self._feature_mask(mask), V, faces, K)
        self.lost_streak = 0
        self.reacquisitions += 1
        log.info("frame %d: object re-acquired by registration (confidence %.2f)", frame.seq, assessment.confidence)
        return self._estimate(frame, V, res.energies, res.iterations, assessment, t0, visible)

    def _mesh_area_m2(self) -> float:
        """The canonical mesh's area, square metres."""
        return float(face_areas(self.mesh.canonical, self.mesh.faces).sum())

    def _placement_failed(self, frame: RGBDFrame, t0: float) -> MeshEstimate | None:
        """After a registration whose placement did not hold: None (the mesh kept) in the first
        ``KEEP_MESH_LOST_FRAMES - 1`` lost frames, else the object segmented again with a new
        mesh (``_reinitialise_on_segment``)."""
        if self.lost_streak < KEEP_MESH_LOST_FRAMES:
            return None
        return self._reinitialise_on_segment(frame, t0)

    def _object_only(self, mask: np.ndarray, frame: RGBDFrame) -> np.ndarray:
        """``mask`` (H, W) bool less what the object cannot be (``_not_object``)."""
        excluded = self._not_object(frame, self._differs(frame))
        return mask if excluded is None else mask & ~excluded

    def _differs(self, frame: RGBDFrame) -> np.ndarray | None:
        """(H, W) bool, the pixels of ``frame`` that differ from the empty workspace; None
        without a background."""
        return None if self._background is None else differs_from_background(frame, self._background)

    @staticmethod
    def _not_object(frame: RGBDFrame, differs: np.ndarray | None) -> np.ndarray | None:
        """(H, W) bool, what the object cannot be: pixels of a known occluder
        (``frame.occluder_mask``) and, with ``differs`` (``_differs``), pixels that do not
        differ from the empty workspace; None when neither is known."""
        excluded = frame.occluder_mask
        if differs is not None:
            excluded = ~differs if excluded is None else excluded | ~differs
        return excluded

    def _reinitialise_on_segment(self, frame: RGBDFrame, t0: float) -> MeshEstimate | None:
        """A new mesh on the object segmented afresh (by its colour, else by depth); the
        estimate if it is not lost, else None, the tracker then left as it was.

        Unless the frame masks the robot's own arms (``RGBDFrame.occluder_mask``), a colourful
        print is not found again on a surface of one hue (``AppearanceModel.could_be``): an arm
        or a hand of the cloth's colour is segmented as readily as the cloth, and a mesh built
        on it would look right to every later check, since its appearance is learnt anew. With
        the arms masked, such a surface is the cloth's unprinted back, and is taken."""
        cfg = self.config
        mask = find_by_colour(frame.depth_m, frame.rgb, self._colour, cfg.segmentation) \
            if self._colour is not None else np.zeros(frame.depth_m.shape, bool)
        if not mask.any():
            mask = find_object(frame.depth_m, frame.camera.K, cfg.segmentation, self._rng)
        mask = self._object_only(mask, frame)
        if not mask.any():
            return None
        # Less of a cloth may show (``PARTIAL_AREA``, ``CUT_AREA``), but it does not grow: a far
        # larger surface of the right colour (a wall, the floor) is not the object.
        try:
            area = object_area_m2(observe(frame, mask, cfg.depth_window_px))
        except InitialisationError:
            return None
        # Measured against the mesh first laid, not one built since on a part of the cloth.
        rest = self._cloth_area_m2
        least = CUT_AREA if touches_border(mask) else PARTIAL_AREA
        if not least * rest <= area <= 1.5 * rest:
            log.debug("frame %d: segmented object of %.3f m^2 against the cloth's %.3f m^2: not it", frame.seq, area, rest)
            return None
        saved = dict(self.__dict__)
        # Carried over to the new mesh: the counts, the cloth's first area, and the workspace's
        # plane (it does not move with the cloth: it stays the one seen first).
        kept = (self.reacquisitions + 1, self.coarse_corrections, self._cloth_area_m2, self._support_plane)
        # ``frame`` and the workspace are undistorted already: the new mesh is laid on them as
        # they are, and the camera's own undistortion stays for the frames to come.
        lens = (self._undistort, self._background_given)
        cloth = self._appearance
        try:
            estimate = self._initialise(frame, mask, None, self._background)
        except TrackingError:
            estimate = None
        if estimate is not None and frame.occluder_mask is None and cloth is not None \
                and not cloth.could_be(self._appearance):
            log.debug("frame %d: the segmented object lacks the cloth's print: not it", frame.seq)
            estimate = None
        if estimate is None or estimate.lost:
            self.__dict__.update(saved)
            return None
        self.reacquisitions, self.coarse_corrections, self._cloth_area_m2, self._support_plane = kept
        self._undistort, self._background_given = lens
        log.info("frame %d: object found again by segmentation; new mesh of %d vertices", frame.seq,
                 self.mesh.n_vertices)
        return replace(estimate, timing_ms=(time.perf_counter() - t0) * 1000.0)

    def _coarse_prediction(self, V_pred: np.ndarray, small: np.ndarray, frame: RGBDFrame) -> np.ndarray:
        """The best of several predictions for this frame (N, 3): ``V_pred`` (constant velocity),
        the last estimate unmoved, and the last estimate moved by the image translation that
        phase correlation measures around it (``perception.coarse``), each scored by how well
        the vertices seen in the last frame agree with the new one; when none agrees well, also
        the last good estimate placed by global registration (``perception.registration``).
        A hypothesis other than ``V_pred`` must score clearly better to be taken, and none is
        that would put the mesh on something come in front of the cloth
        (``_onto_what_came_in_front``)."""
        K = frame.camera.K
        uv_prev = project(self._V, K)
        seen = np.all(np.isfinite(uv_prev), axis=1) & (self._visible if self._visible is not None else True)
        if self._occluded_before is not None:
            # The stored frame is blurred: a vertex next to an object in front looks like the
            # object there, and a hypothesis that moves with the object would score well. Left
            # out of the whole stage (the scores, the box the translation is measured in, the
            # depth change measured), unless too few are left to judge by.
            away = seen & ~self._memory.near(self._occluded_before, uv_prev)
            seen = away if away.sum() >= 3 else seen
        if seen.sum() < 3:
            return V_pred
        scores = {"velocity": self._support(V_pred, small, frame, uv_prev, seen)}
        self.last_motion_scores = scores
        if scores["velocity"] >= 0.9:  # the prediction explains the frame: nothing to look for
            return V_pred
        hypotheses = {"velocity": V_pred, "still": self._V}
        h, w = frame.depth_m.shape
        u, v = uv_prev[seen].T
        box = (max(0.0, v.min()), min(h, v.max() + 1), max(0.0, u.min()), min(w, u.max() + 1))
        found = self._memory.translation(small, box)
        if found is not None and found[1] > MIN_RESPONSE:
            moved = self._translated(uv_prev, seen, found[0], frame)
            if self._onto_what_came_in_front(moved, seen, frame):
                log.debug("frame %d: the translation measured is of something come in front; not taken", frame.seq)
            else:
                hypotheses["translation"] = moved
        for name in hypotheses.keys() - scores.keys():
            scores[name] = self._support(hypotheses[name], small, frame, uv_prev, seen)
        if max(scores.values()) < 0.5 and self._registration is not None:
            # None of them explains the frame: look for the object in the whole frame.
            occluder = frame.occluder_mask
            found = self._registration.register(grey_of(frame), frame.depth_m, self._good_V, self.mesh.faces, K,
                                                None if occluder is None else ~occluder)
            placed = None if found is None else found.apply(self._good_V)
            if placed is not None and not self._onto_what_came_in_front(placed, seen, frame):
                hypotheses["registration"] = placed
                scores["registration"] = self._support(placed, small, frame, uv_prev, seen)
        best = max(scores, key=scores.get)
        if best == "velocity" or scores[best] < scores["velocity"] + 0.03:
            return V_pred
        log.debug("frame %d: predicted from %s (scores %s)", frame.seq, best, scores)
        self.coarse_corrections += 1
        return hypotheses[best]

    def _translated(self, uv_prev: np.ndarray, seen: np.ndarray, shift_px: np.ndarray, frame: RGBDFrame) -> np.ndarray:
        """The last estimate moved so that its image moves by ``shift_px`` (2,), each vertex at
        the depth change measured for the seen ones (their median where a pixel's depth jumps
        away from it, or is missing)."""
        K = frame.camera.K
        h, w = frame.depth_m.shape
        uv_new = uv_prev + shift_px
        cols, rows, inside = pixel_index(uv_new, w, h)
        d = np.where(inside, frame.depth_m[rows, cols], np.nan).astype(np.float64)
        dz = d - self._V[:, 2]
        measured = np.isfinite(dz) & (d > 0) & seen
        typical = float(np.median(dz[measured])) if measured.any() else 0.0
        dz = np.where(measured & (np.abs(dz - typical) < self.config.depth_outlier_m), dz, typical)
        return rays(np.where(np.isfinite(uv_new), uv_new, 0.0), K) * (self._V[:, 2] + dz)[:, None]

    def _onto_what_came_in_front(self, V: np.ndarray, seen: np.ndarray, frame: RGBDFrame) -> bool:
        """True when the hypothesis ``V`` (N, 3) brings the mesh onto something come in front of
        the cloth: nearer (``_brought_nearer``, a median) where it came in front
        (``_came_in_front``, which classifies the vertices: asked only of a hypothesis nearer)."""
        return self._brought_nearer(V, seen) and self._came_in_front(seen, frame)

    def _came_in_front(self, seen: np.ndarray, frame: RGBDFrame) -> bool:
        """True when most of the vertices ``seen`` (N,) bool in the last frame are hidden now
        where they were, behind a surface nearer than them by more than ``occlusion_margin_m``:
        something came in front of the cloth, and a hypothesis that brings the mesh that much
        nearer (``_brought_nearer``) has it on that thing (phase correlation measured a board
        sliding in before a cloth and read its depth where the moved mesh landed, 36 cm off; a
        registration matched a few points and placed the mesh halfway). Never after a lost
        frame: a mesh lost may lie on the wall behind, and what is nearer is then the cloth."""
        if self.lost_streak:
            return False
        state = classify_vertices(self._V[seen], frame.depth_m, frame.camera.K, self.config.occlusion_margin_m)
        return float(np.mean(state == OCCLUDED)) > 0.5

    def _brought_nearer(self, V: np.ndarray, seen: np.ndarray) -> bool:
        """True when ``V`` (N, 3) brings the vertices ``seen`` nearer than the last estimate by
        more than ``occlusion_margin_m`` (median)."""
        return float(np.median(V[seen, 2] - self._V[seen, 2])) < -self.config.occlusion_margin_m

    def _support(self, V: np.ndarray, small: np.ndarray, frame: RGBDFrame, uv_prev: np.ndarray, seen: np.ndarray) -> float:
        """How well ``V`` (N, 3) explains the frame, in [0, 1]: the fraction of the vertices
        seen in the last frame that land on measured depth within ``depth_outlier_m`` of
        their own, weighted by how alike the grey values there and at their previous pixels are."""
        uv = project(V, frame.camera.K)
        h, w = frame.depth_m.shape
        cols, rows, inside = pixel_index(uv[seen], w, h)
        d = frame.depth_m[rows, cols]
        on_surface = inside & np.isfinite(d) & (np.abs(d - V[seen, 2]) < self.config.depth_outlier_m)
        look = self._memory.agreement(small, uv_prev[seen], uv[seen])
        return float(on_surface.mean() * (0.5 + 0.5 * max(look, 0.0)))

    def _tethered(self, V: np.ndarray, frame: RGBDFrame) -> np.ndarray:
        """``V`` (N, 3) within reach of the points ``frame`` says the robot holds (unchanged if none)."""
        if not self.config.tether or frame.held_vertices is None or not frame.held_vertices.size:
            return V
        return self._tethers.apply(V, frame.held_vertices, frame.held_points_m, self.config.tether_slack)

    def _with_unknown_occluders(self, frame: RGBDFrame, V: np.ndarray, differs: np.ndarray | None) -> RGBDFrame:
        """``frame`` with the objects in front of the mesh ``V`` (N, 3) that nobody announced
        (``perception.occluders``) added to its occluder mask; ``differs`` as ``_differs``."""
        near = self.config.unknown_occluder_m
        if near <= 0:
            return frame
        if self._surroundings_measured and self.last_observation is not None:
            self._object_before.append(self.last_observation.mask)
        front = occluders_in_front(frame.depth_m, V, self.mesh.faces, frame.camera.K, near, frame.occluder_mask,
                                   self._unknown_occluder, rgb=frame.rgb, colour=self._colour,
                                   workspace=None if differs is None else ~differs, support=self._support_plane,
                                   object_before=tuple(self._object_before),
                                   seen_before=self._visible)
        self._unknown_occluder = front
        if front is None:
            return frame
        if frame.occluder_mask is not None:
            front = front | frame.occluder_mask
        return replace(frame, occluder_mask=front)

    def _solve_frame(self, frame, V_pred, pred_mask, grey, prepared, t0) -> MeshEstimate:
        cfg = self.config
        K = frame.camera.K
        faces = self.mesh.faces
        V_pred = self._tethered(V_pred, frame)
        differs = self._differs(frame)
        frame = self._with_unknown_occluders(frame, V_pred, differs)
        self._occluded_before = frame.occluder_mask
        z = V_pred[:, 2]
        state = self._states(V_pred, frame)
        behind = np.any(state[faces] == OCCLUDED, axis=1)
        hidden_mask = faces_mask(project(V_pred, K), faces[behind], pred_mask.shape) if behind.any() else None
        not_object = self._not_object(frame, differs)
        segment = segment_tracked(frame.depth_m, pred_mask, (float(z.min()), float(z.max())), cfg.segmentation,
                                  hidden_mask, frame.rgb, self._colour, not_object, with_extent=False, differs=differs)
        mask = segment.mask
        extent = _Done(None)
        if mask.any() and self._colour is not None and self._colour.informative:
            # Only the confidence needs the object's extent: it is found on the second core
            # while this thread minimises.
            args = (mask, frame.depth_m, pred_mask, frame.rgb, self._colour, cfg.segmentation, not_object)
            extent = self._worker().submit(object_extent, *args) if cfg.feature_thread else _Done(object_extent(*args))
        if not mask.any():
            log.debug("frame %d: object not seen", frame.seq)
            self._V_prev, self._V = self._V, self._V.copy()
            self.last_observation = None
            # Nothing of the object was seen, so the estimate reports no vertex seen; the next
            # frame's coarse stage still scores its hypotheses on those the camera could see.
            estimate = self._estimate(frame, self._V, {}, 0, None, t0, np.zeros(len(self._V), bool))
            self._visible = self._states(self._V, frame) == VISIBLE
            return estimate
        # Hidden and out-of-view vertices have no data; one without depth may have slid off
        # the object (the boundary term brings it back) or sit on a hole in the depth.
        observed = (state == VISIBLE) | (state == NO_DEPTH)
        obs = observe(frame, mask, cfg.depth_window_px, grey=grey, unsearched=segment.unsearched)
        corr = None
        feature_mask = self._feature_mask(mask)
        if prepared is not None:
            fid, bary, xy = self._corr.match(obs.grey, feature_mask, V_pred, faces, K, prepared.result(),
                                             face_state=face_states(state, faces))
            if self._anchors is not None:
                found = self._anchors.match(obs.grey, feature_mask, V_pred, K)
                fid, bary, xy = (np.concatenate(parts) for parts in zip((fid, bary, xy), found))
            pts, has = obs.points_at(xy)
            self.last_feature_xy = xy[has]
            if has.any():
                B = barycentric_matrix(fid[has], bary[has], faces, self.mesh.n_vertices)
                corr = CorrespondenceTerm(B, pts[has], np.ones(int(has.sum())))
        terms = self._data_terms(obs, corr, observed, V_pred, frame)
        V = V_pred
        stages = cfg.outlier_radii_m if corr is not None else (None,)
        carry = cfg.lambda_m > 0 and not observed.all()
        if carry and len(stages) == 1:
            stages = (stages[0], stages[0])  # a stage to solve the hidden part moved with the rest
        budget = max(1, cfg.max_iterations // len(stages))
        iterations, energies = 0, {}
        for k, radius in enumerate(stages):
            if k and carry:
                V, terms = self._carry_hidden(V_pred, V, terms, state, observed, frame)
            if radius is not None:
                corr.weights = (corr.residuals(V) < radius).astype(np.float64)
            res = self._solver.minimise(V, terms, budget, cfg.tolerance_m,
                                        min_predicted_decrease=cfg.min_predicted_decrease)
            V, energies = res.vertices, res.energies
            iterations += res.iterations
        V = self._tethered(V, frame)
        if self._corr is not None:
            self._corr.update(obs.grey, feature_mask, V, faces, K)
        self._V_prev, self._V = self._V, V
        self.last_observation = obs
        matched = 1.0
        if corr is not None:
            energies["inliers"] = float(corr.weights.sum())
            matched = matches_cap(corr.residuals(V), stages[-1])
        visible = self._states(V, frame) == VISIBLE
        carried, self._last_seen = self._carried(V, visible, frame)
        assessment = self._assess(V, frame, visible, mask, segment.leak, carried, extent.result(), differs, matched)
        return self._estimate(frame, V, energies, iterations, assessment, t0, visible)

    def _carry_hidden(self, V_pred: np.ndarray, V: np.ndarray, terms: list, state: np.ndarray, observed: np.ndarray,
                      frame: RGBDFrame) -> tuple[np.ndarray, list]:
        """(V, terms) for the next solver stage: the vertices not ``observed`` (N,) bool moved
        from the prediction ``V_pred`` (N, 3) as the cloth seen around them moved from it to
        ``V`` (N, 3), the estimate so far (``perception.hidden_motion``), and the motion prior
        in ``terms`` keeping them there. ``state`` (N,) the vertices' states at the prediction;
        the vertices seen and those the robot holds are the evidence."""
        seen = state == VISIBLE
        if frame.held_vertices is not None and frame.held_vertices.size:
            seen = seen.copy()
            seen[frame.held_vertices] = True
        moved = carried_prior(self.mesh.canonical, V_pred, V, seen, ~observed)
        # the same edges and anchors, around the moved prior
        return moved, [(w, replace(term, prior=moved) if isinstance(term, MotionPriorTerm) else term) for w, term in terms]

    def _carried(self, V: np.ndarray, visible: np.ndarray, frame: RGBDFrame) -> tuple[float, np.ndarray]:
        """(share, last_seen): the share of the vertices of ``V`` (N, 3) that are hidden now
        (``visible`` (N,) bool False, not held by the robot) and lie more than ``carried_tol_m``
        from where they were last seen or held, and (N, 3) where each vertex was last seen or
        held, counting this estimate."""
        placed = visible.copy()
        if frame.held_vertices is not None and frame.held_vertices.size:
            placed[frame.held_vertices] = True
        last_seen = np.where(placed[:, None], V, self._last_seen)
        moved = np.linalg.norm(V - last_seen, axis=1) > self.config.carried_tol_m
        return float(np.mean(moved)), last_seen

    # -- outputs -------------------------------------------------------------------------

    def _assess(self, V: np.ndarray, frame: RGBDFrame, visible: np.ndarray, object_mask: np.ndarray,
                leak: float = 0.0, carried: float = 0.0, extent: np.ndarray | None = None,
                differs: np.ndarray | None = None, matched: float = 1.0) -> Assessment:
        """The evidence for estimate ``V`` (N, 3) in ``frame`` (``perception.confidence``);
        ``leak`` and ``extent`` are the segmentation's (``perception.segmentation.Segment``),
        ``carried`` the share of the mesh moved far while hidden (``_carried``), ``differs``
        the frame's pixels that differ from the empty workspace (``_differs``), if known,
        ``matched`` what the frame's feature matches allow (``perception.confidence.matches_cap``)."""
        K = frame.camera.K
        exposed = None if differs is None else seen_through(V, K, differs, frame.depth_m, self.config.confidence_tol_m)
        likeness = 1.0
        if self._appearance is not None:
            likeness = self._appearance.likeness(frame.rgb, V, self.mesh.faces, K, visible)
        textured = self._appearance is not None and self._appearance.textured
        # only a plain cloth's cap depends on its change of shape: not measured on a printed one
        reshaped = 0.0 if textured or self._laid_V is None else reshaping(self._laid_V, V)
        cap = min(material_cap(textured, reshaped), matched)
        assessment = assess(V, self._edges, self._rest_lengths, visible, frame.depth_m, object_mask,
                            K, self.config.confidence_tol_m, likeness, leak, carried, extent, exposed, cap,
                            self._within_reach(frame, object_mask))
        self.last_assessment = assessment
        return assessment

    def _within_reach(self, frame: RGBDFrame, object_mask: np.ndarray) -> float:
        """The ``within_reach`` cue (``perception.confidence``) of the object ``object_mask``
        (H, W) bool measured in ``frame``, from the points its grippers hold
        (``RGBDFrame.held_vertices``, less rows whose orientation is NaN: points no gripper
        holds); 1 when the frame says of none."""
        held = frame.held_vertices
        if held is None or not held.size:
            return 1.0
        gripped = np.ones(held.size, bool) if frame.held_quats_xyzw is None \
            else np.isfinite(frame.held_quats_xyzw).all(axis=1)
        if not gripped.any():
            return 1.0
        step = 2  # every other pixel each way: a quarter of the pixels, the same extent
        depth = frame.depth_m[::step, ::step]
        rows, cols = np.nonzero(object_mask[::step, ::step] & np.isfinite(depth) & (depth > 0))
        points = backproject(np.column_stack([cols, rows]) * step, depth[rows, cols], frame.camera.K)
        reach = material_reach(self.mesh.canonical, held[gripped])
        return within_reach(reach_ratio(points, frame.held_points_m[gripped], reach))

    def _estimate(self, frame, V, energies, iterations, assessment: Assessment | None, t0, visible) -> MeshEstimate:
        """The MeshEstimate; ``assessment`` None means the object was not seen at all (lost)."""
        confidence = 0.0 if assessment is None else assessment.confidence
        lost = True if assessment is None else assessment.lost(self.config.lost_confidence)
        self._visible = visible
        return MeshEstimate(
            vertices=V, faces=self._faces_out, boundary=self.mesh.boundary, canonical=self.mesh.canonical,
            timestamp_s=frame.timestamp_s, seq=frame.seq, energies=energies, iterations=iterations,
            confidence=confidence, lost=lost,
            timing_ms=(time.perf_counter() - t0) * 1000.0, frame_id=frame.camera.frame_id, visible=visible)


def config_with(config: TrackerConfig, **changes) -> TrackerConfig:
    """A copy of ``config`` with ``changes``; unknown names raise ValueError naming them."""
    known = set(TrackerConfig.__dataclass_fields__)
    unknown = sorted(set(changes) - known)
    if unknown:
        raise ValueError(f"unknown tracker parameter(s): {', '.join(unknown)}")
    return replace(config, **changes)
