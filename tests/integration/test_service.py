"""The perception service in this process, on loopback with free ports: control requests,
bad input, and the state machine's re-initialisation rules.

Frames are a rendered textured sheet (tests.render) moving forth and back, so its true
surface is known in every frame. Every wait has a timeout; every test stops what it starts.
"""

import dataclasses
import math
import re
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from ipc.codec import encode
from ipc.examples import example_messages
from ipc.messages import (
    CameraInfo,
    Heartbeat,
    InitialiseRequest,
    MeshEstimate,
    ResetRequest,
    RGBDFrame,
    SetParametersRequest,
    StatusReply,
    StatusRequest,
)
from ipc.transport import Publisher, RemoteError, RequestClient, Subscriber
from perception import TrackerConfig
from perception.parameters import MAX_MESH_VERTICES, MAX_VERTEX_STEPS, PARAMETER_RANGES, apply_parameters
from perception.service import PerceptionService, ServiceConfig
from perception.service_core import PerceptionCore
from perception.sources import FrameSource, Pacing, publish_frames
from perception.tracker import config_with
from perception.viewer import RerunViewer
from tests.render import frame_of, grid_surface, plane_points, texture

pytestmark = pytest.mark.timeout(120)

ANY = "tcp://127.0.0.1:*"
CAM = CameraInfo.from_fov(320, 240, np.deg2rad(45))
SIZE = (0.6, 0.45)
CENTRE = np.array([0.0, 0.0, 1.3])
STEP = np.array([0.008, -0.004, 0.01])  # metres per frame
N = 12  # frames of one forth-and-back cycle: frame N is frame 0 again, so a loop is smooth


def shift(k):
    k = k % N
    return STEP * (k if k <= N // 2 else N - k)


def near_surface(estimate, seq=None):
    """Median and largest distance (m) of the vertices from the true sheet of frame ``seq``,
    and whether all lie over the sheet's rectangle (within 3 cm)."""
    centre = CENTRE + shift(estimate.seq if seq is None else seq)
    v = estimate.vertices - centre
    dz = np.abs(v[:, 2])
    inside = np.all(np.abs(v[:, :2]) <= np.array(SIZE) / 2 + 0.03)
    return float(np.median(dz)), float(dz.max()), bool(inside)


@pytest.fixture(scope="module")
def frames():
    uv, faces = grid_surface(*SIZE, 31, 24)
    tex = texture(np.random.default_rng(7))
    return [frame_of(plane_points(uv, CENTRE + shift(k), SIZE), uv, faces, tex, CAM, SIZE, t=k / 10, seq=k,
                     noise_m=0.001, rng=np.random.default_rng(k)) for k in range(N)]


def wait_until(predicate, timeout_s, poll_s=0.02):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


def documented_reject_kinds():
    """The kinds of the perception service's table of rejected frames in docs/protocol.md."""
    doc = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
    table = doc[doc.index("| kind | cause |"):doc.index("`messages_malformed`, each")]
    return re.findall(r"^\| `(\w+)` \|", table, flags=re.M)


def assert_frames_add_up(reply: StatusReply, idle_frames_possible: bool) -> None:
    """Every frame received was tracked, dropped, rejected or (only while idle) counted."""
    accounted = reply.frames_tracked + reply.frames_dropped + reply.frames_rejected
    if idle_frames_possible:
        assert reply.frames_received >= accounted, reply
    else:
        assert reply.frames_received == accounted, reply
    assert sum(reply.rejected_by_kind.values()) == reply.frames_rejected


class ListSource(FrameSource):
    name = "test frames"

    def __init__(self, frames):
        self._frames = frames

    def frames(self):
        yield from self._frames


class Running:
    """A PerceptionService thread, optionally a frame publisher thread looping ``frames``,
    a subscriber to its estimates and a control client."""

    def __init__(self, frames=None, frames_endpoint=None, **config):
        self.stop = threading.Event()
        self.threads = []
        self.publisher = None
        if frames is not None:
            self.publisher = Publisher(ANY, source="test frames", heartbeat_period_s=0.2)
            frames_endpoint = self.publisher.endpoint
            self._start(publish_frames, ListSource(frames), self.publisher.publish, pacing=Pacing("rate", 15.0),
                        loop=True, stop=self.stop)
        self.service = PerceptionService(TrackerConfig.realtime(), ServiceConfig(
            frames=frames_endpoint, estimates=ANY, control=ANY, **config))
        self._start(self.service.run, self.stop)
        self.estimates = Subscriber(self.service.endpoints["estimates"], accept=(MeshEstimate,))
        self.control = RequestClient(self.service.endpoints["control"], timeout_s=5.0, attempts=1)

    def _start(self, target, *args, **kw):
        t = threading.Thread(target=target, args=args, kwargs=kw, daemon=True)
        t.start()
        self.threads.append(t)

    def status(self, request_id=0):
        return self.control.request(StatusRequest(request_id=request_id))

    def next_estimate(self, timeout_s=20.0):
        got = self.estimates.recv_latest(timeout_s=timeout_s)
        assert got is not None, f"no estimate within {timeout_s} s; status: {self.status().message}"
        return got

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop.set()
        for t in self.threads:
            t.join(timeout=10)
        self.estimates.close()
        self.control.close()
        self.service.close()
        if self.publisher is not None:
            self.publisher.close()


def test_control_requests_round_trip(frames):
    with Running(frames, auto_init=False) as run:
        reply = run.status(request_id=11)
        assert reply.request_id == 11 and reply.state == "idle" and reply.last_seq == -1
        assert reply.parameters["lambda_d"] == 0.6 and reply.parameters["features"] == "klt"
        assert "outlier_radii_m" not in reply.parameters  # a tuple: not settable over the wire
        assert wait_until(lambda: run.status().frames_received >= 3, 10.0)
        assert run.estimates.recv_latest(timeout_s=0.3) is None  # idle: frames counted, not tracked
        idle = run.status()
        assert idle.frames_tracked == 0 and idle.source == "live" and idle.frame_age_s >= 0
        # Nothing tracked, so nothing measured: nil on the wire, not NaN or 0.
        assert (idle.latency_ms_median, idle.latency_ms_p99, idle.tracking_ms_median, idle.confidence) == (None,) * 4
        assert idle.uptime_s > 0 and idle.message == ""
        assert_frames_add_up(idle, idle_frames_possible=True)

        with pytest.raises(RemoteError, match=r"InitialiseRequest.mask: expected shape \(240, 320\)") as e:
            run.control.request(InitialiseRequest(request_id=2, mask=np.ones((10, 10), np.uint8)))
        assert e.value.code == "invalid" and e.value.reply.request_id == 2
        # The mask applies to the next frame, which may be any of the cycle: where the sheet is in all.
        mask = np.all([f.depth_m < 2.0 for f in frames], axis=0)  # the wall behind is at 2.5 m
        reply = run.control.request(InitialiseRequest(request_id=3, mask=mask))
        assert reply.state == "initialising" and reply.request_id == 3
        est = run.next_estimate()
        med, _, inside = near_surface(est)
        assert med < 0.006 and inside, (med, inside)
        assert wait_until(lambda: run.status().state == "tracking" and run.status().frames_processed >= 3, 10.0)
        n_vertices = len(est.vertices)
        tracking = run.status()
        assert tracking.frames_tracked >= tracking.frames_processed >= 3
        assert tracking.frames_received > idle.frames_received
        assert_frames_add_up(tracking, idle_frames_possible=True)
        # Each latency spans its frame's tracking, so the median latency is at least the median tracking time.
        assert 0 < tracking.tracking_ms_median <= tracking.latency_ms_median <= tracking.latency_ms_p99
        assert 0 <= tracking.confidence <= 1 and tracking.uptime_s > idle.uptime_s

        reply = run.control.request(SetParametersRequest(request_id=4, parameters={"lambda_d": 0.5, "max_iterations": 4}))
        assert reply.parameters["lambda_d"] == 0.5 and reply.parameters["max_iterations"] == 4
        for params, message in (({"lambda_x": 1.0}, "unknown tracker parameter.*lambda_x"),
                                ({"max_iterations": "ten"}, "'max_iterations': expected int, got str"),
                                ({"alpha": -1.0}, r"'alpha': expected a value in \[0.001, 1000\], got -1.0"),
                                ({"lambda_d": 1e300}, r"'lambda_d': expected a value in \[0, 100\], got 1e\+300"),
                                ({"spacing_m": 0.002}, r"'spacing_m': expected a value in 0 or \[0.005, 1\], got 0.002"),
                                ({"solver": "newton"}, "solver method"),
                                ({"segmentation": "on"}, "'segmentation' cannot be set over the wire")):
            with pytest.raises(RemoteError, match=message) as e:
                run.control.request(SetParametersRequest(parameters=params))
            assert e.value.code == "invalid"
        after = run.status()
        assert after.parameters["lambda_d"] == 0.5 and after.parameters["alpha"] == 0.5  # refused requests change nothing
        assert after.parameters["solver"] == "conjugate"
        est = run.next_estimate()
        assert len(est.vertices) == n_vertices and near_surface(est)[0] < 0.006  # still tracking with the new weights

        # An empty mask cannot be built in Python; sent anyway, the service refuses it as a protocol error.
        empty = InitialiseRequest(request_id=5)
        object.__setattr__(empty, "mask", np.zeros((240, 320), np.uint8))
        with pytest.raises(RemoteError, match="no non-zero pixel") as e:
            run.control.request(empty)
        assert e.value.code == "protocol"

        assert run.control.request(ResetRequest(request_id=6)).state == "idle"
        run.estimates.recv_latest(timeout_s=0.3)  # one that was on its way
        assert run.estimates.recv_latest(timeout_s=0.5) is None
        assert run.status().state == "idle" and run.status().frames_processed == 0


def test_bad_frames_are_counted_and_tracking_goes_on(frames):
    ctx = zmq.Context.instance()
    raw = ctx.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")
    try:
        with Running(frames_endpoint=f"tcp://127.0.0.1:{port}", stale_after_s=30.0) as run:
            first = None
            deadline = time.monotonic() + 20
            while first is None and time.monotonic() < deadline:  # the subscription takes a moment to arrive
                raw.send_multipart(encode(frames[0]))
                first = run.estimates.recv_latest(timeout_s=0.2)
            assert first is not None and first.seq == 0
            while run.estimates.recv_latest(timeout_s=0.5) is not None:
                pass  # estimates of copies of frame 0 still on their way

            def send_and_count(message_frames, count):
                before = count(run.status())
                raw.send_multipart(message_frames)
                assert wait_until(lambda: count(run.status()) == before + 1, 10.0), run.status()

            good = run.status()
            assert (good.frames_rejected, good.rejected_by_kind, good.messages_malformed, good.message) == (0, {}, 0, "")
            small = CameraInfo.from_fov(160, 120, np.deg2rad(45))
            send_and_count(encode(RGBDFrame(np.zeros((120, 160, 3), np.uint8), np.full((120, 160), 1.3, np.float32),
                                            small, 0.1, 1)), lambda r: r.frames_rejected)
            nan_depth = dataclasses.replace(frames[1], depth_m=np.full((240, 320), np.nan, np.float32), seq=2)
            send_and_count(encode(nan_depth), lambda r: r.rejected_by_kind.get("no_depth", 0))
            send_and_count([b"\x93 not a message"], lambda r: r.messages_malformed)
            bad = run.status()
            assert bad.message.startswith("frame 2: no valid depth pixel") and bad.frames_rejected == 2
            assert "; last malformed message on the frames endpoint: header: not valid msgpack" in bad.message
            assert bad.rejected_by_kind == {"camera_changed": 1, "no_depth": 1}
            assert set(bad.rejected_by_kind) <= set(documented_reject_kinds())
            assert bad.frames_tracked == good.frames_tracked and bad.frames_received == good.frames_received + 2

            got = []
            for k in range(1, 6):
                raw.send_multipart(encode(dataclasses.replace(frames[k], seq=10 + k)))
                est = run.next_estimate(timeout_s=10.0)
                got.append(est)
                assert len(est.vertices) == len(first.vertices)
                med, _, inside = near_surface(est, seq=k)
                assert med < 0.006 and inside, (k, med)
            assert [e.seq for e in got] == [11, 12, 13, 14, 15]
            reply = run.status()
            # Frame 0 was sent until the service's subscription had arrived: it may have tracked copies.
            assert reply.state == "tracking" and reply.last_seq == 15 and reply.frames_processed >= 6
            assert reply.frames_tracked == reply.frames_processed and reply.confidence == got[-1].confidence
            assert_frames_add_up(reply, idle_frames_possible=False)  # auto_init: never idle
            assert 0 < reply.tracking_ms_median <= reply.latency_ms_median <= reply.latency_ms_p99
    finally:
        raw.close()


def test_a_source_restarted_after_a_silence_is_one_discontinuity(frames):
    """A restarted frame publisher whose first frames arrive before its first heartbeat is
    one discontinuity: one re-initialisation, not a second one when that heartbeat (seq back
    to 0) comes. Raw sockets fix the order of what arrives."""
    ctx = zmq.Context.instance()
    raw = ctx.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")

    def beat(seq):
        return encode(Heartbeat(source="camera", seq=seq, period_s=0.1))

    try:
        with Running(frames_endpoint=f"tcp://127.0.0.1:{port}", stale_after_s=0.5) as run:
            for k in range(40):  # the first publisher: heartbeats up to seq 39 among its frames
                raw.send_multipart(beat(k))
                raw.send_multipart(encode(dataclasses.replace(frames[k % N], seq=k)))
                time.sleep(0.05)
            assert wait_until(lambda: run.status().state == "tracking", 10.0), run.status()
            assert wait_until(lambda: run.status().source == "stale", 5.0)  # it went silent
            before = run.status()
            assert (before.discontinuities, before.reinitialisations) == (0, 0)
            for k in range(20):  # the restarted publisher: frames first, heartbeats from seq 0 later
                if k >= 10:
                    raw.send_multipart(beat(k - 10))
                raw.send_multipart(encode(dataclasses.replace(frames[k % N], seq=k)))
                time.sleep(0.05)
            after = wait_until_status(run, lambda r: r.source == "live" and r.last_seq == 19, 10.0)
            assert (after.discontinuities, after.reinitialisations) == (1, 1), after
            assert after.state == "tracking" and after.frames_processed >= 10
    finally:
        raw.close()


def wait_until_status(run, predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while True:
        reply = run.status()
        if predicate(reply) or time.monotonic() > deadline:
            return reply
        time.sleep(0.05)


# -- the state machine, without sockets ----------------------------------------------------


def test_documented_parameters_exist():
    doc = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
    row = next(line for line in doc.splitlines() if line.startswith("| `parameters` | every tracker parameter"))
    named = {n for n in re.findall(r"`(\w+)`", row) if n != "parameters" and n.islower()}
    assert len(named) >= 10 and named <= set(PerceptionCore().parameters()), named


def test_documented_ranges_and_budgets_are_the_services():
    doc = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
    table = doc[doc.index("#### Parameters"):doc.index("Two budgets keep")]
    documented = {}
    for names, allowed in re.findall(r"((?:`\w+`(?:, )?)+) \| ((?:0 or )?[\[(][-\d., ]+\])", table):
        for name in re.findall(r"`(\w+)`", names):
            documented[name] = allowed
    assert documented == {name: str(allowed) for name, allowed in PARAMETER_RANGES.items()}
    numeric = {name for name, value in PerceptionCore().parameters().items()
               if isinstance(value, (int, float)) and not isinstance(value, bool)}
    assert set(PARAMETER_RANGES) == numeric  # a new numerical tracker parameter needs a range
    budgets = doc[doc.index("Two budgets keep"):doc.index("#### StatusReply from the perception service")]
    assert f"at most {MAX_MESH_VERTICES:,}" in budgets and f"at most {MAX_VERTEX_STEPS:,}" in budgets


def test_the_example_parameters_are_accepted_by_the_service():
    examples = example_messages()
    core = PerceptionCore()
    core.set_parameters(examples[SetParametersRequest].parameters)
    assert set(examples[StatusReply].parameters) <= set(core.parameters())


def test_parameters_out_of_range_or_over_budget_are_refused_and_change_nothing(frames):
    core = PerceptionCore(TrackerConfig.realtime())
    before = core.parameters()
    with pytest.raises(ValueError, match=r"'spacing_m': expected a value in 0 or \[0.005, 1\], got 0.004"):
        core.set_parameters({"spacing_m": 0.004})
    with pytest.raises(ValueError, match=r"'target_vertices': expected a value in \[3, 5000\], got 6000"):
        core.set_parameters({"target_vertices": 6000})
    core.handle_frame(frames[0])
    mesh = core.tracker.mesh
    n, spacing = mesh.n_vertices, mesh.spacing_m  # the spacing the tracker chose for about target_vertices
    assert core.expected_vertices(config_with(core.tracker.config, spacing_m=spacing)) == n
    # A finer spacing gives more vertices by the square of the ratio: the object's size decides.
    finer = spacing * math.sqrt(n / 6000)
    with pytest.raises(ValueError, match=r"'spacing_m': .* over the budget of 5000; expected a spacing of at least"):
        core.set_parameters({"spacing_m": finer, "lambda_d": 0.3})
    with pytest.raises(ValueError, match=r"'max_iterations', 'init_iterations' and 'cg_iterations'"):
        core.set_parameters({"target_vertices": 5000, "max_iterations": 100, "cg_iterations": 100})
    for params, message in (({"lambda_d": 1e300}, r"'lambda_d': expected a value in \[0, 100\]"),
                            ({"max_features": 10**6}, r"'max_features': expected a value in \[1, 2000\]"),
                            ({"tolerance_m": 0.0}, r"'tolerance_m': expected a value in \(0, 1\]"),
                            ({"lost_confidence": 1.5}, r"'lost_confidence': expected a value in \[0, 1\]")):
        with pytest.raises(ValueError, match=message):
            core.set_parameters(params)
    assert core.parameters() == before  # every refused request left the old values in force
    coarser = spacing * math.sqrt(n / 4000)
    core.set_parameters({"spacing_m": coarser, "max_iterations": 20})
    assert core.parameters()["spacing_m"] == coarser and core.parameters()["max_iterations"] == 20


def test_without_a_mesh_the_last_frame_bounds_the_spacing(frames):
    core = PerceptionCore(TrackerConfig.realtime(spacing_m=0.03), auto_init=False)
    core.handle_frame(frames[0])  # idle: seen, not tracked; everything visible could be the object
    seen = core.expected_vertices(core.tracker.config)
    # The wall behind the sheet fills the image: far more than the sheet's own vertices.
    assert seen > 2 * 331
    with pytest.raises(ValueError, match="'spacing_m'"):
        core.set_parameters({"spacing_m": 0.03 * math.sqrt(seen / 6000)})
    core.set_parameters({"spacing_m": 0.0})  # the tracker chooses it for target_vertices


def test_apply_parameters_is_all_or_nothing():
    cfg = TrackerConfig()
    new = apply_parameters(cfg, {"lambda_c": 2, "use_depth": False, "features": "orb"})
    assert (new.lambda_c, new.use_depth, new.features) == (2.0, False, "orb") and isinstance(new.lambda_c, float)
    with pytest.raises(ValueError, match="unknown tracker parameter.*: nope"):
        apply_parameters(cfg, {"lambda_c": 2.0, "nope": 1})
    with pytest.raises(ValueError, match="'use_depth': expected bool, got int"):
        apply_parameters(cfg, {"use_depth": 1})


def test_lost_frames_reinitialise_after_n_and_discontinuities_follow_auto_init(frames):
    core = PerceptionCore(TrackerConfig.realtime(), reinit_after_lost=2)
    assert core.state == "initialising"
    assert core.handle_frame(frames[0]) is not None and core.state == "tracking"
    empty = dataclasses.replace(frames[1], depth_m=np.full((240, 320), 2.5, np.float32))  # the sheet is gone
    assert core.handle_frame(empty).lost and core.state == "lost"
    assert core.handle_frame(empty).lost and core.state == "initialising"  # second lost frame: re-initialise
    assert core.counters.reinitialisations == 1
    est = core.handle_frame(frames[2])
    assert core.state == "tracking" and core.frames_since_init == 1 and near_surface(est, seq=2)[0] < 0.006
    core.discontinuity("test")
    assert core.state == "initialising" and core.counters.reinitialisations == 2

    manual = PerceptionCore(TrackerConfig.realtime(), auto_init=False, reinit_after_lost=1)
    assert manual.state == "idle" and manual.handle_frame(frames[0]) is None
    manual.request_initialise(None)
    manual.handle_frame(frames[0])
    manual.handle_frame(empty)
    manual.discontinuity("test")
    assert manual.state == "lost"  # without auto_init the service never re-initialises by itself
    with pytest.raises(ValueError, match="reinit_after_lost"):
        PerceptionCore(reinit_after_lost=-1)


def test_a_failed_mask_initialisation_goes_idle_and_says_why(frames):
    core = PerceptionCore(TrackerConfig.realtime(), auto_init=False)
    tiny = np.zeros((240, 320), np.uint8)
    tiny[0, 0] = 1  # a single pixel: too small to carry a mesh
    core.request_initialise(tiny)
    assert core.handle_frame(frames[0]) is None
    assert core.state == "idle" and core.counters.rejected == {"init_failed": 1}
    assert core.last_error.startswith("frame 0: initialisation failed:")


def test_a_background_holds_for_the_service_s_own_re_initialisations_until_a_reset(frames):
    core = PerceptionCore(TrackerConfig.realtime(), auto_init=False, reinit_after_lost=1)
    core.handle_frame(frames[0])  # the service now knows the frames' size
    with pytest.raises(ValueError, match="InitialiseRequest.background: expected shape"):
        core.request_initialise(None, dataclasses.replace(frames[0], rgb=frames[0].rgb[:10, :10],
                                                          depth_m=frames[0].depth_m[:10, :10],
                                                          camera=CameraInfo.from_fov(10, 10, 1.0)))
    wall = dataclasses.replace(frames[0], rgb=np.full_like(frames[0].rgb, 90),
                               depth_m=np.full((240, 320), 2.5, np.float32))  # the grey wall alone
    core.request_initialise(None, wall)
    assert near_surface(core.handle_frame(frames[1]), seq=1)[0] < 0.006
    assert core.tracker.last_observation.mask.sum() > 1000
    core._reinitialise()  # as after a lost streak: the service builds a mesh by itself
    core.handle_frame(frames[2])
    assert core.tracker._background_given is wall
    core.request_reset()
    core.request_initialise(None)
    core.handle_frame(frames[3])
    assert core.tracker._background_given is None


def test_viewer_records_frames_and_meshes(frames, tmp_path):
    pytest.importorskip("rerun", reason="the viewer extra (rerun-sdk, 170 MB) is not among the test dependencies")
    core = PerceptionCore(TrackerConfig.realtime())
    est = core.handle_frame(frames[0])
    viewer = RerunViewer(str(tmp_path / "view.rrd"))
    viewer.show(frames[0], est)
    viewer.show(frames[1], None)
    viewer.close()
    assert (tmp_path / "view.rrd").stat().st_size > 10_000  # images, points and the mesh


def test_viewer_without_its_extra_names_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)
    with pytest.raises(RuntimeError, match=r"live viewer needs the Python module 'rerun'.*pip install -e '\.\[viewer\]'"):
        RerunViewer()


def test_occluder_masks_reach_the_tracker_combined_and_only_for_their_frame(frames):
    core = PerceptionCore(TrackerConfig.realtime())
    seen = []
    real_track = core.tracker.track
    core.tracker.track = lambda frame: seen.append(frame.occluder_mask) or real_track(frame)
    h, w = frames[0].depth_m.shape
    left, top = np.zeros((h, w), np.uint8), np.zeros((h, w), bool)
    left[:, :10] = 1
    top[:5] = True
    with pytest.raises(ValueError, match=r"OccluderMaskRequest.mask: expected shape \(240, 320\)"):
        core.handle_frame(frames[0])  # initialises, and fixes the frame size
        core.set_occluder_mask(np.ones((10, 10), np.uint8), seq=3)
    core.set_occluder_mask(left)  # standing
    core.set_occluder_mask(top, seq=2)
    core.set_occluder_mask(top, seq=7)  # never arrives: dropped once a later frame passed
    own = np.zeros((h, w), bool)
    own[-1] = True
    for seq in (1, 2, 3):
        frame = dataclasses.replace(frames[seq], seq=seq, occluder_mask=own if seq == 3 else None)
        assert core.handle_frame(frame) is not None
    assert np.array_equal(seen[0], left > 0)
    assert np.array_equal(seen[1], (left > 0) | top)
    assert np.array_equal(seen[2], (left > 0) | own)
    core.set_occluder_mask(None)  # clears the standing mask
    core.handle_frame(dataclasses.replace(frames[4], seq=8))
    assert seen[3] is None  # seq 7's mask was dropped when frame 8 came


def test_an_initialise_request_builds_the_mesh_on_the_frame_it_names(frames):
    with Running(frames, auto_init=False) as run:
        assert wait_until(lambda: run.status().frames_received >= 4, 10.0)
        named = run.service._frames.recent()[-1].seq  # a frame the service received, as a controller knows it
        reply = run.control.request(InitialiseRequest(request_id=8, mask=frames[named % N].depth_m < 2.0, seq=named))
        assert (reply.request_id, reply.state, reply.last_seq, reply.frames_processed) == (8, "tracking", named, 1)
        # Sent again (a client whose reply came late resends it), it is not carried out again.
        mesh = run.service.core.tracker.mesh
        again = run.control.request(InitialiseRequest(request_id=8, mask=frames[named % N].depth_m < 2.0, seq=named))
        assert again.state == "tracking" and run.service.core.tracker.mesh is mesh
        est = run.next_estimate()
        med, _, inside = near_surface(est)
        assert est.seq >= named and med < 0.006 and inside, (est.seq, med, inside)

        assert wait_until(lambda: run.status().frames_received > 14, 10.0)
        with pytest.raises(RemoteError, match=r"InitialiseRequest.seq 0: not among the last 10 frames received "
                                              r"\(seq \d+ to \d+\)") as e:
            run.control.request(InitialiseRequest(request_id=9, mask=frames[0].depth_m < 2.0, seq=0))
        assert e.value.code == "invalid" and run.status().state == "tracking"  # refused: nothing changed

        ahead = run.service._frames.recent()[-1].seq + 8  # a frame still to come
        reply = run.control.request(InitialiseRequest(mask=frames[ahead % N].depth_m < 2.0, seq=ahead))
        assert reply.state == "initialising"
        with Subscriber(run.service.endpoints["estimates"], accept=(MeshEstimate,), keep_recent=5) as watch:
            assert wait_until(lambda: len(watch.recent()) + (watch.recv_latest(0.0) is not None) >= 2, 20.0)
            first = watch.recent()[0]
        assert first.seq == ahead and near_surface(first)[0] < 0.006  # no frame before it was tracked


def test_a_frame_named_to_initialise_on_that_never_comes_leaves_the_service_idle_saying_why(frames):
    core = PerceptionCore(TrackerConfig.realtime(), auto_init=False)
    core.handle_frame(frames[0])
    core.request_initialise(frames[3].depth_m < 2.0, seq=3)
    assert core.handle_frame(frames[2]) is None and core.state == "initialising"  # before it: waits
    assert core.handle_frame(frames[4]) is None and core.state == "idle"  # 3 was missed
    assert core.counters.rejected == {"init_failed": 1}
    assert core.last_error == ("frame 3 to initialise on was not received (frame 4 came first): "
                               "send a new InitialiseRequest")
    core.request_initialise(frames[3].depth_m < 2.0, seq=3)
    est = core.handle_frame(frames[3], again=True)  # held by the caller since it came
    assert est.seq == 3 and near_surface(est)[0] < 0.006 and core.state == "tracking"
    assert core.counters.frames_taken == 3  # a frame handed in again is not taken twice
    core.request_initialise(None, seq=9)
    core.discontinuity("frame source restarted")
    assert core.state == "idle" and core.last_error.startswith("frame source restarted before frame 9")
    # With automatic initialisation the service builds a mesh by itself instead, as after any discontinuity.
    auto = PerceptionCore(TrackerConfig.realtime())
    auto.handle_frame(frames[0])
    auto.request_initialise(frames[5].depth_m < 2.0, seq=5)
    auto.discontinuity("frame source restarted")
    assert auto.state == "initialising" and auto.initialise_seq == -1 and auto.counters.reinitialisations == 1
    # A frame named that is unusable: without a mask the next frames are tried, a mask goes idle.
    no_depth = dataclasses.replace(frames[2], depth_m=np.zeros_like(frames[2].depth_m))
    auto.request_initialise(None, seq=2)
    assert auto.handle_frame(no_depth) is None and auto.state == "initialising"
    assert auto.handle_frame(frames[3]).seq == 3 and auto.state == "tracking"
    auto.request_initialise(frames[2].depth_m < 2.0, seq=2)
    assert auto.handle_frame(no_depth) is None and auto.state == "idle"
    assert auto.last_error.endswith("the mask cannot be used: send a new InitialiseRequest")


def test_a_frame_counter_going_back_while_an_initialise_request_waits_is_a_discontinuity(frames):
    with Publisher(ANY, source="test frames", heartbeat_period_s=0.2) as pub, \
            Running(frames_endpoint=pub.endpoint, auto_init=False) as run:
        def send(seq):
            pub.publish(dataclasses.replace(frames[seq % N], seq=seq))

        assert wait_until(lambda: send(5) or run.status().frames_received >= 1, 10.0)
        send(6)
        assert wait_until(lambda: run.status().last_seq == -1 and run.status().frames_received >= 2, 10.0)
        ahead = run.control.request(InitialiseRequest(mask=frames[20 % N].depth_m < 2.0, seq=20))
        assert ahead.state == "initialising"
        send(1)  # the source restarted its counter only: frame 20 of the old stream will never come
        assert wait_until(lambda: run.status().discontinuities == 1, 10.0)
        after = run.status()
        assert after.state == "idle" and "frame seq went back from 6 to 1" in after.message, after
        send(20)  # the restarted stream's frame 20 is another frame: the old request is not carried out on it
        assert wait_until(lambda: run.status().frames_received >= 4, 10.0)
        assert run.status().state == "idle" and run.status().frames_tracked == 0


def test_occluder_masks_waiting_are_capped_by_refusing_the_next_and_a_misfit_standing_mask_is_dropped(frames):
    from perception.service_core import MAX_PENDING_OCCLUDERS

    core = PerceptionCore(TrackerConfig.realtime())
    h, w = frames[0].depth_m.shape
    core.set_occluder_mask(np.ones((10, 10), np.uint8))  # before any frame: its size cannot be checked yet
    for seq in range(100, 100 + MAX_PENDING_OCCLUDERS):
        core.set_occluder_mask(np.ones((h, w), np.uint8), seq=seq)
    with pytest.raises(ValueError, match=rf"OccluderMaskRequest.seq 500: {MAX_PENDING_OCCLUDERS} frames' masks are "
                                         rf"waiting already \(frames 100 to {99 + MAX_PENDING_OCCLUDERS}\)"):
        core.set_occluder_mask(np.ones((h, w), np.uint8), seq=500)
    assert sorted(core._occluders_by_seq) == list(range(100, 100 + MAX_PENDING_OCCLUDERS))  # none dropped
    assert core.handle_frame(frames[0]) is not None  # initialises; the misfit standing mask goes
    assert core._standing_occluder is None and "standing occluder mask of shape (10, 10) dropped" in core.last_error


def test_the_vertex_budgets_count_the_mesh_the_tracker_builds(frames):
    core = PerceptionCore(TrackerConfig.realtime())
    assert core.expected_vertices(core.tracker.config) == 400  # before any mesh: target_vertices
    core.set_parameters({"target_vertices": MAX_MESH_VERTICES})  # the top of its documented range
    assert core.handle_frame(frames[0]) is not None and core.state == "tracking"  # not refused as 5001
    n = core.tracker.mesh.n_vertices
    core.set_parameters({"target_vertices": 100})
    # the solver-work budget counts the mesh tracked now, larger than the new target until re-initialised
    assert core.expected_vertices(core.tracker.config) == n > 100


def test_a_frame_from_another_lens_or_optical_frame_is_a_changed_camera(frames):
    core = PerceptionCore(TrackerConfig.realtime())
    assert core.handle_frame(frames[0]) is not None
    rectified_again = dataclasses.replace(CAM, D=np.zeros(5))  # no coefficients and zero ones: one lens
    assert core.handle_frame(dataclasses.replace(frames[1], camera=rectified_again)) is not None
    wrist = dataclasses.replace(frames[2], camera=dataclasses.replace(CAM, frame_id="wrist_optical"))
    lens = dataclasses.replace(frames[3], camera=dataclasses.replace(CAM, D=np.array([-0.2, 0.05, 0.0, 0.0])))
    assert core.handle_frame(wrist) is None and core.handle_frame(lens) is None
    assert core.counters.rejected == {"camera_changed": 2}
    assert core.last_error.startswith("frame 3: camera frame") and "[-0.2, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]" \
        in core.last_error
