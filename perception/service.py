"""The perception service: a ``PerceptionCore`` (``perception.service_core``) behind ZeroMQ
sockets (docs/protocol.md, section "Services").

It subscribes to ``RGBDFrame`` on the frames endpoint (newest frame only), tracks, and
publishes one ``MeshEstimate`` per frame processed on the estimates endpoint; on the
control endpoint it answers ``InitialiseRequest``, ``ResetRequest``,
``SetParametersRequest``, ``OccluderMaskRequest`` and ``StatusRequest`` with a
``StatusReply`` (or ``ErrorReply``). Besides the sockets and the loop it measures what
only it can for the ``StatusReply`` (frame arrivals, latency) and tells the core of
discontinuities of the frame stream; malformed messages are dropped by the subscriber
and counted. An optional live viewer is ``perception.viewer.RerunViewer``.
"""

from __future__ import annotations

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
from perception.service_core import PerceptionCore
from perception.tracker import TrackerConfig
from perception.viewer import RerunViewer

log = logging.getLogger(__name__)

#: Frames the service keeps after taking or skipping them, so that an InitialiseRequest can
#: name one by its seq: a third of a second of a 30 Hz camera, the time a controller takes
#: to make a mask of a frame it received (about 20 MB of 640x480 frames).
RECENT_FRAMES = 10

#: Estimates over which StatusReply summarises latency and tracking time: a few seconds
#: at camera rates, so the figures follow a change of load, and enough for a 99th percentile.
RECENT_ESTIMATES = 100


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


def _check_held(seq: int, held: list[int]) -> None:
    """Raise ValueError unless frame ``seq`` is among ``held`` (the seqs of the frames held,
    oldest first) or still to come (newer than every frame held)."""
    if not held or seq > held[-1] or seq in held:
        return
    raise ValueError(f"InitialiseRequest.seq {seq}: not among the last {len(held)} frames received "
                     f"(seq {held[0]} to {held[-1]}); name a frame received within the last {RECENT_FRAMES}, "
                     "or -1 for the next frame")


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
        self._last_received_seq = -1  # seq of the last frame received, processed or not
        self._malformed_told = 0  # malformed frame messages before the last InitialiseRequest or ResetRequest
        # (request_id, seq, hash of the mask) of the last InitialiseRequest carried out on a frame held
        self._initialised_on: tuple | None = None
        self._viewer = None
        self._closers = []
        try:
            server, client = (config.curve.server, config.curve.client) if config.curve else (None, None)
            self._frames = Subscriber(config.frames, accept=(RGBDFrame,), stale_after_s=config.stale_after_s,
                                      on_liveness=self._on_liveness, on_restart=self._on_restart, curve=client,
                                      keep_recent=RECENT_FRAMES)
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
        # Tracking, the stream goes on from the last frame tracked; waiting for the frame an
        # InitialiseRequest names, from the last frame received (none of them was tracked).
        last = self.core.last_seq if self.core.state in ("tracking", "lost") else \
            self._last_received_seq if self.core.initialise_seq >= 0 else -1
        self._last_received_seq = frame.seq
        if frame.seq < last:
            self._seq_went_back_at = time.monotonic()
            self._discontinuity(f"frame seq went back from {last} to {frame.seq}")
        if 0 <= self.core.initialise_seq < frame.seq:
            # The frame to initialise on was skipped for this newer one: build the mesh on
            # it first (if it is still held), then track this frame from there.
            self._initialise_on_held(self.core.initialise_seq)
        estimate = self.core.handle_frame(frame)
        self._publish(frame, estimate, arrived_at)
        return estimate

    def _initialise_on_held(self, seq: int, held: list | None = None) -> bool:
        """Hand the core the frame ``seq`` again, if it is among the frames ``held`` (default:
        those the subscriber holds now); whether it was."""
        held = self._frames.recent() if held is None else held
        earlier = next((f for f in held if f.seq == seq), None)
        if earlier is not None:
            self._publish(earlier, self.core.handle_frame(earlier, again=True))
        return earlier is not None

    def _publish(self, frame: RGBDFrame, estimate: MeshEstimate | None, arrived_at: float | None = None) -> None:
        """Publish ``estimate`` (if any) of ``frame``; its latency counts when ``arrived_at``
        (``time.monotonic()`` of the frame's arrival) is given."""
        if estimate is not None:
            self._estimates.publish(estimate)
            if arrived_at is not None:
                self._recent.append(((time.monotonic() - arrived_at) * 1000.0, estimate.timing_ms))
        if self._viewer is not None:
            self._viewer.show(frame, estimate)

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
            self._discontinuity(reason)

    def _discontinuity(self, reason: str) -> None:
        """Tell the core; the frames held from before cannot be initialised on any more."""
        self._frames.clear_recent()
        self.core.discontinuity(reason)

    # -- control ---------------------------------------------------------------------------

    def _on_initialise(self, request: InitialiseRequest) -> StatusReply:
        key = (request.request_id, request.seq, None if request.mask is None else hash(request.mask.tobytes()))
        if request.seq >= 0 and key == self._initialised_on:
            # A client's resend of a request already carried out (its reply was late): the
            # frame it names may have left the frames held since; nothing to do again.
            return self.status(request.request_id)
        held = self._frames.recent() if request.seq >= 0 else []
        if request.seq >= 0:
            _check_held(request.seq, [f.seq for f in held])
        self.core.request_initialise(request.mask, request.background, request.seq)
        # a frame received already: build the mesh now
        done = request.seq >= 0 and self._initialise_on_held(request.seq, held)
        self._initialised_on = key if done else None
        self._malformed_told = self._frames.malformed
        return self.status(request.request_id)

    def _on_reset(self, request: ResetRequest) -> StatusReply:
        self._initialised_on = None
        self.core.request_reset()
        self._malformed_told = self._frames.malformed
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
            parameters=core.parameters(), message=self._message(),
            uptime_s=time.monotonic() - self._started_at, source=source,
            frame_age_s=None if arrived_at is None else time.monotonic() - arrived_at,
            frames_received=counters.frames_taken + frames.skipped, frames_tracked=counters.processed,
            frames_dropped=frames.skipped, frames_rejected=sum(counters.rejected.values()),
            rejected_by_kind=counters.rejected, messages_malformed=frames.malformed,
            latency_ms_median=latency_median, latency_ms_p99=latency_p99, tracking_ms_median=tracking_median,
            confidence=core.last_confidence, lost_streak=core.lost_streak,
            reinitialisations=counters.reinitialisations, discontinuities=counters.discontinuities)

    def _message(self) -> str:
        """StatusReply.message: the core's last error and, when malformed messages arrived on
        the frames endpoint since the last InitialiseRequest or ResetRequest, why the last was."""
        parts = [" ".join(self.core.last_error.split())]
        if self._frames.malformed > self._malformed_told:
            parts.append(f"last malformed message on the frames endpoint: {self._frames.last_malformed}")
        return "; ".join(p for p in parts if p)

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
