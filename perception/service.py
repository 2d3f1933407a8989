"""The perception service: MeshTracker behind ZeroMQ (docs/protocol.md, section "Services").

It subscribes to ``RGBDFrame`` on the frames endpoint (newest frame only), tracks, and
publishes one ``MeshEstimate`` per frame processed on the estimates endpoint; on the
control endpoint it answers ``InitialiseRequest``, ``ResetRequest``,
``SetParametersRequest``, ``OccluderMaskRequest`` and ``StatusRequest`` with a
``StatusReply`` (or ``ErrorReply``).

Two layers:

- ``PerceptionCore``: the state machine, without sockets: frames and requests in,
  estimates and states out. States are those of ``StatusReply.STATES``:
  "idle" (no mesh; frames are counted, not tracked), "initialising" (a mesh is built on
  the next usable frame), "tracking", "lost" (the last estimate was flagged lost).
- ``PerceptionService``: the sockets and the loop around a core, plus what only it can
  measure for the ``StatusReply`` (frame arrivals, latency) and an optional live viewer
  (rerun-sdk).

Bad input never stops the service: a frame without any valid depth, with depth or
intrinsics no sensor gives (``perception.frame_checks``), from another camera (size or
intrinsics), a frame the tracker rejects, a failed initialisation (an object too large
for the mesh budget among the reasons) or a tracker failure is logged once per kind,
counted (``StatusReply.rejected_by_kind``) and skipped; malformed messages are dropped by
the subscriber and counted. Parameters are checked against ``PARAMETER_RANGES`` and the
budgets ``MAX_MESH_VERTICES`` and ``MAX_VERTEX_STEPS`` before they apply, so that one
frame's work, which control requests wait for, stays bounded.

Automatic (re-)initialisation by depth segmentation, when ``auto_init`` is on (default):
at start; after a discontinuity of the frame stream (the source was silent for the
subscriber's stale limit and came back, it restarted, or ``seq`` went backwards), since
the tracker's motion prediction assumes consecutive frames; and, if
``reinit_after_lost`` = N > 0, after N consecutive lost or rejected frames. A
``ResetRequest`` always leaves the service "idle" until an ``InitialiseRequest``.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from ipc import endpoints
from ipc.messages import (
    InitialiseRequest,
    MeshEstimate,
    OccluderMaskRequest,
    ResetRequest,
    RGBDFrame,
    SetParametersRequest,
    StatusReply,
    StatusRequest,
)
from ipc.transport import HEARTBEAT_PERIOD_S, STALE_AFTER_S, CurveKeys, Publisher, ReplyServer, Subscriber
from perception.frame_checks import (
    check_frame,
    mesh_vertices,
    object_lattice_bound,
    seen_area_m2,
    spacing_for_area,
    spacing_px,
)
from perception.geometry import backproject
from perception.segmentation import find_object
from perception.tracker import MeshTracker, TrackerConfig, TrackingError, config_with

log = logging.getLogger(__name__)

#: Value types a tracker parameter must have to be read and set over the wire.
WIRE_TYPES = (bool, int, float, str)

#: Occluder masks sent for frames not yet received that the service keeps at most.
MAX_PENDING_OCCLUDERS = 64

#: Estimates over which StatusReply summarises latency and tracking time: a few seconds
#: at camera rates, so the figures follow a change of load, and enough for a 99th percentile.
RECENT_ESTIMATES = 100


#: Most vertices a mesh may have: a finer spacing is refused when the current object (or,
#: before any mesh, the area seen in the last frame) would need more. With the paper's
#: preset a 5,500-vertex mesh took 0.25 s a frame and 0.4 s to build on two cores, so a
#: control request waiting for that frame is still answered within the 1 s of docs/protocol.md.
MAX_MESH_VERTICES = 5000

#: Most lattice points laid over an object when a mesh is built (``object_lattice_bound``),
#: an upper bound of its vertices: a compact object (a flat rectangle of cloth) keeps about
#: three quarters of them, so this admits the vertex budget for it and bounds every other.
LATTICE_BUDGET = 2 * MAX_MESH_VERTICES

#: Most solver work per frame, in vertex-steps: vertices x iterations x conjugate-gradient
#: steps per iteration (1 for the semi-implicit solver), for tracking (``max_iterations``) and
#: for the initialisation (``init_iterations``). The paper's preset on a 5,000-vertex mesh.
MAX_VERTEX_STEPS = 5000 * 10 * 8


@dataclass(frozen=True)
class Range:
    """Allowed values of a numerical parameter: from ``lo`` (excluded when ``lo_open``) to
    ``hi``, and 0 too when ``or_zero`` (a parameter for which 0 means "choose it")."""

    lo: float
    hi: float
    lo_open: bool = False
    or_zero: bool = False

    def __contains__(self, value) -> bool:
        if self.or_zero and value == 0:
            return True
        return (self.lo < value if self.lo_open else self.lo <= value) and value <= self.hi

    def __str__(self) -> str:
        return f"{'0 or ' if self.or_zero else ''}{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"


#: The range of every numerical parameter a SetParametersRequest may set: TrackerConfig's own
#: lower bounds, and upper bounds that keep the solver's numbers finite and one frame's work
#: bounded (a frame is tracked while control requests wait).
PARAMETER_RANGES = {
    "spacing_m": Range(0.005, 1.0, or_zero=True),
    "target_vertices": Range(3, MAX_MESH_VERTICES),
    "lambda_c": Range(0.0, 100.0),
    "lambda_d": Range(0.0, 100.0),
    "lambda_b": Range(0.0, 100.0),
    "lambda_m": Range(0.0, 100.0),
    "alpha": Range(1e-3, 1e3),
    "max_iterations": Range(1, 100),
    "cg_iterations": Range(1, 100),
    "tolerance_m": Range(0.0, 1.0, lo_open=True),
    "min_predicted_decrease": Range(0.0, 1.0),
    "max_features": Range(1, 2000),
    "min_descriptor_features": Range(0, 2000),
    "match_gate_px": Range(0.0, 1000.0, lo_open=True),
    "match_keep_fraction": Range(0.0, 1.0, lo_open=True),
    "depth_window_px": Range(1, 31),
    "depth_outlier_m": Range(0.0, 10.0, lo_open=True),
    "occlusion_margin_m": Range(0.0, 10.0, lo_open=True),
    "boundary_gate_m": Range(0.0, 10.0, lo_open=True),
    "velocity_prediction": Range(0.0, 2.0),
    "init_iterations": Range(0, 100),
    "confidence_tol_m": Range(0.0, 10.0, lo_open=True),
    "lost_confidence": Range(0.0, 1.0),
    "reacquire_every": Range(0, 1000),
}


def tracker_parameters(config: TrackerConfig) -> dict:
    """Every TrackerConfig field whose value is a bool, int, float or str, with its value:
    the parameters a SetParametersRequest may change (tuples and nested configs may not)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
            if isinstance(getattr(config, f.name), WIRE_TYPES)}


def apply_parameters(config: TrackerConfig, parameters: dict) -> TrackerConfig:
    """A copy of ``config`` with ``parameters`` (name -> value) applied, all or nothing.

    A value must have its parameter's type (an int is accepted for a float parameter) and
    lie in its ``PARAMETER_RANGES`` range. The budgets, which depend on the object, are
    ``check_work``'s.
    raises ValueError naming the unknown names, or the first parameter that cannot be set
    over the wire, or the first value of the wrong type or out of its range
    """
    if any(name not in TrackerConfig.__dataclass_fields__ for name in parameters):
        config_with(config, **parameters)  # raises ValueError naming every unknown name
    settable = tracker_parameters(config)
    changes = {}
    for name, value in parameters.items():
        if name not in settable:
            raise ValueError(f"tracker parameter {name!r} cannot be set over the wire (not a bool, int, float or str)")
        current = settable[name]
        if isinstance(current, bool):
            ok = isinstance(value, bool)
        elif isinstance(current, int):
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif isinstance(current, float):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            value = float(value) if ok else value
        else:
            ok = isinstance(value, str)
        if not ok:
            raise ValueError(f"tracker parameter {name!r}: expected {type(current).__name__}, got {type(value).__name__} {value!r}")
        allowed = PARAMETER_RANGES.get(name)
        if allowed is not None and value not in allowed:
            raise ValueError(f"tracker parameter {name!r}: expected a value in {allowed}, got {value!r}")
        changes[name] = value
    return config_with(config, **changes)


def check_work(config: TrackerConfig, n_vertices: int | None) -> None:
    """Refuse a configuration whose mesh of ``n_vertices`` (None: not known) would exceed
    ``MAX_MESH_VERTICES``, or whose solver work per frame would exceed ``MAX_VERTEX_STEPS``.

    raises ValueError naming the parameter and the largest or smallest value allowed
    """
    cg = config.cg_iterations if config.solver == "conjugate" else 1
    steps = max(config.max_iterations, config.init_iterations) * cg
    if n_vertices is None:
        return
    if n_vertices > MAX_MESH_VERTICES:
        raise ValueError(f"tracker parameter 'spacing_m': {config.spacing_m:g} m gives about {n_vertices} vertices on the "
                         f"object, over the budget of {MAX_MESH_VERTICES}; expected a spacing of at least "
                         f"{config.spacing_m * math.sqrt(n_vertices / MAX_MESH_VERTICES):.4g} m")
    if n_vertices * steps > MAX_VERTEX_STEPS:
        raise ValueError(f"tracker parameters 'max_iterations', 'init_iterations' and 'cg_iterations': {n_vertices} vertices x "
                         f"{steps} steps is {n_vertices * steps} vertex-steps a frame, over the budget of {MAX_VERTEX_STEPS}; "
                         f"expected at most {MAX_VERTEX_STEPS // max(n_vertices, 1)} steps (iterations x cg_iterations)")


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
        self._standing_occluder: np.ndarray | None = None  # (H, W) bool, for every frame
        self._occluders_by_seq: dict[int, np.ndarray] = {}  # seq -> (H, W) bool, for one frame
        self._frame_shape: tuple | None = None  # (H, W) of the last frame received
        self._last_frame: RGBDFrame | None = None
        self._mesh_camera = None  # CameraInfo the mesh was initialised on
        self._logged_kinds: set = set()
        self._rng = np.random.default_rng(0)  # depth segmentation's plane fits, for the size check

    # -- requests --------------------------------------------------------------------------

    def request_initialise(self, mask: np.ndarray | None) -> None:
        """Build a new mesh on the next usable frame, on ``mask`` ((H, W) uint8, non-zero on
        the object) or, if None, on the object found by depth segmentation.
        raises ValueError if the mask's size differs from that of the frames received"""
        if mask is not None and self._frame_shape is not None and mask.shape != self._frame_shape:
            raise ValueError(f"InitialiseRequest.mask: expected shape {self._frame_shape} like the frames, got {mask.shape}")
        self._pending_mask = mask
        self.state = "initialising"
        self.last_error = ""
        log.info("initialising on the next frame (%s)", "mask" if mask is not None else "depth segmentation")

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
                del self._occluders_by_seq[min(self._occluders_by_seq)]  # the oldest frame's mask
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
        """About how many vertices a mesh built with ``config`` would have: ``target_vertices``
        when it chooses the spacing (``spacing_m`` 0); else on the current object if there is
        a mesh, or on everything seen in the last frame received (no object can be larger);
        None before any frame."""
        if config.spacing_m == 0:
            return config.target_vertices
        mesh = self.tracker.mesh
        if mesh is not None:
            return math.ceil(mesh.n_vertices * (mesh.spacing_m / config.spacing_m) ** 2)
        frame = self._last_frame
        if frame is None:
            return None
        return mesh_vertices(seen_area_m2(frame), config.spacing_m)

    def discontinuity(self, reason: str) -> None:
        """The frame stream is not a continuation of the frames tracked so far (``reason``, one line)."""
        self.counters.discontinuities += 1
        if self.auto_init and self.state in ("tracking", "lost"):
            log.info("%s: re-initialising on the next frame", reason)
            self._reinitialise()
        else:
            log.info("%s", reason)

    def _reinitialise(self) -> None:
        self.counters.reinitialisations += 1
        self._pending_mask = None
        self.state = "initialising"
        self.lost_streak = 0

    # -- frames ----------------------------------------------------------------------------

    def handle_frame(self, frame: RGBDFrame) -> MeshEstimate | None:
        """Process one frame according to the state; returns its estimate, or None when the
        frame was not tracked (idle, or rejected: see ``counters.rejected``)."""
        self.counters.frames_taken += 1
        self._frame_shape = frame.depth_m.shape
        self._last_frame = frame
        if self.state == "idle":
            return None
        problem = check_frame(frame)
        if problem is not None:
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
            estimate = self.tracker.initialise(frame, mask=mask)
        except TrackingError as e:
            if mask is not None:
                # A controller's mask will not fit later frames better: wait for a new request.
                self._pending_mask = None
                self.state = "idle"
            return self._reject("init_failed", f"frame {frame.seq}: initialisation failed: {e}")
        self._pending_mask = None
        self._mesh_camera = frame.camera
        self.frames_since_init = 0
        self.lost_streak = 0
        self.last_error = ""
        return self._accept(frame, estimate)

    def _check_object_size(self, frame: RGBDFrame, mask: np.ndarray | None) -> None:
        """Raise TrackingError when the mesh laid over the object (``mask``, or the object
        depth segmentation finds) could exceed the vertex budget, or one of its triangles
        the image, before the tracker spends memory and time on it. Segmenting here and again in the tracker costs one segmentation per
        initialisation."""
        config = self.tracker.config
        if mask is None:
            mask = find_object(frame.depth_m, frame.camera.K, config.segmentation, self._rng)
        elif mask.shape != frame.depth_m.shape:
            raise TrackingError(f"mask: expected shape {frame.depth_m.shape} like the frame, got {mask.shape}")
        mask = mask.astype(bool)
        area_m2 = seen_area_m2(frame, mask)
        # A chosen spacing gives about target_vertices over the object's area, tilted surfaces
        # counting more: at least the spacing for its area as seen facing the camera.
        spacing = config.spacing_m or spacing_for_area(area_m2, config.target_vertices)
        if spacing == 0:
            return  # no pixel of the object has depth: the tracker says so
        edge_px = spacing_px(frame, mask, spacing)
        if edge_px > max(frame.camera.width, frame.camera.height):
            raise TrackingError(f"the object is smaller than one triangle: spacing_m {spacing:g} spans "
                                f"{edge_px:.0f} px at its depth, more than the {frame.camera.width}x{frame.camera.height} image")
        vertices = mesh_vertices(area_m2, spacing)
        if vertices > MAX_MESH_VERTICES:
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


@dataclass(frozen=True)
class ServiceConfig:
    """Endpoints and behaviour of a PerceptionService.

    frames : endpoint of the frame publisher to connect to
    estimates, control : endpoints to bind (``tcp://127.0.0.1:*`` picks free ports)
    auto_init, reinit_after_lost : see PerceptionCore
    stale_after_s : seconds without any message from the frame publisher before it counts
        as gone (at least three of its heartbeat periods)
    heartbeat_period_s : seconds between heartbeats of the estimates publisher
    poll_s : longest wait for a frame before control requests are served again
    viewer : None, "spawn" (start a Rerun viewer) or a path to save a Rerun .rrd recording
    curve : ``ipc.transport.CurveKeys``: the estimates and control sockets are CURVE servers
        and the frame subscription a CURVE client; None: no encryption
    """

    frames: str = endpoints.FRAMES
    estimates: str = endpoints.ESTIMATES
    control: str = endpoints.PERCEPTION_CONTROL
    auto_init: bool = True
    reinit_after_lost: int = 0
    stale_after_s: float = STALE_AFTER_S
    heartbeat_period_s: float = HEARTBEAT_PERIOD_S
    poll_s: float = 0.02
    viewer: str | None = None
    curve: CurveKeys | None = None


class PerceptionService:
    """Sockets and loop of the perception service; see the module docstring.

    tracker_config : TrackerConfig (default: the paper's)
    config : ServiceConfig

    ``run(stop)`` serves until ``stop`` is set; ``step()`` does one round (serve waiting
    control requests, take the newest frame, track it, publish the estimate). After
    construction ``endpoints`` holds the endpoints actually bound or connected.
    Use from one thread; close() (or the context manager) releases the sockets.
    """

    def __init__(self, tracker_config: TrackerConfig | None = None, config: ServiceConfig = ServiceConfig()):
        self.config = config
        self.core = PerceptionCore(tracker_config, auto_init=config.auto_init, reinit_after_lost=config.reinit_after_lost)
        self._started_at = time.monotonic()
        # (latency_ms, tracking_ms) of the recent estimates published
        self._recent: deque = deque(maxlen=RECENT_ESTIMATES)
        # Discontinuities of the frame stream seen by the subscriber's receiver thread (one
        # line each, in order); the loop hands them to the core between frames.
        self._source_events: queue.SimpleQueue = queue.SimpleQueue()
        self._seq_went_back_at = -math.inf  # time.monotonic() of the last frame whose seq went back
        self._viewer = None
        self._closers = []
        try:
            server, client = (config.curve.server, config.curve.client) if config.curve else (None, None)
            self._frames = Subscriber(config.frames, accept=(RGBDFrame,), stale_after_s=config.stale_after_s,
                                      on_liveness=self._on_liveness, on_restart=self._on_restart, curve=client)
            self._closers.append(self._frames.close)
            self._estimates = Publisher(config.estimates, source="perception", heartbeat_period_s=config.heartbeat_period_s,
                                        curve=server)
            self._closers.append(self._estimates.close)
            handlers = {InitialiseRequest: self._on_initialise, ResetRequest: self._on_reset,
                        SetParametersRequest: self._on_set_parameters, OccluderMaskRequest: self._on_occluder_mask,
                        StatusRequest: self._on_status}
            self._control = ReplyServer(config.control, handlers, curve=server)
            self._closers.append(self._control.close)
            if config.viewer is not None:
                self._viewer = RerunViewer(config.viewer)
        except BaseException:
            self.close()
            raise
        self.endpoints = {"frames": config.frames, "estimates": self._estimates.endpoint, "control": self._control.endpoint}
        log.info("perception service: frames from %s, estimates on %s, control on %s, %s%s", config.frames,
                 self.endpoints["estimates"], self.endpoints["control"], self.core.state, ", CURVE" if config.curve else "")

    # -- loop ------------------------------------------------------------------------------

    def run(self, stop: threading.Event) -> None:
        """Serve until ``stop`` is set."""
        while not stop.is_set():
            self.step()

    def step(self) -> MeshEstimate | None:
        """One round; returns the estimate published, if any."""
        while self._control.serve_once(0.0):
            pass
        frame = self._frames.recv_latest(self.config.poll_s)
        # After taking the frame: an event that came before the frame is in the queue by now.
        self._check_source()
        if frame is None:
            return None
        arrived_at = self._frames.taken_arrived_at
        if frame.seq < self.core.last_seq and self.core.state in ("tracking", "lost"):
            self._seq_went_back_at = time.monotonic()
            self.core.discontinuity(f"frame seq went back from {self.core.last_seq} to {frame.seq}")
        estimate = self.core.handle_frame(frame)
        if estimate is not None:
            self._estimates.publish(estimate)
            self._recent.append(((time.monotonic() - arrived_at) * 1000.0, estimate.timing_ms))
        if self._viewer is not None:
            self._viewer.show(frame, estimate)
        return estimate

    # Subscriber callbacks: they run on its receiver thread, so they only queue the event.

    def _on_liveness(self, alive: bool, seconds: float) -> None:
        if alive:
            self._source_events.put(("silence", f"frame source back after {seconds:.1f} s of silence"))

    def _on_restart(self, previous, beat) -> None:
        self._source_events.put(("restart", f"frame source {beat.source!r} restarted "
                                            f"(heartbeat seq {beat.seq} after {previous.seq})"))

    def _check_source(self) -> None:
        """Tell the core of each discontinuity of the frame source: back after a silence, or
        restarted (its heartbeat seq went back or its name changed: a new publisher process).

        A restarted publisher's first frames can arrive before its first heartbeat: their seq
        going back is then the same restart, counted once."""
        while True:
            try:
                kind, reason = self._source_events.get_nowait()
            except queue.Empty:
                return
            if kind == "restart" and time.monotonic() - self._seq_went_back_at < self._frames.stale_limit_s:
                log.info("%s: the discontinuity already seen as seq going back", reason)
                continue
            self.core.discontinuity(reason)

    # -- control ---------------------------------------------------------------------------

    def _on_initialise(self, request: InitialiseRequest) -> StatusReply:
        self.core.request_initialise(request.mask)
        return self.status(request.request_id)

    def _on_reset(self, request: ResetRequest) -> StatusReply:
        self.core.request_reset()
        return self.status(request.request_id)

    def _on_set_parameters(self, request: SetParametersRequest) -> StatusReply:
        self.core.set_parameters(request.parameters)
        return self.status(request.request_id)

    def _on_occluder_mask(self, request: OccluderMaskRequest) -> StatusReply:
        self.core.set_occluder_mask(request.mask, request.seq)
        return self.status(request.request_id)

    def _on_status(self, request: StatusRequest) -> StatusReply:
        return self.status(request.request_id)

    def status(self, request_id: int = 0) -> StatusReply:
        """The StatusReply for ``request_id`` (docs/protocol.md, "StatusReply from the
        perception service"); its message is the last error, if any."""
        core, counters, frames = self.core, self.core.counters, self._frames
        if frames.age_s == math.inf:
            source = "waiting"
        else:
            source = "stale" if frames.stale else "live"
        arrived_at = frames.data_arrived_at
        latency_median = latency_p99 = tracking_median = None
        if self._recent:
            latencies, trackings = np.array(self._recent).T
            latency_median, latency_p99 = np.percentile(latencies, [50, 99])
            tracking_median = np.median(trackings)
        return StatusReply(
            request_id=request_id, state=core.state, frames_processed=core.frames_since_init, last_seq=core.last_seq,
            parameters=core.parameters(), message=" ".join(core.last_error.split()),
            uptime_s=time.monotonic() - self._started_at, source=source,
            frame_age_s=None if arrived_at is None else time.monotonic() - arrived_at,
            frames_received=counters.frames_taken + frames.skipped, frames_tracked=counters.processed,
            frames_dropped=frames.skipped, frames_rejected=sum(counters.rejected.values()),
            rejected_by_kind=counters.rejected, messages_malformed=frames.malformed,
            latency_ms_median=latency_median, latency_ms_p99=latency_p99, tracking_ms_median=tracking_median,
            confidence=core.last_confidence, lost_streak=core.lost_streak,
            reinitialisations=counters.reinitialisations, discontinuities=counters.discontinuities)

    def close(self) -> None:
        """Close the sockets (and the viewer's recording)."""
        for close in reversed(self._closers):
            close()
        self._closers = []
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    def __enter__(self) -> PerceptionService:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class RerunViewer:
    """Live view of the service in Rerun (optional ``rerun-sdk`` >= 0.23, extra "viewer").

    target : "spawn" starts a Rerun viewer window; any other string is a path where the
        recording is saved (.rrd), for machines without a display

    Logged per frame on timeline "frame" (the frame's seq), in the camera's optical frame
    (right, down, forward): ``camera`` (pinhole), ``camera/rgb``, ``camera/depth``
    (metres), ``points`` (the depth image back-projected, every ``POINT_STRIDE``-th pixel,
    coloured) and ``mesh`` (the estimate's triangles).
    """

    POINT_STRIDE = 4  # a 640x480 frame gives ~19k points: enough to judge the fit, light to send

    def __init__(self, target: str = "spawn"):
        try:
            rr = importlib.import_module("rerun")
        except ImportError as e:
            raise RuntimeError(f"the live viewer needs the Python module 'rerun' ({e}); "
                               "install it with: pip install 'clothkit[viewer]'") from None
        self._rr = rr
        rr.init("clothkit perception", spawn=(target == "spawn"))
        if target != "spawn":
            rr.save(target)
        rr.log("/", rr.ViewCoordinates.RDF, static=True)

    def show(self, frame: RGBDFrame, estimate: MeshEstimate | None) -> None:
        """Log ``frame`` and, if given, the estimate tracked on it."""
        rr = self._rr
        cam = frame.camera
        rr.set_time("frame", sequence=frame.seq)
        rr.log("camera", rr.Pinhole(image_from_camera=cam.K, width=cam.width, height=cam.height))
        rr.log("camera/rgb", rr.Image(frame.rgb))
        rr.log("camera/depth", rr.DepthImage(frame.depth_m, meter=1.0))
        s = self.POINT_STRIDE
        depth = frame.depth_m[::s, ::s]
        rows, cols = np.nonzero(np.isfinite(depth) & (depth > 0))
        z = depth[rows, cols].astype(np.float64)
        u, v = cols * s, rows * s
        points = backproject(np.column_stack([u, v]), z, cam.K)
        rr.log("points", rr.Points3D(points, colors=frame.rgb[v, u]))
        if estimate is not None:
            rr.log("mesh", rr.Mesh3D(vertex_positions=estimate.vertices, triangle_indices=estimate.faces))

    def close(self) -> None:
        self._rr.disconnect()
