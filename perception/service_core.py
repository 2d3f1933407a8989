"""The perception service's state machine around one MeshTracker: frames and requests in,
estimates and states out, without sockets or threads.

States are those of ``StatusReply.STATES``: "idle" (no mesh; frames are counted, not
tracked), "initialising" (a mesh is built on the next usable frame), "tracking", "lost"
(the last estimate was flagged lost). Bad input never stops it: a frame without any valid
depth, with depth or intrinsics no sensor gives (``perception.frame_checks``), from
another camera (size or intrinsics), a frame the tracker rejects, a failed initialisation
(an object too large for the mesh budget among the reasons) or a tracker failure is
logged once per kind, counted (``Counters.rejected``) and skipped. Parameters are
checked by ``perception.parameters`` before they apply.

Automatic (re-)initialisation by depth segmentation, when ``auto_init`` is on (default):
at start; after a discontinuity of the frame stream (``discontinuity``: the source was
silent and came back, it restarted, or ``seq`` went backwards), since the tracker's motion
prediction assumes consecutive frames; and, if ``reinit_after_lost`` = N > 0, after N
consecutive lost or rejected frames. ``request_reset`` always leaves it "idle" until
``request_initialise``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from ipc.messages import MeshEstimate, RGBDFrame
from perception.frame_checks import check_frame, object_lattice_bound, seen_area_m2, spacing_px
from perception.geometry import lens_coefficients, same_optics
from perception.initial_mesh import automatic_spacing, mesh_vertices
from perception.parameters import LATTICE_BUDGET, MAX_MESH_VERTICES, apply_parameters, check_work, tracker_parameters
from perception.segmentation import find_object
from perception.tracker import MeshTracker, TrackerConfig, TrackingError

log = logging.getLogger(__name__)

#: Occluder masks sent for frames not yet received that the service keeps at most.
MAX_PENDING_OCCLUDERS = 64


@dataclass
class Counters:
    """What the service has seen since it started (ints, read any time)."""

    frames_taken: int = 0  # frames given to the core (the others were skipped as older than the newest)
    processed: int = 0  # frames initialised on or tracked
    reinitialisations: int = 0  # automatic re-initialisations (discontinuity, lost streak, re-acquisition)
    discontinuities: int = 0  # frame stream discontinuities seen
    rejected: dict = dataclasses.field(default_factory=dict)  # kind -> frames rejected


class PerceptionCore:
    """The service's state machine around one MeshTracker; no sockets, no threads.

    tracker_config : TrackerConfig of the tracker
    auto_init : start "initialising" and re-initialise by depth segmentation after a
        discontinuity (see the module docstring); else start "idle"
    reinit_after_lost : N > 0 re-initialises after N consecutive lost or rejected frames
        (with auto_init); 0 never
    """

    def __init__(self, tracker_config: TrackerConfig | None = None, *, auto_init: bool = True, reinit_after_lost: int = 0):
        if isinstance(reinit_after_lost, bool) or not isinstance(reinit_after_lost, int) or reinit_after_lost < 0:
            raise ValueError(f"reinit_after_lost: expected a non-negative integer, got {reinit_after_lost!r}")
        self.tracker = MeshTracker(tracker_config)
        self.auto_init = bool(auto_init)
        self.reinit_after_lost = reinit_after_lost
        self.state = "initialising" if self.auto_init else "idle"
        self.counters = Counters()
        self.frames_since_init = 0  # frames processed since the last initialisation, that one included
        self.last_seq = -1  # seq of the last frame processed
        self.last_confidence: float | None = None  # confidence of the last estimate, None before the first
        self.lost_streak = 0  # consecutive lost or rejected frames while tracking
        self.last_error = ""  # one line: why the last initialisation or frame failed
        self._pending_mask: np.ndarray | None = None
        self._pending_seq = -1  # the seq of the frame to initialise on; -1: the next one
        self._standing_occluder: np.ndarray | None = None  # (H, W) bool, for every frame
        self._occluders_by_seq: dict[int, np.ndarray] = {}  # seq -> (H, W) bool, for one frame
        self._frame_shape: tuple | None = None  # (H, W) of the last frame received
        self._last_frame: RGBDFrame | None = None
        self._background: RGBDFrame | None = None  # the empty workspace (InitialiseRequest.background)
        self._mesh_camera = None  # CameraInfo the mesh was initialised on
        self._logged_kinds: set = set()
        self._rng = np.random.default_rng(0)  # depth segmentation's plane fits, for the size check

    # -- requests --------------------------------------------------------------------------

    def request_initialise(self, mask: np.ndarray | None, background: RGBDFrame | None = None, seq: int = -1) -> None:
        """Build a new mesh on the next usable frame, or on the frame ``seq`` (>= 0), on
        ``mask`` ((H, W) uint8, non-zero on the object) or, if None, on the object found by
        depth segmentation; ``background`` (the empty workspace, or None) holds for this
        mesh and any the service builds itself after it, until the next request or a reset.

        With ``seq``, frames before it are not tracked, and a later frame handed first
        means the frame ``seq`` was missed: the initialisation fails ("init_failed"). A
        caller that holds frames received earlier hands the frame ``seq`` in again
        (``handle_frame(frame, again=True)``) before a later one.
        raises ValueError if the mask's or the background's size differs from that of the frames received"""
        if mask is not None and self._frame_shape is not None and mask.shape != self._frame_shape:
            raise ValueError(f"InitialiseRequest.mask: expected shape {self._frame_shape} like the frames, got {mask.shape}")
        if background is not None and self._frame_shape is not None and background.depth_m.shape != self._frame_shape:
            raise ValueError(f"InitialiseRequest.background: expected shape {self._frame_shape} like the frames, "
                             f"got {background.depth_m.shape}")
        self._background = background
        self._pending_mask = mask
        self._pending_seq = int(seq)
        self.state = "initialising"
        self.last_error = ""
        log.info("initialising on %s (%s)", f"frame {seq}" if seq >= 0 else "the next frame",
                 "mask" if mask is not None else "depth segmentation")

    @property
    def initialise_seq(self) -> int:
        """The ``seq`` of the frame the next mesh is to be built on, or -1 (none in particular)."""
        return self._pending_seq if self.state == "initialising" else -1

    def set_occluder_mask(self, mask: np.ndarray | None, seq: int = -1) -> None:
        """Where a known occluder covers frame ``seq`` (-1: every frame from now on).

        mask : (H, W) uint8 or bool, non-zero on the occluder; None clears it
        raises ValueError if the mask's size differs from that of the frames received"""
        if mask is not None and self._frame_shape is not None and mask.shape != self._frame_shape:
            raise ValueError(f"OccluderMaskRequest.mask: expected shape {self._frame_shape} like the frames, got {mask.shape}")
        occluder = None if mask is None else np.asarray(mask) != 0
        if seq < 0:
            self._standing_occluder = occluder
        elif occluder is None:
            self._occluders_by_seq.pop(seq, None)
        else:
            if seq not in self._occluders_by_seq and len(self._occluders_by_seq) >= MAX_PENDING_OCCLUDERS:
                raise ValueError(f"OccluderMaskRequest.seq {seq}: {MAX_PENDING_OCCLUDERS} frames' masks are waiting "
                                 f"already (frames {min(self._occluders_by_seq)} to {max(self._occluders_by_seq)}); "
                                 f"send it when fewer are")
            self._occluders_by_seq[seq] = occluder

    def _with_occluders(self, frame: RGBDFrame) -> RGBDFrame:
        """``frame`` with its own occluder mask, the standing one and the one sent for its seq combined."""
        for seq in [s for s in self._occluders_by_seq if s < frame.seq]:
            del self._occluders_by_seq[seq]  # those frames have passed
        masks = [m for m in (frame.occluder_mask, self._standing_occluder, self._occluders_by_seq.pop(frame.seq, None))
                 if m is not None and m.shape == frame.depth_m.shape]
        if not masks or (len(masks) == 1 and masks[0] is frame.occluder_mask):
            return frame
        return dataclasses.replace(frame, occluder_mask=np.logical_or.reduce(masks))

    def request_reset(self) -> None:
        """Drop the mesh; stay idle until ``request_initialise``."""
        self.tracker.reset()
        self._pending_mask = None
        self._pending_seq = -1
        self._background = None
        self._mesh_camera = None
        self.state = "idle"
        self.frames_since_init = 0
        self.lost_streak = 0
        log.info("reset: idle until an InitialiseRequest")

    def set_parameters(self, parameters: dict) -> None:
        """Change tracker parameters (see ``apply_parameters`` and ``check_work``); raises
        ValueError, changing nothing."""
        old = self.tracker.config
        new = apply_parameters(old, parameters)
        check_work(new, self.expected_vertices(new))
        try:
            self.tracker.set_config(new)
        except ValueError:
            # set_config may fail after taking the new config (e.g. an unknown solver name).
            self.tracker.set_config(old)
            raise
        log.info("tracker parameters set: %s", parameters)

    def parameters(self) -> dict:
        """The parameters SetParametersRequest accepts, with their current values."""
        return tracker_parameters(self.tracker.config)

    def expected_vertices(self, config: TrackerConfig) -> int | None:
        """About how many vertices a mesh built with ``config`` would have, or the mesh tracked
        now if it has more: when ``config`` chooses the spacing (``spacing_m`` 0), the larger
        of ``target_vertices`` and the current mesh's count; else on the current object if
        there is a mesh, or on everything seen in the last frame received (no object can be
        larger); None before any frame."""
        mesh = self.tracker.mesh
        if config.spacing_m == 0:  # the mesh tracked now, or the one a new object gets
            return max(config.target_vertices, 0 if mesh is None else mesh.n_vertices)
        if mesh is not None:
            return math.ceil(mesh.n_vertices * (mesh.spacing_m / config.spacing_m) ** 2)
        frame = self._last_frame
        if frame is None:
            return None
        return mesh_vertices(seen_area_m2(frame), config.spacing_m)

    def discontinuity(self, reason: str) -> None:
        """The frame stream is not a continuation of the frames tracked so far (``reason``, one line)."""
        self.counters.discontinuities += 1
        if self.initialise_seq >= 0:
            # The frame to build the mesh on belongs to a stream that has ended: with automatic
            # initialisation the service builds a mesh by itself, as after any discontinuity.
            missed = f"{reason} before frame {self._pending_seq} to initialise on arrived"
            if self.auto_init:
                log.info("%s: re-initialising on the next frame", missed)
                self._reinitialise()
            else:
                self.last_error = self._give_up_initialising(missed)
                log.warning("%s", self.last_error)
        elif self.auto_init and self.state in ("tracking", "lost"):
            log.info("%s: re-initialising on the next frame", reason)
            self._reinitialise()
        else:
            log.info("%s", reason)

    def _reinitialise(self) -> None:
        self.counters.reinitialisations += 1
        self._pending_mask = None
        self._pending_seq = -1
        self.state = "initialising"
        self.lost_streak = 0

    # -- frames ----------------------------------------------------------------------------

    def handle_frame(self, frame: RGBDFrame, again: bool = False) -> MeshEstimate | None:
        """Process one frame according to the state; returns its estimate, or None when the
        frame was not tracked (idle, waiting for the frame to initialise on, or rejected:
        see ``counters.rejected``). ``again``: a frame received before (skipped or taken),
        handed in again to be initialised on; not counted as taken a second time."""
        estimate = self._handle_frame(frame, again)
        standing = self._standing_occluder
        if standing is not None and standing.shape != frame.depth_m.shape:
            # Sent before any frame, when its size could not be checked, and ignored for this
            # one: dropped, and said after the frame (an initialisation clears the last error).
            self.last_error = (f"standing occluder mask of shape {standing.shape} dropped: the frames are "
                               f"{frame.depth_m.shape}")
            log.warning("%s", self.last_error)
            self._standing_occluder = None
        return estimate

    def _handle_frame(self, frame: RGBDFrame, again: bool) -> MeshEstimate | None:
        if not again:
            self.counters.frames_taken += 1
            self._frame_shape = frame.depth_m.shape
            self._last_frame = frame
        if self.state == "idle":
            return None
        wanted = self.initialise_seq
        if wanted >= 0 and frame.seq != wanted:
            if frame.seq > wanted:
                return self._reject("init_failed", self._give_up_initialising(
                    f"frame {wanted} to initialise on was not received (frame {frame.seq} came first)"))
            return None
        problem = check_frame(frame)
        if problem is not None:
            if wanted >= 0:
                # The frame named is unusable: without a mask, as when the mesh cannot be built
                # on it, depth segmentation tries the next frames; a mask fits no other frame.
                self._pending_seq = -1
                if self._pending_mask is not None:
                    kind, message = problem
                    return self._reject(kind, self._give_up_initialising(f"{message}; the mask cannot be used"))
            return self._reject(*problem)
        frame = self._with_occluders(frame)
        try:
            if self.state == "initialising":
                return self._initialise(frame)
            return self._track(frame)
        except Exception as e:  # a tracker failure on one frame must not stop the service
            if "internal" not in self._logged_kinds:
                log.exception("frame %d: tracker failed (later failures are counted in the status)", frame.seq)
            return self._reject("internal", f"frame {frame.seq}: {type(e).__name__}: {e}", log_it=False)

    def _initialise(self, frame: RGBDFrame) -> MeshEstimate | None:
        mask = self._pending_mask
        try:
            self._check_object_size(frame, mask)
            estimate = self.tracker.initialise(frame, mask=mask, background=self._background)
        except TrackingError as e:
            self._pending_seq = -1  # without a mask, depth segmentation tries the next frames
            if mask is not None:
                # A controller's mask will not fit later frames better: wait for a new request.
                self._pending_mask = None
                self.state = "idle"
            return self._reject("init_failed", f"frame {frame.seq}: initialisation failed: {e}")
        self._pending_mask = None
        self._pending_seq = -1
        self._mesh_camera = frame.camera
        self.frames_since_init = 0
        self.lost_streak = 0
        self.last_error = ""
        return self._accept(frame, estimate)

    def _give_up_initialising(self, reason: str) -> str:
        """The frame the request named cannot be had: wait idle for a new request. Returns
        the one-line error."""
        self._pending_mask = None
        self._pending_seq = -1
        self.state = "idle"
        return f"{reason}: send a new InitialiseRequest"

    def _check_object_size(self, frame: RGBDFrame, mask: np.ndarray | None) -> None:
        """Raise TrackingError when the mesh laid over the object (``mask``, or the object
        depth segmentation finds) could exceed the vertex budget, or one of its triangles
        the image, before the tracker spends memory and time on it. Segmenting here and again
        in the tracker costs one segmentation per initialisation."""
        config = self.tracker.config
        if mask is None:
            mask = find_object(frame.depth_m, frame.camera.K, config.segmentation, self._rng)
        elif mask.shape != frame.depth_m.shape:
            raise TrackingError(f"mask: expected shape {frame.depth_m.shape} like the frame, got {mask.shape}")
        mask = mask.astype(bool)
        area_m2 = seen_area_m2(frame, mask)
        if config.spacing_m:
            spacing = config.spacing_m
        else:
            # As the tracker chooses it (``perception.initial_mesh.spacing_for``), on the area as
            # seen facing the camera: tilted surfaces count more, so the tracker's is no finer.
            z = frame.depth_m[mask & (frame.depth_m > 0)]
            if z.size == 0:
                return  # no pixel of the object has depth: the tracker says so
            spacing = automatic_spacing(area_m2, config.target_vertices, float(np.median(z)), frame.camera.fx)
        edge_px = spacing_px(frame, mask, spacing)
        if edge_px > max(frame.camera.width, frame.camera.height):
            raise TrackingError(f"the object is smaller than one triangle: spacing_m {spacing:g} spans "
                                f"{edge_px:.0f} px at its depth, more than the {frame.camera.width}x{frame.camera.height} image")
        vertices = mesh_vertices(area_m2, spacing)
        if config.spacing_m and vertices > MAX_MESH_VERTICES:  # a chosen spacing stays near target_vertices
            raise TrackingError(f"the object is too large for a mesh at spacing_m {spacing:g}: about {vertices} "
                                f"vertices, over the budget of {MAX_MESH_VERTICES}")
        bound = object_lattice_bound(frame, mask, spacing)
        if bound > LATTICE_BUDGET:
            raise TrackingError(f"the object is too large for a mesh at spacing_m {spacing:g}: up to {bound} "
                                f"lattice points, over the budget of {LATTICE_BUDGET}")

    def _track(self, frame: RGBDFrame) -> MeshEstimate | None:
        cam, ref = frame.camera, self._mesh_camera
        if (cam.width, cam.height) != (ref.width, ref.height) or not np.allclose(cam.K, ref.K):
            return self._reject("camera_changed", f"frame {frame.seq}: camera {cam.width}x{cam.height} fx={cam.fx:.6g} "
                                f"differs from the mesh's {ref.width}x{ref.height} fx={ref.fx:.6g}")
        if not same_optics(cam, ref):
            return self._reject("camera_changed", f"frame {frame.seq}: camera frame {cam.frame_id!r}, distortion "
                                f"{lens_coefficients(cam.D).tolist()} differ from the mesh's {ref.frame_id!r}, "
                                f"{lens_coefficients(ref.D).tolist()}")
        found_before = self.tracker.reacquisitions
        try:
            estimate = self.tracker.track(frame)
        except TrackingError as e:
            return self._reject("tracker", f"frame {frame.seq}: {e}")
        # The tracker found a lost object again by itself: that, too, is a re-initialisation.
        self.counters.reinitialisations += self.tracker.reacquisitions - found_before
        return self._accept(frame, estimate)

    def _accept(self, frame: RGBDFrame, estimate: MeshEstimate) -> MeshEstimate:
        self.counters.processed += 1
        self.frames_since_init += 1
        self.last_seq = frame.seq
        self.last_confidence = estimate.confidence
        if estimate.lost:
            self.state = "lost"
            self._bad_frame()
        else:
            self.state = "tracking"
            self.lost_streak = 0
        return estimate

    def _bad_frame(self) -> None:
        self.lost_streak += 1
        n = self.reinit_after_lost
        if self.auto_init and n and self.lost_streak >= n and self.state in ("tracking", "lost"):
            log.info("%d consecutive lost or rejected frames: re-initialising on the next frame", self.lost_streak)
            self._reinitialise()

    def _reject(self, kind: str, message: str, log_it: bool = True) -> None:
        """Count a frame not tracked, as ``kind``; log the first of each kind."""
        if self.state in ("tracking", "lost"):
            self._bad_frame()
        rejected = self.counters.rejected
        rejected[kind] = rejected.get(kind, 0) + 1
        self.last_error = message
        if kind not in self._logged_kinds:
            self._logged_kinds.add(kind)
            if log_it:
                log.warning("%s (later frames rejected as %r are counted in the status, not logged)", message, kind)
        else:
            log.debug("%s", message)
