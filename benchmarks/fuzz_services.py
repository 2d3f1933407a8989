"""Fuzz the running services: malformed and hostile messages on every socket, oversize
messages and multipart bombs, then check that every service still serves.

    python benchmarks/fuzz_services.py [--messages 100000] [--runs 2] [--bomb-frames 16] [--output FUZZ.json]

Starts ``launch_scripts.perception_service`` (realtime preset) on a frame stream this
process publishes, and ``launch_scripts.planner_service`` on the service's estimates and the
same frames, as separate processes on loopback. Each run sends --messages messages:

- on the frame stream (80 %): frames of a rendered sheet, hostile frames that decode
  (tests.fuzz_frames: huge, tiny, NaN depth, degenerate intrinsics, changing sizes) and
  messages that do not (tests.unit.test_ipc_fuzz's mutations of every message type:
  random bytes, truncations, hostile values in every field), paced so that the service's
  subscriber takes them all;
- on the control socket (10 %) and the planner socket (10 %): the same mutations of
  requests, parameter changes and initialisation masks in and out of range, and valid
  requests; every request must be answered within --timeout-s.

Then, on each socket: one frame over the 64 MiB cap (the subscriptions must receive
frames again, timed; the REP sockets give no reply, and must answer the next request),
and a multipart bomb of --bomb-frames frames of 60 MiB (answered ErrorReply on REP). The
resident memory of both services is sampled every 20 ms throughout.

Reports, per run: messages sent and taken by the services, requests answered and their
replies by type, unanswered requests, ``internal`` rejections and errors, the services'
memory after the run (the second run shows whether the first left anything behind) and at
its peak during the bombs, and the time until frames flowed again after each oversize
message. Exit status 1 if a service died, a request went unanswered (other than the
oversize ones), or an ``internal`` rejection or error happened.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import msgpack
import numpy as np
import zmq

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ipc import messages as m  # noqa: E402
from ipc.codec import encode  # noqa: E402
from ipc.examples import example_messages  # noqa: E402
from perception.parameters import tracker_parameters  # noqa: E402
from perception.tracker import TrackerConfig  # noqa: E402
from tests.fuzz_frames import FrameFuzzer, sheet_frames  # noqa: E402
from tests.unit.test_ipc_fuzz import CORPUS, hostile_values, paths, replaced  # noqa: E402

CAP = 64 * 2**20
BOMB_FRAME = 60 * 2**20
FRAME_RATE_HZ = 1500.0  # hostile frames per second on the stream: slower than the subscriber decodes them


def rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) / 1024.0 for line in f if line.startswith("VmRSS:"))
    except (FileNotFoundError, StopIteration):
        return float("nan")


class MemoryWatch:
    """Samples the RSS of some processes every 20 ms on a thread; ``peak`` per name since ``reset``."""

    def __init__(self, pids: dict):
        self.pids, self.peak = pids, dict.fromkeys(pids, 0.0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.wait(0.02):
            for name, pid in self.pids.items():
                self.peak[name] = max(self.peak[name], rss_mb(pid))

    def reset(self):
        self.peak = dict.fromkeys(self.pids, 0.0)

    def close(self):
        self._stop.set()
        self._thread.join()


class Mutator:
    """Malformed messages from valid encodings of every type: structured mutations of the
    header, random bytes, truncations, buffer frames cut or added."""

    def __init__(self, rng: np.random.Generator, corpus: list):
        self.rng = rng
        self.corpus = [(msgpack.unpackb(frames[0], strict_map_key=False), frames) for frames in corpus]

    def __call__(self) -> list:
        rng = self.rng
        top, frames = self.corpus[int(rng.integers(len(self.corpus)))]
        roll = rng.random()
        if roll < 0.1:
            return [rng.bytes(int(rng.integers(0, 200)))]
        if roll < 0.2:
            return [frames[0][: int(rng.integers(0, len(frames[0])))], *frames[1:]]
        if roll < 0.3 and len(frames) > 1:
            cut = [bytes(f) for f in frames]
            cut[-1] = cut[-1][: max(0, len(cut[-1]) - int(rng.integers(1, 9)))]
            return cut
        all_paths = list(paths(top))
        values = hostile_values(rng)
        mutant = replaced(top, all_paths[int(rng.integers(len(all_paths)))], values[int(rng.integers(len(values)))])
        try:
            return [msgpack.packb(mutant, use_bin_type=True), *frames[1:]]
        except (OverflowError, ValueError, TypeError):
            return [rng.bytes(16)]


def corpus_of(*types) -> list:
    return [frames for frames in CORPUS if msgpack.unpackb(frames[0], strict_map_key=False).get("type") in types]


def start(args: list[str], log) -> tuple[subprocess.Popen, dict]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", *args], stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, stderr=log,
                            text=True, cwd=REPO, env=env)
    line = proc.stdout.readline()
    if not line.startswith("{"):
        proc.kill()
        raise RuntimeError(f"{args[0]} did not start: {line!r}")
    return proc, json.loads(line)


class Requester:
    """REQ client that sends raw frames and decodes the reply's type; a new socket after a timeout."""

    def __init__(self, endpoint: str, timeout_s: float):
        self.endpoint, self.timeout_ms = endpoint, int(1000 * timeout_s)
        self.sock = None
        self.reply_s: list[float] = []  # how long each answered request waited for its reply

    def send(self, frames) -> str | None:
        """The reply's type (and error code), or None without a reply in time."""
        if self.sock is None:
            self.sock = zmq.Context.instance().socket(zmq.REQ)
            self.sock.setsockopt(zmq.LINGER, 0)
            self.sock.connect(self.endpoint)
        t0 = time.monotonic()
        self.sock.send_multipart(frames, copy=False)
        if not self.sock.poll(self.timeout_ms):
            self.sock.close(linger=0)
            self.sock = None
            return None
        reply = msgpack.unpackb(self.sock.recv_multipart()[0], strict_map_key=False)
        self.reply_s.append(time.monotonic() - t0)
        if reply["type"] == "ErrorReply":
            return f"ErrorReply:{reply['fields']['code']}"
        return reply["type"]

    def close(self):
        if self.sock is not None:
            self.sock.close(linger=0)


def status(control: Requester) -> m.StatusReply:
    from ipc.codec import decode

    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(control.endpoint)
    try:
        sock.send_multipart(encode(m.StatusRequest()))
        if not sock.poll(5000):
            raise TimeoutError("no StatusReply within 5 s")
        return decode(sock.recv_multipart())
    finally:
        sock.close(linger=0)


def frames_flow_again(pub: zmq.Socket, control: Requester, good: list, timeout_s: float = 10.0) -> float | None:
    """Seconds until the service receives a frame again (frames sent at 30 Hz meanwhile), or None."""
    before = status(control)
    count = before.frames_received + before.messages_malformed
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < timeout_s:
        pub.send_multipart(good[k % len(good)])
        k += 1
        time.sleep(1 / 30)
        now = status(control)
        if now.frames_received + now.messages_malformed > count:
            return time.monotonic() - t0
    return None


def fuzz_run(run: int, args, pub, control, planner, procs, watch) -> dict:
    rng = np.random.default_rng(args.seed + run)
    sheet = sheet_frames()
    good_frames = [encode(f, depth_scale=1000.0) for f in sheet]
    frames_fuzz = FrameFuzzer(args.seed + run, tracker_parameters(TrackerConfig.realtime()), sheet).events(10**9)
    mutate_frame = Mutator(rng, corpus_of("RGBDFrame", "Heartbeat", "MeshEstimate"))
    mutate_control = Mutator(rng, corpus_of("InitialiseRequest", "ResetRequest", "SetParametersRequest", "StatusRequest",
                                            "GraspRequest"))
    mutate_planner = Mutator(rng, corpus_of("GraspRequest"))
    examples = example_messages()
    replies = {"control": Counter(), "planner": Counter()}
    sent = Counter()
    unanswered = Counter()
    t_run = time.monotonic()
    next_frame = time.monotonic()
    for i in range(args.messages):
        roll = rng.random()
        if roll < 0.8:
            kind = rng.random()
            if kind < 0.3:
                frames = good_frames[i % len(good_frames)]
            elif kind < 0.65:
                event, value = next(frames_fuzz)
                while event != "frame":
                    event, value = next(frames_fuzz)
                frames = encode(value)
            else:
                frames = mutate_frame()
            next_frame += 1.0 / FRAME_RATE_HZ
            time.sleep(max(0.0, next_frame - time.monotonic()))
            pub.send_multipart(frames, copy=False)
            sent["frames"] += 1
            continue
        target = "control" if roll < 0.9 else "planner"
        if target == "control":
            kind = rng.random()
            if kind < 0.5:
                frames = mutate_control()
            else:
                event, value = next(frames_fuzz)
                while event == "frame":
                    event, value = next(frames_fuzz)
                msg = (m.SetParametersRequest(parameters=value) if event == "parameters"
                       else m.InitialiseRequest(mask=value) if value is None or value.any() else m.ResetRequest())
                frames = encode(msg)
            reply = control.send(frames)
        else:
            frames = mutate_planner() if rng.random() < 0.7 else encode(examples[m.GraspRequest])
            reply = planner.send(frames)
        sent[target] += 1
        if reply is None:
            unanswered[target] += 1
        else:
            replies[target][reply] += 1
    fuzz_s = time.monotonic() - t_run
    reply_ms = {name: {"median": round(1000 * float(np.median(r.reply_s)), 1),
                       "p99": round(1000 * float(np.percentile(r.reply_s, 99)), 1),
                       "max": round(1000 * max(r.reply_s), 1)}
                for name, r in (("control", control), ("planner", planner)) if r.reply_s}
    control.reply_s.clear()
    planner.reply_s.clear()
    time.sleep(1.0)
    after = status(control)

    # Oversize single frames: the subscriptions reconnect; REP sockets drop the request.
    recoveries = []
    for _ in range(args.oversize):
        pub.send(b"x" * (CAP + 1))
        recoveries.append(frames_flow_again(pub, control, good_frames))
    oversize_rep = {}
    for name, requester in (("control", control), ("planner", planner)):
        no_reply = requester.send([b"x" * (CAP + 1)]) is None
        next_reply = requester.send(encode(m.StatusRequest() if name == "control" else examples[m.GraspRequest]))
        oversize_rep[name] = {"no_reply": no_reply, "next_request": next_reply}

    # Multipart bombs: every frame under the cap, the whole message far over it.
    bomb = [encode(m.StatusRequest())[0]] + [b"b" * BOMB_FRAME] * (args.bomb_frames - 1)
    watch.reset()
    bombs = {"frames": None}
    pub.send_multipart(bomb, copy=False)
    bombs["frames_flow_again_s"] = frames_flow_again(pub, control, good_frames)
    for name, requester in (("control", control), ("planner", planner)):
        bombs[name] = requester.send(bomb)
    time.sleep(0.5)
    bombs["peak_rss_mb"] = {k: round(v, 1) for k, v in watch.peak.items()}
    bombs.pop("frames")
    final = status(control)
    alive = {name: proc.poll() is None for name, proc in procs.items()}
    return {
        "run": run, "fuzz_s": round(fuzz_s, 1), "sent": dict(sent), "unanswered": dict(unanswered),
        "replies": {k: dict(v) for k, v in replies.items()}, "reply_ms": reply_ms,
        "service_after_fuzz": {"frames_received": after.frames_received, "messages_malformed": after.messages_malformed,
                               "frames_tracked": after.frames_tracked, "frames_dropped": after.frames_dropped,
                               "rejected_by_kind": after.rejected_by_kind, "state": after.state},
        "internal": final.rejected_by_kind.get("internal", 0) + sum(r.get("ErrorReply:internal", 0) for r in replies.values()),
        "rss_mb_after_run": {name: round(rss_mb(proc.pid), 1) for name, proc in procs.items()},
        "oversize_frames_flow_again_s": [None if r is None else round(r, 3) for r in recoveries],
        "oversize_request": oversize_rep, "multipart_bomb": bombs, "alive": alive,
    }


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--messages", type=int, default=100_000)
    p.add_argument("--runs", type=int, default=2)
    p.add_argument("--oversize", type=int, default=5, help="oversize frames on the frame stream per run")
    p.add_argument("--bomb-frames", type=int, default=16)
    p.add_argument("--timeout-s", type=float, default=5.0, help="longest wait for a reply (default 5)")
    p.add_argument("--seed", type=int, default=20261130)
    p.add_argument("--output", type=Path)
    p.add_argument("--services-log", type=Path, default=Path(os.devnull), help="where the services' logs go")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    services_log = args.services_log.open("a")

    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.setsockopt(zmq.SNDHWM, 1000)
    frames_endpoint = f"tcp://127.0.0.1:{pub.bind_to_random_port('tcp://127.0.0.1')}"
    procs = {}
    results = []
    try:
        perception, ends = start(["launch_scripts.perception_service", "--frames", frames_endpoint, "--estimates",
                                  "tcp://127.0.0.1:*", "--control", "tcp://127.0.0.1:*", "--print-endpoints",
                                  "--preset", "realtime", "--reinit-after-lost", "5"], services_log)
        procs["perception_service"] = perception
        planner_proc, planner_end = start(["launch_scripts.planner_service", "--estimates", ends["estimates"], "--frames",
                                           frames_endpoint, "--bind", "tcp://127.0.0.1:*", "--print-endpoint",
                                           "--log-level", "ERROR"], services_log)
        procs["planner_service"] = planner_proc
        time.sleep(1.0)
        watch = MemoryWatch({name: proc.pid for name, proc in procs.items()})
        control, planner = Requester(ends["control"], args.timeout_s), Requester(planner_end["planner"], args.timeout_s)
        print(f"memory at start (MB): { {n: round(rss_mb(pr.pid), 1) for n, pr in procs.items()} }", flush=True)
        for run in range(args.runs):
            result = fuzz_run(run, args, pub, control, planner, procs, watch)
            results.append(result)
            print(json.dumps(result), flush=True)
            if not all(result["alive"].values()):
                break
        watch.close()
        control.close()
        planner.close()
    finally:
        for proc in procs.values():
            proc.terminate()
        for proc in procs.values():
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
        pub.close()
        services_log.close()
    if args.output is not None:
        args.output.write_text(json.dumps(results, indent=2) + "\n")
    ok = all(all(r["alive"].values()) and not r["internal"] and not sum(r["unanswered"].values()) for r in results)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
