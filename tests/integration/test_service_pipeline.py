"""``python -m launch_scripts.pipeline``: one command runs source, service and monitor; Ctrl-C
stops everything, and the children die with the parent even when it is killed."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ipc.messages import CameraInfo
from perception.sequence import SequenceWriter
from tests.render import frame_of, grid_surface, plane_points, texture

pytestmark = [pytest.mark.timeout(120), pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; parent-death signal is Linux's")]

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    cam = CameraInfo.from_fov(160, 120, np.deg2rad(45))
    size, uv_faces = (0.6, 0.45), grid_surface(0.6, 0.45, 16, 12)
    tex = texture(np.random.default_rng(1))
    path = tmp_path_factory.mktemp("pipeline") / "sheet"
    with SequenceWriter(path, cam) as writer:
        for k in range(6):
            points = plane_points(uv_faces[0], np.array([0.0, 0.0, 1.2 + 0.005 * k]), size)
            writer.write(frame_of(points, *uv_faces, tex, cam, size, t=k / 10, seq=k))
    return path


def children_of(pid):
    """PIDs of the live processes whose parent is ``pid``."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                out.append(int(entry))
    return out


def alive(pid):
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def start_pipeline(sequence):
    command = [sys.executable, "-m", "launch_scripts.pipeline", "--print-period-s", "0.2", "--status-period-s", "0.5",
               "sequence", str(sequence), "--loop", "--pacing", "rate", "--rate-hz", "10"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # A session of its own, as a terminal's job: Ctrl-C reaches the whole process group.
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            text=True, cwd=REPO, env=env, start_new_session=True)


def read_until(proc, text, timeout_s):
    lines, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f"no {text!r} within {timeout_s} s:\n{''.join(lines)}")


def test_ctrl_c_stops_the_pipeline_cleanly(sequence):
    proc = start_pipeline(sequence)
    try:
        lines = read_until(proc, "estimate seq", 60.0)
        lines += read_until(proc, "status: tracking", 30.0)
        ends = json.loads(lines[0])  # the first line: the endpoints, as documented
        assert sorted(ends) == ["control", "estimates", "frames"] and ends["control"].startswith("tcp://127.0.0.1:")
        kids = children_of(proc.pid)
        assert len(kids) == 2
        os.killpg(proc.pid, signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
        assert proc.returncode == 0, rest
        assert "Traceback" not in rest
        assert not [k for k in kids if alive(k)]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_children_die_with_a_killed_parent(sequence):
    proc = start_pipeline(sequence)
    kids = []
    try:
        read_until(proc, "estimate seq", 60.0)
        kids = children_of(proc.pid)
        assert len(kids) == 2
        proc.kill()  # no cleanup possible in the parent
        proc.wait(timeout=10)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(alive(k) for k in kids):
            time.sleep(0.1)
        assert not [k for k in kids if alive(k)]
    finally:
        for k in kids:
            if alive(k):
                os.kill(k, signal.SIGKILL)
