"""CURVE from the command line: a key directory made by launch_scripts.curve_keys, services
started with --curve-keys, and clients with and without the right keys. Binding an address
other machines can reach without CURVE needs --insecure (checked without binding one).
Free loopback ports, bounded waits, every process stopped at the end."""

import json
import os
import subprocess
import sys
import time
from argparse import Namespace
from pathlib import Path

import pytest
import zmq

from ipc.endpoints import is_loopback
from ipc.messages import ErrorReply, GraspRequest, Heartbeat, StatusRequest
from ipc.transport import CurveClient, CurveKeys, Publisher, RemoteError, RequestClient, RequestTimeout, Subscriber
from launch_scripts import curve_keys
from launch_scripts.cli import curve_keys_from_args

pytestmark = [
    pytest.mark.timeout(120),
    pytest.mark.slow,
    pytest.mark.skipif(not zmq.has("curve"), reason="libzmq built without CURVE"),
]

REPO = Path(__file__).resolve().parents[2]
ANY = "tcp://127.0.0.1:*"


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    directory = tmp_path_factory.mktemp("keys")
    assert curve_keys.main([str(directory), "--client", "controller", "--client", "stranger"]) == 0
    (directory / "authorized_clients" / "stranger.key").unlink()  # a key pair nobody authorised
    return directory


def start(module, *args):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", module, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True, cwd=REPO, env=env)
    line = proc.stdout.readline()
    assert line.startswith("{"), f"{module} did not start: {line!r} {proc.stderr.read() if proc.poll() is not None else ''}"
    return proc, json.loads(line)


def client(keys, name):
    return CurveClient.from_files(keys / "clients" / f"{name}.key_secret", keys / "server.key")


def test_services_with_curve_keys_serve_authorised_clients_only(keys):
    services = CurveKeys.from_directory(keys)
    procs = []
    with Publisher(ANY, source="camera", heartbeat_period_s=0.1, curve=services.server) as frames:
        try:
            perception, ends = start("launch_scripts.perception_service", "--frames", frames.endpoint, "--estimates", ANY,
                                     "--control", ANY, "--print-endpoints", "--no-auto-init", "--curve-keys", str(keys))
            procs.append(perception)
            planner, planner_end = start("launch_scripts.planner_service", "--estimates", ends["estimates"], "--bind", ANY,
                                         "--print-endpoint", "--curve-keys", str(keys))
            procs.append(planner)

            with RequestClient(ends["control"], timeout_s=5.0, attempts=1, curve=client(keys, "controller")) as control:
                deadline = time.monotonic() + 20
                reply = control.request(StatusRequest(request_id=1))
                while reply.source != "live" and time.monotonic() < deadline:  # the frame source's heartbeats, over CURVE
                    time.sleep(0.1)
                    reply = control.request(StatusRequest(request_id=1))
                assert reply.request_id == 1 and reply.source == "live", reply
            with RequestClient(planner_end["planner"], timeout_s=5.0, attempts=1, curve=client(keys, "controller")) as plan:
                with pytest.raises(RemoteError) as e:
                    plan.request(GraspRequest(request_id=2))
                assert isinstance(e.value.reply, ErrorReply) and e.value.code == "not_ready"
            with Subscriber(ends["estimates"], curve=client(keys, "controller")) as estimates:
                deadline = time.monotonic() + 10
                while estimates.last_heartbeat is None and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert isinstance(estimates.last_heartbeat, Heartbeat) and estimates.last_heartbeat.source == "perception"

            for refused in (None, client(keys, "stranger")):  # unencrypted, and a key not authorised
                with RequestClient(ends["control"], timeout_s=0.5, attempts=1, curve=refused) as control:
                    with pytest.raises(RequestTimeout):
                        control.request(StatusRequest())
        finally:
            for proc in procs:
                proc.terminate()
                proc.wait(timeout=10)


@pytest.mark.parametrize("module, args", [
    ("launch_scripts.perception_service", ["--control", "tcp://0.0.0.0:5562"]),
    ("launch_scripts.planner_service", ["--bind", "tcp://*:5563"]),
    ("launch_scripts.publish_frames", ["sequence", "nowhere", "--endpoint", "tcp://10.1.2.3:5560"]),
])
def test_a_reachable_address_without_curve_needs_insecure(module, args):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=REPO, env=env,
                          timeout=60)
    assert done.returncode == 2
    last = done.stderr.strip().splitlines()[-1]
    assert "can be reached from other machines" in last and "--curve-keys DIR" in last and "--insecure" in last


def test_security_options_are_read_as_documented(keys, tmp_path):
    def args(**kw):
        return Namespace(**{"curve_keys": None, "insecure": False, **kw})

    assert curve_keys_from_args(args(), ["tcp://127.0.0.1:5562", "tcp://localhost:1", "ipc:///tmp/x"]) is None
    assert curve_keys_from_args(args(insecure=True), ["tcp://0.0.0.0:5562"]) is None
    loaded = curve_keys_from_args(args(curve_keys=str(keys)), ["tcp://0.0.0.0:5562"])
    assert loaded.client.server_public_key == loaded.server.public_key  # services connect to each other as clients
    assert loaded.server.public_key in loaded.server.authorized_clients
    with pytest.raises(ValueError, match="server.key_secret not found"):
        curve_keys_from_args(args(curve_keys=str(tmp_path)), [])
    for endpoint, local in (("tcp://127.0.0.2:1", True), ("tcp://[::1]:1", True), ("tcp://lo:1", True),
                            ("tcp://eth0:1", False), ("tcp://192.168.1.4:1", False), ("tcp://*:1", False)):
        assert is_loopback(endpoint) is local, endpoint
