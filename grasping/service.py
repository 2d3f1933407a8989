"""The grasp planner service: the planner of ``grasping`` behind ZeroMQ sockets.

Data flow (docs/protocol.md)::

    perception --MeshEstimate (PUB)--> planner service <--GraspRequest | AdjacentCornersRequest (REQ)-- controller
    frame source --RGBDFrame (PUB)---^  (optional)    --GraspPlanReply | AdjacentCornersReply | ErrorReply-->

Two layers, as the perception service (``PerceptionCore`` and ``PerceptionService``): a
socket-free core, and the sockets around it:

- ``PlannerCore`` holds the newest estimate (and the recent frames, for the
  visibility term) and answers a ``GraspRequest`` with a ``GraspPlanReply`` (best
  first), an ``AdjacentCornersRequest`` with an ``AdjacentCornersReply``, or either
  with an ``ErrorReply``: ``not_ready`` before any estimate has arrived,
  ``invalid`` when the request asks only for kinds this service does not serve, names
  a held vertex off the mesh or its outline, or carries an estimate the planner cannot
  use. It knows nothing of sockets.
- ``run_planner_service`` binds and connects the sockets (``ipc.transport``) and
  drives a ``PlannerCore`` until a stop event is set. Malformed requests are
  answered by ``ReplyServer`` itself and never stop the loop.

Frames: the plans are in the estimate's camera frame; ``GraspPlannerConfig`` holds
``T_world_cam``, used for the workspace box and the up direction only.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections import OrderedDict

from grasping._planner import GraspPlanner, GraspPlannerConfig
from ipc.messages import (
    AdjacentCornersReply,
    AdjacentCornersRequest,
    ErrorReply,
    GraspPlan,
    GraspPlanReply,
    GraspRequest,
    MeshEstimate,
    RGBDFrame,
)

log = logging.getLogger(__name__)

#: The requests the planner's REP socket answers (docs/protocol.md, section 13.4); any other
#: is answered ``unsupported``.
REQUESTS = (GraspRequest, AdjacentCornersRequest)

#: Frames kept to find the one an estimate was made from (the tracker lags the camera
#: by a frame or two; 2 MB each at 640x480).
FRAME_HISTORY = 8


class PlannerCore:
    """Answers grasp requests from the newest estimate; no sockets (see the module docstring).

    config : GraspPlannerConfig; its ``kind`` is ignored, the kinds come from each request
    kinds : kinds this service serves, a subset of ``("corner", "boundary", "highest")``;
        a request's kinds outside it are skipped, and a request with none inside it is
        answered ``invalid``
    max_age_s : a request without its own estimate is answered ``not_ready`` when the
        newest estimate arrived longer ago than this (seconds; the perception service
        stopped or lost the frames); None plans on an estimate of any age

    A request plans on its own ``estimate`` when it carries one, else on the newest
    estimate received (``on_estimate``). The visibility term is used when the frame the
    estimate was made from (same ``seq`` and ``timestamp_s``) was received
    (``on_frame``); otherwise the plan goes without it. Candidates of several kinds are
    merged best first and cut to the request's ``max_candidates``. Adjacent corners are
    answered whatever ``kinds`` holds: they are a request of their own, not a grasp kind.
    """

    def __init__(self, config: GraspPlannerConfig | None = None, kinds=GraspPlan.KINDS, max_age_s: float | None = None):
        config = config if config is not None else GraspPlannerConfig()
        kinds = tuple(kinds)
        if not kinds or len(set(kinds)) != len(kinds) or any(k not in GraspPlan.KINDS for k in kinds):
            raise ValueError(f"Expected kinds: distinct values among {GraspPlan.KINDS}, got {kinds!r}")
        if max_age_s is not None and not (math.isfinite(max_age_s) and max_age_s > 0):
            raise ValueError(f"Expected max_age_s > 0 or None, got {max_age_s}")
        self.kinds = kinds
        self.max_age_s = max_age_s
        # One planner per kind: each caches its analysis of the canonical mesh.
        self._planners = {k: GraspPlanner(dataclasses.replace(config, kind=k)) for k in kinds}
        # Adjacent corners need the canonical outline, which every GraspPlanner analyses:
        # share the corner planner's analysis when there is one.
        self._adjacent = self._planners.get("corner") or GraspPlanner(dataclasses.replace(config, kind="corner"))
        self.latest: MeshEstimate | None = None
        self._latest_at = -math.inf  # time.monotonic() when ``latest`` arrived
        self._frames: OrderedDict = OrderedDict()
        self.requests = 0

    def on_estimate(self, estimate: MeshEstimate) -> None:
        """Keep ``estimate`` as the newest one."""
        self.latest = estimate
        self._latest_at = time.monotonic()

    def on_frame(self, frame: RGBDFrame) -> None:
        """Remember ``frame`` (the last ``FRAME_HISTORY`` frames are kept)."""
        self._frames[(frame.seq, frame.timestamp_s)] = frame
        while len(self._frames) > FRAME_HISTORY:
            self._frames.popitem(last=False)

    def frame_for(self, estimate: MeshEstimate) -> RGBDFrame | None:
        """The received frame ``estimate`` was made from, or None."""
        frame = self._frames.get((estimate.seq, estimate.timestamp_s))
        if frame is not None and frame.camera.frame_id != estimate.frame_id:
            return None
        return frame

    def handle(self, request: GraspRequest | AdjacentCornersRequest):
        """The reply to one request: GraspPlanReply (candidates best first) for a
        GraspRequest, AdjacentCornersReply for an AdjacentCornersRequest, or ErrorReply.

        Raises ValueError (answered ``invalid`` by ``ReplyServer``) for an estimate the
        planner cannot use, or a held vertex off the canonical mesh or its outline.
        """
        self.requests += 1
        if isinstance(request, AdjacentCornersRequest):
            return self._handle_adjacent(request)
        rid = request.request_id
        wanted = tuple(k for k in request.kinds if k in self.kinds)
        if not wanted:
            return ErrorReply("invalid", f"this planner serves {', '.join(self.kinds)} grasps, "
                                         f"not {', '.join(request.kinds)}", rid)
        estimate = self._estimate_for(request)
        if isinstance(estimate, ErrorReply):
            return estimate
        frame = self.frame_for(estimate)
        t0 = time.perf_counter()
        plans = []
        for k in wanted:
            result = self._planners[k].plan(estimate, frame)
            if not result:
                log.info("request %d: no %s grasp on estimate %d: %s", rid, k, estimate.seq, result.reason)
            plans.extend(result.plans)
        # sorted() is stable: equal scores keep the planner's order and the request's kind order.
        plans = sorted(plans, key=lambda p: -p.score)[: request.max_candidates]
        log.info("request %d: %d candidate(s) on estimate %d (%s) in %.1f ms%s", rid, len(plans), estimate.seq,
                 "+".join(wanted), 1000 * (time.perf_counter() - t0), "" if frame is not None else ", no frame")
        return GraspPlanReply(request_id=rid, candidates=tuple(plans), estimate_seq=estimate.seq)

    def _estimate_for(self, request) -> MeshEstimate | ErrorReply:
        """The request's own estimate, else the newest one, else ErrorReply ``not_ready``."""
        if request.estimate is not None:
            return request.estimate
        if self.latest is None:
            return ErrorReply("not_ready", "no mesh estimate received yet; retry later", request.request_id)
        age = time.monotonic() - self._latest_at
        if self.max_age_s is not None and age > self.max_age_s:
            return ErrorReply("not_ready", f"the newest mesh estimate arrived {age:.1f} s ago, over the "
                                           f"{self.max_age_s:g} s limit; retry later", request.request_id)
        return self.latest

    def _handle_adjacent(self, request: AdjacentCornersRequest):
        rid = request.request_id
        estimate = self._estimate_for(request)
        if isinstance(estimate, ErrorReply):
            return estimate
        frame = self.frame_for(estimate)
        t0 = time.perf_counter()
        result = self._adjacent.adjacent_corners(estimate, request.held_vertex, frame, request.max_candidates,
                                                 request.even_if_lost)
        log.info("request %d: %d corner(s) adjacent to vertex %d on estimate %d in %.1f ms%s%s", rid,
                 len(result.candidates), request.held_vertex, estimate.seq, 1000 * (time.perf_counter() - t0),
                 "" if frame is not None else ", no frame", f": {result.reason}" if not result else "")
        return AdjacentCornersReply(request_id=rid, estimate_seq=estimate.seq, held_vertex=request.held_vertex,
                                    held_outline_vertex=result.held_outline_vertex, candidates=result.candidates)


def run_planner_service(
    core: PlannerCore,
    *,
    estimates_endpoint: str,
    planner_endpoint: str,
    frames_endpoint: str | None = None,
    stop: threading.Event | None = None,
    poll_s: float = 0.02,
    on_bound=None,
    curve=None,
) -> None:
    """Serve ``core`` on ZeroMQ until ``stop`` is set.

    estimates_endpoint : the perception service's MeshEstimate publisher to connect to
    planner_endpoint : where to bind the REP socket, e.g. ``ipc.endpoints.PLANNER`` or
        ``tcp://127.0.0.1:*`` for a free port
    frames_endpoint : a frame publisher to connect to for the visibility term, or None
    stop : threading.Event; the loop checks it every ``poll_s`` seconds
    on_bound : called with the planner endpoint actually bound, once serving
    curve : ``ipc.transport.CurveKeys``: the REP socket is a CURVE server, the subscriptions
        CURVE clients; None: no encryption

    Raises ValueError (one line) when an endpoint cannot be bound or connected.
    """
    from ipc.transport import ReplyServer, Subscriber  # zmq only where sockets are made

    stop = stop if stop is not None else threading.Event()
    server, client = (curve.server, curve.client) if curve is not None else (None, None)
    frames = None
    with Subscriber(estimates_endpoint, accept=(MeshEstimate,), curve=client) as estimates:
        try:
            if frames_endpoint is not None:
                frames = Subscriber(frames_endpoint, accept=(RGBDFrame,), curve=client)

            def drain() -> None:
                # Take what arrived before answering, so a request sees the newest estimate.
                if frames is not None:
                    frame = frames.recv_latest(timeout_s=0)
                    if frame is not None:
                        core.on_frame(frame)
                estimate = estimates.recv_latest(timeout_s=0)
                if estimate is not None:
                    core.on_estimate(estimate)

            def handle(request: GraspRequest | AdjacentCornersRequest):
                drain()
                return core.handle(request)

            with ReplyServer(planner_endpoint, dict.fromkeys(REQUESTS, handle), curve=server) as replies:
                log.info("planner service: estimates from %s, %sserving %s grasps and adjacent corners on %s%s",
                         estimates_endpoint, f"frames from {frames_endpoint}, " if frames_endpoint else "",
                         "/".join(core.kinds), replies.endpoint, ", CURVE" if curve is not None else "")
                if on_bound is not None:
                    on_bound(replies.endpoint)
                while not stop.is_set():
                    drain()
                    replies.serve_once(timeout_s=poll_s)
        finally:
            if frames is not None:
                frames.close()
    log.info("planner service stopped after %d request(s)", core.requests)
