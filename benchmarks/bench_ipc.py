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

Each figure is the median over ``--runs`` runs. Targets: p99 <= 5 ms at 30 Hz,
>= 300 frames/s delivered.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing as mp
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ipc import codec  # noqa: E402
from ipc.messages import CameraInfo, RGBDFrame  # noqa: E402
from ipc.transport import Publisher, Subscriber  # noqa: E402

WIDTH, HEIGHT = 640, 480
WARMUP_SEQ = -1


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


def publisher_process(endpoints, go, done, depth_scale, rate_hz, amount, report) -> None:
    """Publish warm-up frames until ``go``, then measured frames.

    rate_hz > 0: ``amount`` frames at ``rate_hz``, each stamped with the clock as it is
    built. rate_hz == 0: the same prebuilt frame back to back for ``amount`` seconds.
    Puts the send rate (frames/s) on ``report``.
    """
    base = make_frame()
    with Publisher("tcp://127.0.0.1:*", source="bench", depth_scale=depth_scale) as pub:
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


def transport_run(depth_scale: float | None, rate_hz: float, amount: float) -> dict:
    """One run with a fresh publisher process (see ``publisher_process``).

    Returns latencies (s, rate_hz > 0 only), frames received, delivered and sent rates.
    """
    ctx = mp.get_context("spawn")
    endpoints, report = ctx.Queue(), ctx.Queue()
    go, done = ctx.Event(), ctx.Event()
    proc = ctx.Process(target=publisher_process, args=(endpoints, go, done, depth_scale, rate_hz, amount, report), daemon=True)
    proc.start()
    try:
        with Subscriber(endpoints.get(timeout=30.0), accept=(RGBDFrame,)) as sub:
            while (msg := sub.recv_latest(timeout_s=10.0)) is not None and msg.seq != WARMUP_SEQ:
                pass
            if msg is None:
                raise RuntimeError("no warm-up frame from the publisher")
            go.set()
            latencies, first, last, received = [], None, None, 0
            while received < (amount if rate_hz else math.inf):
                msg = sub.recv_latest(timeout_s=1.0)
                if msg is None:
                    break  # the publisher has finished (or died)
                now = time.perf_counter()
                if msg.seq == WARMUP_SEQ:
                    continue
                if rate_hz:
                    latencies.append(now - msg.timestamp_s)
                first = now if first is None else first
                last, received = now, received + 1
            send_rate = report.get(timeout=30.0)
    finally:
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs per figure; the median is reported")
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each 30 Hz latency run")
    parser.add_argument("--throughput-seconds", type=float, default=3.0, help="length of each back-to-back run")
    args = parser.parse_args(argv)

    cores = os.cpu_count()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cores
    print(f"cores: {cores} (usable by this process: {usable}); python {sys.version.split()[0]}; frame {WIDTH}x{HEIGHT} RGB-D")
    print(f"each figure: median of {args.runs} runs\n")
    frame = make_frame()
    print(f"load average before: {os.getloadavg()[0]:.2f} (other processes compete for the cores)\n")
    for label, scale in (("float32 depth", None), ("uint16 depth, depth_scale 1000", 1000.0)):
        size = sum(len(f) for f in codec.encode(frame, depth_scale=scale))
        codec_runs = [bench_codec(frame, scale) for _ in range(args.runs)]
        enc = statistics.median(r[0] for r in codec_runs)
        dec = statistics.median(r[1] for r in codec_runs)
        lat_runs = [transport_run(scale, 30.0, int(30.0 * args.seconds)) for _ in range(args.runs)]
        p50 = statistics.median(1e3 * np.percentile(r["latencies"], 50) for r in lat_runs)
        p99 = statistics.median(1e3 * np.percentile(r["latencies"], 99) for r in lat_runs)
        lost = sum(int(30.0 * args.seconds) - r["received"] for r in lat_runs)
        thr_runs = [transport_run(scale, 0.0, args.throughput_seconds) for _ in range(args.runs)]
        fps = statistics.median(r["delivered_fps"] for r in thr_runs)
        send = statistics.median(r["send_fps"] for r in thr_runs)
        print(f"== {label}: {size / 2**20:.2f} MiB on the wire")
        print(f"codec:      encode {enc:.2f} ms, decode {dec:.2f} ms (median of {args.runs} x 200)")
        print(
            f"30 Hz:      latency p50 {p50:.2f} ms, p99 {p99:.2f} ms over {int(30 * args.seconds)} frames per run; frames lost in all runs: {lost}"
        )
        print(
            f"throughput: {fps:.0f} frames/s delivered and decoded ({send:.0f} frames/s offered, {args.throughput_seconds:g} s per run)\n"
        )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
