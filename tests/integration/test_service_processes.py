"""The pipeline as separate processes on loopback: sequence player -> perception service ->
a subscriber here; then the player is killed and restarted mid-stream.

The sequence is written here with perception.sequence's writer from frames of a rendered
textured sheet (tests.render) moving forth and back, so the true surface of every frame is
known. Free ports, bounded waits, every process stopped at the end.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ipc.messages import CameraInfo, MeshEstimate, StatusRequest
from ipc.transport import RequestClient, Subscriber
from perception.sequence import SequenceWriter
from tests.render import frame_of, grid_surface, plane_points, texture

pytestmark = [pytest.mark.timeout(150), pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
CAM = CameraInfo.from_fov(320, 240, np.deg2rad(45))
SIZE = (0.6, 0.45)
CENTRE = np.array([0.0, 0.0, 1.3])
STEP = np.array([0.008, -0.004, 0.01])  # metres per frame
N = 12  # one forth-and-back cycle; the player loops it, and seq N is frame 0 again


def shift(k):
    k = k % N
    return STEP * (k if k <= N // 2 else N - k)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    path = tmp_path_factory.mktemp("service") / "sheet"
    uv, faces = grid_surface(*SIZE, 31, 24)
    tex = texture(np.random.default_rng(7))
    with SequenceWriter(path, CAM, depth_scale=5000.0) as writer:
        for k in range(N):
            writer.write(frame_of(plane_points(uv, CENTRE + shift(k), SIZE), uv, faces, tex, CAM, SIZE, t=k / 10,
                                  seq=k, noise_m=0.001, rng=np.random.default_rng(k)))
    return path


def start(module, *args):
    """``python -m module args`` with its endpoints JSON line read from stdout."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", module, *args], stdout=subprocess.PIPE, stdin=subprocess.DEVNULL,
                            text=True, cwd=REPO, env=env)
    line = proc.stdout.readline()
    assert line.startswith("{"), f"{module} did not start: {line!r}"
    return proc, json.loads(line)


def start_player(sequence, endpoint):
    return start("launch_scripts.publish_frames", "sequence", str(sequence), "--endpoint", endpoint,
                 "--print-endpoint", "--pacing", "rate", "--rate-hz", "8", "--loop", "--start-delay-s", "0",
                 "--heartbeat-period-s", "0.2")


def check_estimates(estimates):
    """Consistent vertex counts and increasing seq, every vertex on the frame's true sheet."""
    assert len({len(e.vertices) for e in estimates}) == 1, "the mesh changed size without a re-initialisation"
    seqs = [e.seq for e in estimates]
    assert seqs == sorted(set(seqs)), seqs
    for e in estimates:
        assert e.faces.max() < len(e.vertices) and len(e.canonical) == len(e.vertices)
        v = e.vertices - (CENTRE + shift(e.seq))
        dz = np.abs(v[:, 2])
        assert np.median(dz) < 0.006 and np.percentile(dz, 95) < 0.02, (e.seq, np.median(dz), dz.max())
        assert np.all(np.abs(v[:, :2]) <= np.array(SIZE) / 2 + 0.03), e.seq


def collect(sub, n, timeout_s):
    got = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        e = sub.recv_latest(timeout_s=0.5)
        if e is not None:
            got.append(e)
    assert len(got) == n, f"{len(got)} of {n} estimates within {timeout_s} s"
    return got


def wait_status(control, predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while True:
        reply = control.request(StatusRequest())
        if predicate(reply) or time.monotonic() > deadline:
            return reply
        time.sleep(0.1)


def test_player_service_subscriber_and_a_publisher_restart(sequence):
    procs = []
    try:
        player, bound = start_player(sequence, "tcp://127.0.0.1:*")
        procs.append(player)
        service, ends = start("launch_scripts.perception_service", "--frames", bound["frames"],
                              "--estimates", "tcp://127.0.0.1:*", "--control", "tcp://127.0.0.1:*",
                              "--print-endpoints", "--preset", "realtime", "--stale-after-s", "1.0")
        procs.append(service)
        with Subscriber(ends["estimates"], accept=(MeshEstimate,)) as sub, \
                RequestClient(ends["control"], timeout_s=5.0, attempts=1) as control:
            before = collect(sub, 6, 60.0)
            check_estimates(before)
            reply = control.request(StatusRequest())
            assert reply.state == "tracking" and reply.source == "live"

            player.kill()
            player.wait(timeout=10)
            reply = wait_status(control, lambda r: r.source == "stale", 10.0)
            assert reply.source == "stale" and reply.frame_age_s >= 1.0, reply
            sub.recv_latest(timeout_s=0.3)  # drop an estimate from before the kill

            player, _ = start_player(sequence, bound["frames"])  # same endpoint, a new process: seq from 0
            procs.append(player)
            after = collect(sub, 6, 60.0)
            check_estimates(after)
            reply = wait_status(control, lambda r: r.source == "live", 10.0)
            assert reply.source == "live" and reply.reinitialisations == 1 and reply.discontinuities == 1
            assert reply.state == "tracking", reply
    finally:
        for proc in procs:
            proc.kill()
            proc.wait(timeout=10)
