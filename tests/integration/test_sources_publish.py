"""A frame source on a ZeroMQ publisher (run_publisher, launch_scripts.publish_frames), on loopback."""

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ipc.messages import CameraInfo, RGBDFrame
from ipc.transport import Subscriber
from perception.sequence import SequenceWriter
from perception.sources import Pacing, SequenceSource, run_publisher

pytestmark = pytest.mark.timeout(60)

REPO = Path(__file__).resolve().parents[2]
CAM = CameraInfo.from_fov(40, 30, 1.0)


def test_a_sequence_travels_with_its_depth_units_and_name(tmp_path):
    rng = np.random.default_rng(3)
    written = []
    with SequenceWriter(tmp_path / "seq", CAM, depth_scale=5000.0) as writer:
        for k in range(4):
            depth = np.round(rng.uniform(0.5, 3.0, (30, 40)) * 5000) / 5000  # whole TUM units
            depth[0, :3] = 0.0
            f = RGBDFrame(rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), depth.astype(np.float32), CAM, k / 30, k)
            writer.write(f)
            written.append(f)
    bound, stop = [], threading.Event()
    with SequenceSource(tmp_path / "seq") as source:
        thread = threading.Thread(target=run_publisher, args=(source, "tcp://127.0.0.1:*"), daemon=True, kwargs=dict(
            pacing=Pacing("rate", 20.0), loop=True, stop=stop, on_bound=bound.append, heartbeat_period_s=0.1))
        thread.start()
        try:
            assert _wait(lambda: bound, 10.0)
            with Subscriber(bound[0], accept=(RGBDFrame,)) as sub:
                got = {}
                while len(got) < 8:
                    f = sub.recv_latest(timeout_s=10.0)
                    assert f is not None
                    got[f.seq] = f
                assert sub.last_heartbeat.source == "sequence:seq"
        finally:
            stop.set()
            thread.join(timeout=10)
    assert not thread.is_alive()
    for seq, f in got.items():  # looped passes continue seq; frame seq % 4 is the written one
        w = written[seq % 4]
        np.testing.assert_array_equal(f.rgb, w.rgb)
        # uint16 at the sequence's own scale on the wire: the recorded values, exactly
        np.testing.assert_array_equal(np.rint(f.depth_m.astype(np.float64) * 5000), np.rint(w.depth_m.astype(np.float64) * 5000))


def test_publish_frames_command_fails_with_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    (tmp_path / "a.mkv").write_bytes(b"")
    for args, message in ((["sequence", str(tmp_path / "none")], "no such directory"),
                          (["sequence", str(tmp_path), "--pacing", "rate"], "--pacing rate needs --rate-hz HZ"),
                          (["kinect", "--recording", str(tmp_path / "none.mkv")], "none.mkv not found"),
                          (["kinect", "--recording", str(tmp_path / "a.mkv"), "--fps", "15"], "own colour resolution")):
        proc = subprocess.run([sys.executable, "-m", "launch_scripts.publish_frames", *args], capture_output=True,
                              text=True, cwd=REPO, env=env, timeout=60)
        assert proc.returncode == 2
        assert proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr


def _wait(predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.02)
    return predicate()
