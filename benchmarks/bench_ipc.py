"""IPC benchmark: codec and transport figures for 640x480 RGB-D frames on loopback.

    python benchmarks/bench_ipc.py [--runs 3] [--seconds 10] [--throughput-seconds 3]

Prints, for depth sent as float32 metres and as uint16 millimetres:

- codec: encode and decode time of one frame (in process);
- latency at 30 Hz: a publisher process publishes frames at 30 Hz to a subscriber in
  this process; latency runs from the moment the frame is stamped (just before it is
  built, validated, encoded and sent) to the moment ``Subscriber.recv_latest`` has
  returned it decoded and validated. Both processes read the same clock
  (``time.perf_counter``, CLOCK_MONOTONIC on Linux). p50 and p99;
- throughput: the publisher publishes one prebuilt frame back to back (encoding it
  each time) for ``--throughput-seconds``; frames per second delivered (received and
  decoded) to the subscriber, and the rate offered by the publisher (PUB drops what
  the connection cannot take, so it can exceed the delivered rate).

Each figure is the median over ``--runs`` runs. The same runs are repeated with a peer:
plain pyzmq PUB/SUB sending the same image bytes as raw frames (no header, codec,
validation, heartbeats or receiver thread), the floor that this machine's loopback
allows at the same time. Targets: p99 <= 5 ms at 30 Hz, >= 300 frames/s delivered.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing as mp
import os
import statistics
import struct
import sys
import time
from pathlib import Path

import numpy as np
import zmq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ipc import codec  # noqa: E402
from ipc.messages import CameraInfo, RGBDFrame  # noqa: E402
from ipc.transport import HWM, Publisher, Subscriber  # noqa: E402

WIDTH, HEIGHT = 640, 480
WARMUP_SEQ = -1
STAMP = struct.Struct("<qd")  # the peer's first frame: seq, timestamp


def make_frame(seed: int = 0) -> RGBDFrame:
    """A 640x480 frame with textured colour and a depth ramp from 0.5 to 3 m, some pixels missing."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    depth = np.linspace(0.5, 3.0, HEIGHT * WIDTH, dtype=np.float32).reshape(HEIGHT, WIDTH)
    depth[rng.random((HEIGHT, WIDTH)) < 0.05] = 0.0
    return RGBDFrame(rgb=rgb, depth_m=depth, camera=CameraInfo.from_fov(WIDTH, HEIGHT, np.deg2rad(58.0)))


def bench_codec(frame: RGBDFrame, depth_scale: float | None, repeats: int = 200) -> tuple[float, float]:
    """Median encode and decode time of one frame, milliseconds."""
    enc, dec = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        frames = codec.encode(frame, depth_scale=depth_scale)
        t1 = time.perf_counter()
        codec.decode(frames)
        t2 = time.perf_counter()
        enc.append(t1 - t0)
        dec.append(t2 - t1)
    return 1e3 * statistics.median(enc), 1e3 * statistics.median(dec)


class _PeerPublisher:
    """Plain PUB socket sending [seq+stamp, rgb bytes, depth bytes]: the peer to compare with."""

    def __init__(self, depth_scale: float | None):
        self.sock = zmq.Context.instance().socket(zmq.PUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SNDHWM, HWM)
        self.endpoint = f"tcp://127.0.0.1:{self.sock.bind_to_random_port('tcp://127.0.0.1')}"
        self.depth_scale = depth_scale

    def publish(self, frame: RGBDFrame) -> None:
        depth = frame.depth_m if self.depth_scale is None else np.rint(frame.depth_m * self.depth_scale).astype(np.uint16)
        self.sock.send_multipart([STAMP.pack(frame.seq, frame.timestamp_s), frame.rgb, depth], copy=False)

    def close(self) -> None:
        self.sock.close()


class _PeerSubscriber:
    """Plain SUB socket read in the calling thread; returns (seq, timestamp) per message."""

    def __init__(self, endpoint: str):
        self.sock = zmq.Context.instance().socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RCVHWM, HWM)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.connect(endpoint)

    def receive(self, timeout_s: float) -> tuple[int, float] | None:
        if not self.sock.poll(int(1000 * timeout_s)):
            return None
        head, *buffers = self.sock.recv_multipart(copy=False)
        for buf in buffers:
            np.frombuffer(buf, np.uint8)  # as a consumer would view them
        return STAMP.unpack(head.bytes)

    def close(self) -> None:
        self.sock.close()


class _IpcSubscriber:
    def __init__(self, endpoint: str):
        self.sub = Subscriber(endpoint, accept=(RGBDFrame,))

    def receive(self, timeout_s: float) -> tuple[int, float] | None:
        msg = self.sub.recv_latest(timeout_s)
        return None if msg is None else (msg.seq, msg.timestamp_s)

    def close(self) -> None:
        self.sub.close()


def publisher_process(peer, endpoints, go, done, depth_scale, rate_hz, amount, report) -> None:
    """Publish warm-up frames until ``go``, then measured frames.

    rate_hz > 0: ``amount`` frames at ``rate_hz``, each stamped with the clock as it is
    built. rate_hz == 0: the same prebuilt frame back to back for ``amount`` seconds.
    Puts the send rate (frames/s) on ``report``.
    """
    base = make_frame()
    pub = _PeerPublisher(depth_scale) if peer else Publisher("tcp://127.0.0.1:*", source="bench", depth_scale=depth_scale)
    try:
        endpoints.put(pub.endpoint)
        while not go.wait(0.02):
            pub.publish(dataclasses.replace(base, seq=WARMUP_SEQ, timestamp_s=time.perf_counter()))
        start, sent = time.perf_counter(), 0
        if rate_hz:
            for seq in range(amount):
                delay = start + seq / rate_hz - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                pub.publish(dataclasses.replace(base, seq=seq, timestamp_s=time.perf_counter()))
            sent = amount
        else:
            while time.perf_counter() - start < amount:
                pub.publish(base)
                sent += 1
        report.put(sent / (time.perf_counter() - start))
        done.wait(30.0)
    finally:
        pub.close()


def transport_run(peer: bool, depth_scale: float | None, rate_hz: float, amount: float) -> dict:
    """One run with a fresh publisher process (see ``publisher_process``).

    Returns latencies (s, rate_hz > 0 only), frames received, delivered and sent rates.
    """
    ctx = mp.get_context("spawn")
    endpoints, report = ctx.Queue(), ctx.Queue()
    go, done = ctx.Event(), ctx.Event()
    args = (peer, endpoints, go, done, depth_scale, rate_hz, amount, report)
    proc = ctx.Process(target=publisher_process, args=args, daemon=True)
    proc.start()
    receiver = None
    try:
        endpoint = endpoints.get(timeout=30.0)
        receiver = _PeerSubscriber(endpoint) if peer else _IpcSubscriber(endpoint)
        while (got := receiver.receive(timeout_s=10.0)) is not None and got[0] != WARMUP_SEQ:
            pass
        if got is None:
            raise RuntimeError("no warm-up frame from the publisher")
        go.set()
        latencies, first, last, received = [], None, None, 0
        while received < (amount if rate_hz else math.inf):
            got = receiver.receive(timeout_s=1.0)
            if got is None:
                break  # the publisher has finished (or died)
            now = time.perf_counter()
            if got[0] == WARMUP_SEQ:
                continue
            if rate_hz:
                latencies.append(now - got[1])
            first = now if first is None else first
            last, received = now, received + 1
        send_rate = report.get(timeout=30.0)
    finally:
        if receiver is not None:
            receiver.close()
        done.set()
        proc.join(timeout=10.0)
        if proc.is_alive():
            proc.kill()
    return {
        "latencies": np.array(latencies),
        "received": received,
        "delivered_fps": (received - 1) / (last - first) if received > 1 else 0.0,
        "send_fps": send_rate,
    }


def transport_figures(peer: bool, depth_scale: float | None, args) -> str:
    n = int(30.0 * args.seconds)
    lat_runs = [transport_run(peer, depth_scale, 30.0, n) for _ in range(args.runs)]
    p50 = statistics.median(1e3 * np.percentile(r["latencies"], 50) for r in lat_runs)
    p99 = statistics.median(1e3 * np.percentile(r["latencies"], 99) for r in lat_runs)
    lost = sum(n - r["received"] for r in lat_runs)
    thr_runs = [transport_run(peer, depth_scale, 0.0, args.throughput_seconds) for _ in range(args.runs)]
    fps = statistics.median(r["delivered_fps"] for r in thr_runs)
    offered = statistics.median(r["send_fps"] for r in thr_runs)
    return (
        f"30 Hz latency p50 {p50:5.2f} ms, p99 {p99:5.2f} ms ({n} frames per run, {lost} lost in all); "
        f"throughput {fps:4.0f} frames/s delivered ({offered:.0f} offered)"
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs per figure; the median is reported")
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each 30 Hz latency run")
    parser.add_argument("--throughput-seconds", type=float, default=3.0, help="length of each back-to-back run")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    cores = os.cpu_count()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cores
    print(f"cores: {cores} (usable by this process: {usable}); python {sys.version.split()[0]}; frame {WIDTH}x{HEIGHT} RGB-D")
    print(f"each figure: median of {args.runs} runs; load average before: {os.getloadavg()[0]:.2f}\n")
    frame = make_frame()
    for label, scale in (("float32 depth", None), ("uint16 depth, depth_scale 1000", 1000.0)):
        size = sum(len(f) for f in codec.encode(frame, depth_scale=scale))
        codec_runs = [bench_codec(frame, scale) for _ in range(args.runs)]
        enc = statistics.median(r[0] for r in codec_runs)
        dec = statistics.median(r[1] for r in codec_runs)
        print(f"== {label}: {size / 2**20:.2f} MiB on the wire")
        print(f"codec: encode {enc:.2f} ms, decode {dec:.2f} ms")
        print(f"ipc:   {transport_figures(False, scale, args)}")
        print(f"peer:  {transport_figures(True, scale, args)}  [plain pyzmq, raw buffers]\n")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
