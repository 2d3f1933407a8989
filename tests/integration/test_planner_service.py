"""The grasp planner service as a real process on loopback: not_ready, plans best first,
adjacent corners, bad requests answered while it keeps serving, its command line, a clean stop.

Estimates are a flat 0.4 x 0.3 m rectangle facing the camera 1 m away, built as the
tracker builds its canonical mesh, so the corners are known. Every wait is bounded.
"""

import dataclasses
import json
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from grasping.service import PlannerCore
from ipc.codec import decode
from ipc.messages import (
    AdjacentCornersReply,
    AdjacentCornersRequest,
    ErrorReply,
    GraspPlanReply,
    GraspRequest,
    MeshEstimate,
)
from ipc.transport import Publisher, RemoteError, RequestClient
from perception.mesh import rectangle_mesh

pytestmark = pytest.mark.timeout(120)

ANY = "tcp://127.0.0.1:*"
W, H, S = 0.4, 0.3, 0.02
CORNERS_CAM = np.array([[x, y, 1.0] for x in (-W / 2, W / 2) for y in (-H / 2, H / 2)])


def rectangle_estimate(seq=0, shift=(0.0, 0.0, 0.0)) -> MeshEstimate:
    mesh = rectangle_mesh(W, H, S)
    canonical = mesh.canonical
    vertices = canonical - [W / 2, H / 2, 0.0] + [0.0, 0.0, 1.0] + np.asarray(shift)
    return MeshEstimate(vertices=vertices, faces=mesh.faces, boundary=mesh.boundary, canonical=canonical, seq=seq,
                        timestamp_s=seq / 30.0)


def start_planner(*args):
    proc = subprocess.Popen([sys.executable, "-m", "launch_scripts.planner_service", "--print-endpoint",
                             "--bind", ANY, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 60)
    line = proc.stdout.readline() if ready else ""
    if not line:
        proc.kill()
        raise AssertionError(f"planner did not start: {proc.stderr.read()[-500:]}")
    return proc, json.loads(line)["planner"]


def stop(proc) -> int:
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def service():
    """(publisher of estimates, planner endpoint) with a planner process serving corner and boundary grasps."""
    with Publisher(ANY, source="test estimates") as publisher:
        proc, endpoint = start_planner("--estimates", publisher.endpoint, "--kinds", "corner", "boundary",
                                       "--pinch-inset-m", "0")
        try:
            yield publisher, endpoint
        finally:
            assert stop(proc) == 0


def test_requests_before_any_estimate_are_not_ready(service):
    _, endpoint = service
    with RequestClient(endpoint, timeout_s=5.0, attempts=1) as client, pytest.raises(RemoteError) as e:
        client.request(GraspRequest(request_id=3, kinds=("corner",)))
    assert e.value.code == "not_ready"
    assert e.value.reply.request_id == 3
    assert "no mesh estimate received yet" in e.value.reply.message


def plan_after_publishing(publisher, client, estimate, request, timeout_s=30.0):
    """Publish ``estimate`` until the planner plans on it (a subscriber joins late)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        publisher.publish(estimate)
        try:
            reply = client.request(request)
        except RemoteError as e:
            assert e.code == "not_ready"
        else:
            if reply.estimate_seq == estimate.seq:
                return reply
        time.sleep(0.1)
    raise AssertionError(f"no plan on estimate {estimate.seq} within {timeout_s} s")


def test_plans_on_the_newest_estimate_are_corners_best_first(service):
    publisher, endpoint = service
    with RequestClient(endpoint, timeout_s=10.0, attempts=1) as client:
        reply = plan_after_publishing(publisher, client, rectangle_estimate(seq=7),
                                      GraspRequest(request_id=1, max_candidates=10, kinds=("corner",)))
        assert isinstance(reply, GraspPlanReply) and reply.request_id == 1 and reply.estimate_seq == 7
        assert len(reply.candidates) == 4
        scores = [c.score for c in reply.candidates]
        assert scores == sorted(scores, reverse=True)
        positions = np.array([c.position for c in reply.candidates])
        dist = np.linalg.norm(positions[:, None] - CORNERS_CAM[None], axis=2)
        assert sorted(np.argmin(dist, axis=1)) == [0, 1, 2, 3] and dist.min(axis=1).max() < 2 * S
        assert {c.kind for c in reply.candidates} == {"corner"}

        two = client.request(GraspRequest(request_id=2, max_candidates=2, kinds=("corner", "boundary")))
        assert len(two.candidates) == 2
        # A request may carry its own estimate: planned on it, not on the newest.
        moved = rectangle_estimate(seq=99, shift=(0.1, 0.0, 0.0))
        own = client.request(GraspRequest(request_id=4, max_candidates=10, kinds=("corner",), estimate=moved))
        assert own.estimate_seq == 99
        assert np.min(np.linalg.norm(np.array([c.position for c in own.candidates]) - (CORNERS_CAM[0] + [0.1, 0, 0]),
                                     axis=1)) < 2 * S


def test_bad_requests_are_answered_and_the_service_keeps_serving(service):
    publisher, endpoint = service
    with RequestClient(endpoint, timeout_s=10.0, attempts=1) as client:
        plan_after_publishing(publisher, client, rectangle_estimate(seq=11), GraspRequest(kinds=("corner",)))
        with pytest.raises(RemoteError) as e:
            client.request(GraspRequest(request_id=5, kinds=("highest",)))
        assert e.value.code == "invalid" and e.value.reply.request_id == 5
        assert e.value.reply.message == "this planner serves corner, boundary grasps, not highest"

    context = zmq.Context.instance()
    raw = context.socket(zmq.REQ)
    raw.setsockopt(zmq.LINGER, 0)
    raw.connect(endpoint)
    try:
        for junk in ([b"\x93not msgpack at all"], [b"\x81\xa4type\xa3Bad"]):
            raw.send_multipart(junk)
            assert raw.poll(10_000), "no reply to a malformed request"
            reply = decode(raw.recv_multipart())
            assert isinstance(reply, ErrorReply) and reply.code == "protocol"
            assert "\n" not in reply.message
    finally:
        raw.close()

    with RequestClient(endpoint, timeout_s=10.0, attempts=1) as client:
        reply = client.request(GraspRequest(request_id=6, kinds=("boundary",), max_candidates=100))
        assert reply.request_id == 6 and len(reply.candidates) > 4
        assert {c.kind for c in reply.candidates} == {"boundary"}


def test_adjacent_corners_through_the_sockets_whatever_the_kinds():
    """A planner serving highest-point grasps only still answers AdjacentCornersRequest: not_ready
    before any estimate, then the two corners sharing an edge with the held one; a held vertex
    off the mesh is invalid, and the service keeps serving both requests."""
    with Publisher(ANY, source="test estimates") as publisher:
        proc, endpoint = start_planner("--estimates", publisher.endpoint, "--kinds", "highest", "--pinch-inset-m", "0")
        try:
            with RequestClient(endpoint, timeout_s=10.0, attempts=1) as client:
                with pytest.raises(RemoteError) as e:
                    client.request(AdjacentCornersRequest(request_id=12, held_vertex=0))
                assert e.value.code == "not_ready" and e.value.reply.request_id == 12
                assert "no mesh estimate received yet" in e.value.reply.message

                estimate = rectangle_estimate(seq=21)
                held = int(np.argmin(np.linalg.norm(estimate.vertices - CORNERS_CAM[0], axis=1)))
                reply = plan_after_publishing(publisher, client, estimate,
                                              AdjacentCornersRequest(request_id=13, held_vertex=held))
                assert isinstance(reply, AdjacentCornersReply)
                assert (reply.request_id, reply.estimate_seq, reply.held_vertex, reply.held_outline_vertex) == \
                       (13, 21, held, held)
                assert sorted(c.side for c in reply.candidates) == [-1, 1]
                positions = np.array([c.plan.position for c in reply.candidates])
                dist = np.linalg.norm(positions[:, None] - CORNERS_CAM[None], axis=2)
                # The corners along the two edges at the held corner, never the diagonal one.
                assert sorted(np.argmin(dist, axis=1)) == [1, 2] and dist.min(axis=1).max() < S
                assert all(c.reachable and c.plan.kind == "corner" for c in reply.candidates)

                with pytest.raises(RemoteError) as e:
                    client.request(AdjacentCornersRequest(request_id=14, held_vertex=100_000))
                assert e.value.code == "invalid" and e.value.reply.request_id == 14
                assert "held_vertex" in e.value.reply.message and "\n" not in e.value.reply.message

                own = client.request(AdjacentCornersRequest(request_id=15, held_vertex=held, max_candidates=1,
                                                            estimate=rectangle_estimate(seq=30, shift=(0.1, 0.0, 0.0))))
                assert own.estimate_seq == 30 and len(own.candidates) == 1
                assert client.request(GraspRequest(request_id=16, kinds=("highest",))).request_id == 16
        finally:
            assert stop(proc) == 0


def test_service_core_without_sockets():
    service = PlannerCore(kinds=("corner",))
    assert service.handle(GraspRequest(kinds=("corner",))).code == "not_ready"
    service.on_estimate(rectangle_estimate(seq=2))
    reply = service.handle(GraspRequest(kinds=("corner", "highest"), max_candidates=10))
    assert len(reply.candidates) == 4 and reply.estimate_seq == 2
    with pytest.raises(ValueError, match=r"Expected kinds: distinct values among .*, got \('corner', 'corner'\)"):
        PlannerCore(kinds=("corner", "corner"))


def test_kinds_as_documented():
    """docs/protocol.md: kinds default to all three, which compete on score; a kind this planner
    does not serve is invalid, not not_ready (retrying cannot help)."""
    assert GraspRequest().kinds == ("corner", "boundary", "highest")
    estimate = rectangle_estimate(seq=3)
    # One corner's flap folded over onto the cloth, 1 cm above it: that corner and the outline
    # beside it lose clearance (another layer is near), so the kinds' scores differ.
    V = estimate.vertices.copy()
    corner = int(np.argmin(V[:, 0] + V[:, 1]))
    flap = np.linalg.norm(V - V[corner], axis=1) < 0.05
    d = V[flap] - V[corner]
    V[flap] = V[corner] + [0.1, 0.1, -0.01] - d[:, [1, 0, 2]] * [1.0, 1.0, 0.0]
    every = PlannerCore().handle(GraspRequest(estimate=dataclasses.replace(estimate, vertices=V), max_candidates=100))
    scores = [c.score for c in every.candidates]
    kinds = [c.kind for c in every.candidates]
    assert scores == sorted(scores, reverse=True) and set(kinds) == {"corner", "boundary", "highest"}
    folded = next(i for i, c in enumerate(every.candidates) if c.kind == "corner" and c.vertex_id == corner)
    assert scores[folded] < 0.9  # ranked by score among the other kinds' plans, not with its own kind
    assert "boundary" in kinds[:folded] and kinds.index("corner") < kinds.index("boundary")
    reply = PlannerCore(kinds=("corner",)).handle(GraspRequest(kinds=("boundary",), estimate=estimate))
    assert isinstance(reply, ErrorReply) and reply.code == "invalid" and "serves corner grasps, not boundary" in reply.message
    doc = (Path(__file__).resolve().parents[2] / "docs" / "protocol.md").read_text()
    assert "`invalid` when none of the requested `kinds` is served by this planner" in doc


def test_a_stale_estimate_is_not_ready_but_a_request_may_bring_its_own():
    service = PlannerCore(kinds=("corner",), max_age_s=0.05)
    service.on_estimate(rectangle_estimate(seq=2))
    assert len(service.handle(GraspRequest(kinds=("corner",))).candidates) == 4
    time.sleep(0.1)
    stale = service.handle(GraspRequest(request_id=8, kinds=("corner",)))
    assert stale.code == "not_ready" and stale.request_id == 8
    assert "over the 0.05 s limit" in stale.message
    assert service.handle(GraspRequest(kinds=("corner",), estimate=rectangle_estimate(seq=3))).estimate_seq == 3
    with pytest.raises(ValueError, match="Expected max_age_s > 0 or None, got 0"):
        PlannerCore(max_age_s=0)


@pytest.mark.parametrize("args, message", [
    (["--kinds", "middle"], "argument --kinds: invalid choice: 'middle'"),
    (["--workspace-min", "1", "1", "1", "--workspace-max", "0", "0", "0"], "Expected workspace_min_world <= workspace_max_world"),
    (["--T-world-cam", *["2"] * 16], "Expected T_world_cam with last row [0, 0, 0, 1]"),
    (["--bind", "nowhere"], "argument --bind: expected a ZeroMQ endpoint"),
    (["--min-score", "nan"], "argument --min-score: expected a finite number, got 'nan'"),
])
def test_bad_command_lines_exit_2_with_one_line(args, message, capsys):
    from launch_scripts.planner_service import main

    with pytest.raises(SystemExit) as e:
        main(args)
    assert e.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0]


def test_a_port_in_use_is_a_one_line_error():
    with Publisher(ANY, source="occupies a port") as occupant:
        done = subprocess.run([sys.executable, "-m", "launch_scripts.planner_service", "--bind", occupant.endpoint,
                               "--estimates", occupant.endpoint], check=False, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot bind" in lines[0]
