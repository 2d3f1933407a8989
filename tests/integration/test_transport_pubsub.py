"""PUB/SUB on loopback: delivery, newest-message semantics with bounded memory, heartbeats,
a publisher killed and restarted, malformed messages. Random free ports; every test
starts and stops what it needs, and every wait has a timeout."""

import dataclasses
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from ipc import messages as m
from ipc.codec import Limits, encode
from ipc.examples import example_messages
from ipc.transport import Publisher, Subscriber

pytestmark = pytest.mark.timeout(60)

ANY_PORT = "tcp://127.0.0.1:*"
REPO = Path(__file__).resolve().parents[2]
FRAME = example_messages()[m.RGBDFrame]


def wait_until(predicate, timeout_s: float, poll_s: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


def publish_until_received(pub: Publisher, sub: Subscriber, msg, timeout_s: float = 5.0):
    """PUB drops messages until the subscription has arrived (slow joiner): resend until one lands."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pub.publish(msg)
        got = sub.recv_latest(timeout_s=0.05)
        if got is not None:
            return got
    raise AssertionError("nothing received")


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_delivery_heartbeats_and_filtering():
    with Publisher(ANY_PORT, source="frames", heartbeat_period_s=0.05) as pub, \
            Subscriber(pub.endpoint, accept=(m.RGBDFrame,)) as sub:
        assert pub.endpoint.startswith("tcp://127.0.0.1:") and not pub.endpoint.endswith("*")
        got = publish_until_received(pub, sub, FRAME)
        assert got.seq == FRAME.seq and np.array_equal(got.rgb, FRAME.rgb)
        assert np.array_equal(got.depth_m, np.nan_to_num(FRAME.depth_m, nan=0.0))
        assert not got.rgb.flags.writeable  # a zero-copy view on the received frame
        assert wait_until(lambda: sub.last_heartbeat is not None and sub.last_heartbeat.seq >= 2, 2.0)
        assert sub.last_heartbeat.source == "frames" and sub.last_heartbeat.period_s == 0.05
        assert sub.age_s < 1.0 and not sub.stale
        assert sub.malformed == 0
        pub.publish(m.StatusReply())  # not accepted by this subscriber: dropped, and counted
        assert sub.recv_latest(timeout_s=0.2) is None
        assert sub.received >= 3 and sub.malformed == 1
        assert sub.last_malformed == "a StatusReply is not carried here; expected RGBDFrame or Heartbeat"


def test_uint16_depth_publisher():
    with Publisher(ANY_PORT, source="sensor", depth_scale=1000.0) as pub, Subscriber(pub.endpoint) as sub:
        got = publish_until_received(pub, sub, FRAME)
        assert got.depth_m.dtype == np.float32
        assert np.allclose(got.depth_m, np.nan_to_num(FRAME.depth_m, nan=0.0), atol=0.0005 + 1e-6)


def test_slow_consumer_gets_the_newest_frame_and_memory_stays_bounded():
    """A consumer that takes nothing while 300 full-size frames (620 MB in all) are published
    then gets the newest frame, and no backlog after it."""
    cam = m.CameraInfo.from_fov(640, 480, 1.0)
    depth = np.full((480, 640), 1.5, np.float32)
    with Publisher(ANY_PORT, source="frames") as pub, Subscriber(pub.endpoint) as sub:
        first = m.RGBDFrame(np.zeros((480, 640, 3), np.uint8), depth, cam, seq=0)
        publish_until_received(pub, sub, first)
        baseline, peak = rss_bytes(), 0
        n = 300
        for seq in range(1, n + 1):
            # Fresh buffers every frame, as from a camera: anything queued would add up.
            rgb = np.full((480, 640, 3), seq % 256, np.uint8)
            pub.publish(m.RGBDFrame(rgb, depth.copy(), cam, seq=seq))
            if seq % 10 == 0:
                peak = max(peak, rss_bytes() - baseline)
        time.sleep(0.3)  # let the last frames cross; then one more that must be the one returned
        pub.publish(m.RGBDFrame(np.full((480, 640, 3), 7, np.uint8), depth, cam, seq=n + 1))
        time.sleep(0.3)
        peak = max(peak, rss_bytes() - baseline)
        newest = sub.recv_latest(timeout_s=2.0)
        assert newest is not None and newest.seq == n + 1 and newest.rgb[0, 0, 0] == 7
        assert sub.recv_latest(timeout_s=0.2) is None  # no backlog behind the newest
        assert peak < 150 * 2**20, f"memory grew by {peak / 2**20:.0f} MiB"


# Publishes frames at 50 Hz until killed; each frame's timestamp_s is the process's generation.
PUBLISHER_SCRIPT = """
import dataclasses, sys, time
from ipc.examples import example_messages
from ipc.messages import RGBDFrame
from ipc.transport import Publisher
frame = example_messages()[RGBDFrame]
with Publisher(sys.argv[1], source="frames", heartbeat_period_s=0.1) as pub:
    print(pub.endpoint, flush=True)
    seq = 0
    while True:
        pub.publish(dataclasses.replace(frame, seq=seq, timestamp_s=float(sys.argv[2])))
        seq += 1
        time.sleep(0.02)
"""


def start_publisher(endpoint: str, generation: int) -> tuple[subprocess.Popen, str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-c", PUBLISHER_SCRIPT, endpoint, str(generation)]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, cwd=REPO, env=env)
    line = proc.stdout.readline().strip()  # the endpoint actually bound, once it is bound
    assert line.startswith("tcp://"), f"publisher did not start: {line!r}"
    return proc, line


def test_publisher_killed_and_restarted(caplog):
    caplog.set_level(logging.INFO, logger="ipc.transport")
    events, restarts = [], []
    proc, endpoint = start_publisher(ANY_PORT, generation=1)
    try:
        with Subscriber(endpoint, stale_after_s=0.5, on_liveness=lambda alive, s: events.append((alive, s)),
                        on_restart=lambda old, new: restarts.append((old, new))) as sub:
            first = sub.recv_latest(timeout_s=10.0)
            assert first is not None and first.timestamp_s == 1.0
            # Ten heartbeats, so that the new process's first ones have a smaller seq.
            assert wait_until(lambda: sub.last_heartbeat is not None and sub.last_heartbeat.seq >= 10, 5.0)
            proc.kill()
            proc.wait(timeout=5)
            assert wait_until(lambda: sub.stale, 3.0)
            assert sub.age_s > 0.5
            # The receiver thread sets the flag, then calls back: wait for the call too.
            assert wait_until(lambda: events, 1.0) and events[0][0] is False and events[0][1] > 0.5
            assert any(r.levelno == logging.WARNING and "no message from publisher 'frames'" in r.getMessage()
                       for r in caplog.records)
            sub.recv_latest(timeout_s=0.01)  # drop a frame taken before the kill, if any

            proc, _ = start_publisher(endpoint, generation=2)
            again = sub.recv_latest(timeout_s=10.0)
            assert again is not None and again.timestamp_s == 2.0  # from the new process
            assert not sub.stale
            assert wait_until(lambda: events[-1][0] is True, 1.0) and events[-1][1] > 0.5
            assert any("receiving again" in r.getMessage() for r in caplog.records)
            assert wait_until(lambda: any("restarted" in r.getMessage() for r in caplog.records), 3.0)
            assert restarts == []  # a restart during a silence is that silence's end, reported once
    finally:
        proc.kill()
        proc.wait(timeout=5)


def publisher_on(endpoint, **kw) -> Publisher:
    """A Publisher on an endpoint just closed: libzmq's I/O thread releases the port a moment later."""
    deadline = time.monotonic() + 5.0
    while True:
        try:
            return Publisher(endpoint, **kw)
        except ValueError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_a_restart_without_silence_is_reported_once():
    restarts, events = [], []
    pub = Publisher(ANY_PORT, source="frames", heartbeat_period_s=0.05)
    endpoint = pub.endpoint
    try:
        with Subscriber(endpoint, stale_after_s=5.0, on_restart=lambda old, new: restarts.append((old, new)),
                        on_liveness=lambda alive, s: events.append(alive)) as sub:
            assert wait_until(lambda: sub.last_heartbeat is not None and sub.last_heartbeat.seq >= 5, 5.0)
            pub.close()
            pub = publisher_on(endpoint, source="frames", heartbeat_period_s=0.05)  # same endpoint, seq from 0 again
            assert wait_until(lambda: restarts, 5.0)
            time.sleep(0.3)
    finally:
        pub.close()
    old, new = restarts[0]
    assert len(restarts) == 1 and new.seq < old.seq and events == []


def test_never_heard_publisher_is_reported_stale(caplog):
    with Publisher(ANY_PORT, source="x") as pub:
        endpoint = pub.endpoint
    with Subscriber(endpoint, stale_after_s=0.2) as sub:
        assert sub.age_s == float("inf")
        assert wait_until(lambda: sub.stale, 2.0)
        assert sub.recv_latest(timeout_s=0.05) is None


def test_stale_limit_follows_a_long_heartbeat_period():
    with Publisher(ANY_PORT, source="slow", heartbeat_period_s=0.4) as pub:
        endpoint = pub.endpoint
    with Subscriber(endpoint, stale_after_s=0.2) as alone:  # no heartbeat heard: the configured limit
        assert alone.stale_limit_s == 0.2
    with Publisher(endpoint, source="slow", heartbeat_period_s=0.4), Subscriber(endpoint, stale_after_s=0.2) as sub:
        assert wait_until(lambda: sub.last_heartbeat is not None, 3.0)
        assert sub.stale_limit_s == pytest.approx(1.2)
        time.sleep(1.0)  # more than two heartbeat periods, each longer than stale_after_s
        assert not sub.stale


def test_malformed_messages_are_dropped_and_counted(caplog):
    ctx = zmq.Context.instance()
    raw = ctx.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")
    try:
        with Subscriber(f"tcp://127.0.0.1:{port}") as sub:
            good = encode(dataclasses.replace(FRAME, seq=5))
            deadline = time.monotonic() + 5.0
            got = None
            while got is None and time.monotonic() < deadline:
                raw.send_multipart([b"\xc1 not msgpack"])
                raw.send_multipart([good[0][:-3]])
                raw.send_multipart([b"x"] * 40)  # more frames than the limit
                raw.send_multipart(good)
                got = sub.recv_latest(timeout_s=0.05)
            assert got is not None and got.seq == 5
            assert wait_until(lambda: sub.malformed >= 3, 2.0)
            assert any("dropped a malformed message" in r.getMessage() for r in caplog.records)
    finally:
        raw.close()


def test_closed_subscriber_returns_none_and_bad_arguments_are_named():
    with Publisher(ANY_PORT, source="x") as pub:
        sub = Subscriber(pub.endpoint)
        sub.close()
        assert sub.recv_latest(timeout_s=1.0) is None
        with pytest.raises(ValueError, match="Subscriber.stale_after_s"):
            Subscriber(pub.endpoint, stale_after_s=0)
        with pytest.raises(ValueError, match="Subscriber.accept"):
            Subscriber(pub.endpoint, accept=(dict,))
    with pytest.raises(ValueError, match=r"Heartbeat\.source"):
        Publisher(ANY_PORT, source="")
    with pytest.raises(ValueError, match=r"tcp://256\.0\.0\.1:1: cannot bind"):
        Publisher("tcp://256.0.0.1:1", source="x")
    with Publisher(ANY_PORT, source="x") as pub:
        with pytest.raises(ValueError, match="cannot bind"):
            Publisher(pub.endpoint, source="y")  # port taken


def test_oversize_messages_do_not_deafen_the_subscriber():
    """libzmq drops a connection that carries a frame over the cap and never reconnects a
    connecting socket after that: the Subscriber opens a new socket, so frames from the same
    publisher, and from one restarted on the same endpoint, arrive again."""
    limits = Limits(max_message_bytes=2**16, max_array_bytes=2**16)
    good = encode(FRAME)
    ctx = zmq.Context.instance()

    def raw_publisher(endpoint):
        raw = ctx.socket(zmq.PUB)
        raw.setsockopt(zmq.LINGER, 0)
        deadline = time.monotonic() + 5.0
        while True:
            try:
                raw.bind(endpoint)
                return raw
            except zmq.ZMQError:  # a closed socket's port is released by libzmq's I/O thread a moment later
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

    def resend_until_received(raw, sub, timeout_s=5.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            raw.send_multipart(good)
            if sub.recv_latest(timeout_s=0.02) is not None:
                return True
        return False

    raw = raw_publisher(ANY_PORT)
    endpoint = raw.getsockopt_string(zmq.LAST_ENDPOINT)
    try:
        with Subscriber(endpoint, limits=limits) as sub:
            assert resend_until_received(raw, sub)
            for reconnects in range(3):
                raw.send(b"x" * (limits.max_message_bytes + 1))
                assert wait_until(lambda n=reconnects: sub.reconnects > n, 2.0)
                assert resend_until_received(raw, sub), "deaf after an oversize frame"
            raw.send(b"x" * (limits.max_message_bytes + 1))
            raw.close()
            raw = raw_publisher(endpoint)  # a new publisher on the same endpoint
            assert resend_until_received(raw, sub), "deaf to a restarted publisher after an oversize frame"
            assert sub.reconnects >= 4 and sub.malformed == 0
    finally:
        raw.close()


def test_malformed_messages_in_a_burst_are_each_counted_not_skipped(caplog):
    """Messages are decoded as they arrive: malformed ones among frames the consumer never
    took are counted as malformed, and only valid frames count as skipped. The malformed
    ones here have a valid header (an RGBDFrame) and a buffer a byte short."""
    ctx = zmq.Context.instance()
    raw = ctx.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")
    good = encode(FRAME)
    try:
        with Subscriber(f"tcp://127.0.0.1:{port}", accept=(m.RGBDFrame,)) as sub:
            deadline = time.monotonic() + 5.0
            while sub.received == 0 and time.monotonic() < deadline:  # until the subscription has arrived
                raw.send_multipart(good)
                time.sleep(0.01)
            assert sub.recv_latest(timeout_s=1.0) is not None
            start = sub.received
            short = [bytes(f) for f in encode(FRAME, inline_max_bytes=0)]
            short[-1] = short[-1][:-1]
            for _ in range(20):
                raw.send_multipart(short)
                raw.send_multipart(good)
                time.sleep(0.002)  # slower than the receiver thread: nothing is lost to the queue limit
            assert wait_until(lambda: sub.received - start == 40, 5.0), sub.received - start
            assert sub.malformed == 20 and sub.skipped == 19
            assert sub.recv_latest(timeout_s=0.1) is not None
            # Counted one by one, logged at most once a second: garbage cannot flood the log.
            logged = [r for r in caplog.records if "dropped a malformed message" in r.getMessage()]
            assert 1 <= len(logged) <= 2
    finally:
        raw.close()


def test_recent_keeps_the_messages_taken_or_skipped_not_the_one_waiting():
    with Publisher(ANY_PORT, source="frames", heartbeat_period_s=0.05) as pub, \
            Subscriber(pub.endpoint, accept=(m.RGBDFrame,), keep_recent=3) as sub, \
            Subscriber(pub.endpoint, accept=(m.RGBDFrame,)) as plain:
        publish_until_received(pub, sub, FRAME)
        publish_until_received(pub, plain, FRAME)  # its subscription may arrive later
        # The copies sent while the subscriptions were on their way may still land after the
        # one taken (late on a loaded machine): take them, so that none counts as skipped below.
        while sub.recv_latest(timeout_s=0.5) is not None:
            pass
        assert {f.seq for f in sub.recent()} == {FRAME.seq}
        sub.clear_recent()
        before = sub.skipped
        for seq in range(10, 15):  # one at a time, each received before the next (the queue holds few)
            pub.publish(dataclasses.replace(FRAME, seq=seq))
            assert wait_until(lambda n=seq - 10: sub.skipped - before == n, 5.0), (seq, sub.skipped - before)
        assert [f.seq for f in sub.recent()] == [11, 12, 13]  # skipped, oldest dropped; 14 still waits
        assert sub.recv_latest(1.0).seq == 14
        assert [f.seq for f in sub.recent()] == [12, 13, 14]
        sub.clear_recent()
        assert sub.recent() == []
        assert plain.recent() == []
    with pytest.raises(ValueError, match="keep_recent"):
        Subscriber(ANY_PORT.replace("*", "1"), keep_recent=-1)


def test_a_publisher_refuses_a_message_its_subscribers_would_drop_and_too_frequent_heartbeats():
    from ipc.codec import ProtocolError

    limits = Limits(max_message_bytes=2**16, max_array_bytes=2**16)
    with Publisher(ANY_PORT, source="t", limits=limits) as pub, Subscriber(pub.endpoint, limits=limits) as sub:
        def frame(side):
            camera = m.CameraInfo(side, side, np.array([[side, 0, side / 2], [0, side, side / 2], [0, 0, 1.0]]))
            return m.RGBDFrame(rgb=np.zeros((side, side, 3), np.uint8), depth_m=np.ones((side, side), np.float32),
                               camera=camera, seq=side)

        small, big = frame(8), frame(128)
        with pytest.raises(ProtocolError, match=r"RGBDFrame message of \d+ bytes exceeds the 65536-byte message "
                                                r"limit subscribers keep; not sent"):
            pub.publish(big)  # sent, it would have cut the subscriber off without a word
        assert publish_until_received(pub, sub, small).seq == small.seq and sub.reconnects == 0
    with pytest.raises(ValueError, match=r"heartbeat period: expected at least 0\.05 s .*got 0\.001 s"):
        Publisher(ANY_PORT, source="t", heartbeat_period_s=0.001)
