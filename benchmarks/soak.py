"""Soak: the pipeline at 30 Hz with a planning client, for a long time, on flat memory?

    python benchmarks/soak.py --duration-s 3600 --output soak.json [--sample-period-s 5] [--warmup-s 60]

Starts, as separate processes on loopback, ``launch_scripts.pipeline`` (a frame publisher
looping a recorded sequence at 30 Hz, and a perception service with the realtime preset)
and ``launch_scripts.planner_service`` on the pipeline's estimates and frames. This process
is the client: a GraspRequest every --plan-period-s (default 1 s) and a StatusRequest
every --status-period-s (default 5 s). The sequence is a textured sheet rendered at 640 x
480 moving forth and back (tests.render), written to a temporary folder first.

Every --sample-period-s the resident memory (VmRSS) of every process is sampled: the
pipeline, its two children, the planner and this client. The summary (JSON, and a table
on stdout) gives per process the RSS after the warm-up, at the end, the largest, and the
growth after the warm-up (end minus start, and the slope of a least-squares line through
the samples, MB per hour) and every sample (seconds, MB); the service's counters at the
end; and the requests answered, refused and unanswered. Exit status 0 when every process lived to the end, 1 otherwise.
Run it on a quiet machine; it needs about 1.3 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ipc.messages import CameraInfo, GraspPlanReply, GraspRequest, StatusRequest  # noqa: E402
from ipc.transport import RemoteError, RequestClient, RequestTimeout  # noqa: E402
from perception.sequence import SequenceWriter  # noqa: E402
from tests.render import frame_of, grid_surface, plane_points, texture  # noqa: E402

CYCLE = 30  # frames of one forth-and-back movement of the sheet
STARTUP_TIMEOUT_S = 120.0


def write_sequence(path: Path) -> Path:
    """A 640 x 480 sequence of a textured 0.6 x 0.45 m sheet, 1.3 m away, moving forth and back."""
    cam = CameraInfo.from_fov(640, 480, np.deg2rad(45))
    size, centre, step = (0.6, 0.45), np.array([0.0, 0.0, 1.3]), np.array([0.006, -0.003, 0.004])
    uv, faces = grid_surface(*size, 31, 24)
    tex = texture(np.random.default_rng(7))
    with SequenceWriter(path, cam, depth_scale=1000.0) as writer:
        for k in range(CYCLE):
            phase = k if k <= CYCLE // 2 else CYCLE - k
            writer.write(frame_of(plane_points(uv, centre + step * phase, size), uv, faces, tex, cam, size, t=k / 30,
                                  seq=k, noise_m=0.001, rng=np.random.default_rng(k)))
    return path


def rss_mb(pid: int) -> float | None:
    """Resident memory of a process, MB (2^20 bytes); None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(p) for p in f.read().split()]
    except FileNotFoundError:
        return []


def command_of(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            parts = f.read().split(b"\0")
        return next((p.decode() for p in parts if p.startswith(b"launch_scripts.")), parts[0].decode())
    except FileNotFoundError:
        return "?"


def start(args: list[str]) -> tuple[subprocess.Popen, dict]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", *args], stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                            cwd=REPO, env=env)
    line = proc.stdout.readline()
    if not line.startswith("{"):
        proc.kill()
        raise RuntimeError(f"{args[0]} did not start: {line!r}")
    return proc, json.loads(line)


def slope_mb_per_hour(times_s: list[float], values: list[float]) -> float | None:
    if len(values) < 3:
        return None
    return float(np.polyfit(np.asarray(times_s) / 3600.0, np.asarray(values), 1)[0])


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration-s", type=float, default=3600.0)
    p.add_argument("--warmup-s", type=float, default=60.0, help="excluded from the growth figures (default 60)")
    p.add_argument("--sample-period-s", type=float, default=5.0)
    p.add_argument("--plan-period-s", type=float, default=1.0)
    p.add_argument("--status-period-s", type=float, default=5.0)
    p.add_argument("--rate-hz", type=float, default=30.0)
    p.add_argument("--output", type=Path, help="write the summary as JSON here")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    procs: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory(prefix="soak-") as tmp:
        sequence = write_sequence(Path(tmp) / "sheet")
        try:
            pipeline, ends = start(["launch_scripts.pipeline", "--preset", "realtime", "--print-period-s", "3600",
                                    "--status-period-s", "3600", "sequence", str(sequence), "--loop", "--pacing", "rate",
                                    "--rate-hz", f"{args.rate_hz:g}"])
            procs.append(pipeline)
            planner, planner_end = start(["launch_scripts.planner_service", "--estimates", ends["estimates"], "--frames",
                                          ends["frames"], "--bind", "tcp://127.0.0.1:*", "--print-endpoint",
                                          "--log-level", "WARNING"])
            procs.append(planner)
            summary = soak(args, ends, planner_end["planner"], pipeline, planner)
        finally:
            for proc in procs:
                proc.terminate()
            for proc in procs:
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    report(summary)
    if args.output is not None:
        args.output.write_text(json.dumps(summary, indent=2) + "\n")
    return 0 if summary["all_alive"] else 1


def soak(args, ends: dict, planner_endpoint: str, pipeline: subprocess.Popen, planner: subprocess.Popen) -> dict:
    pids = {"pipeline (monitor)": pipeline.pid, "planner_service": planner.pid, "soak client": os.getpid()}
    for child in children(pipeline.pid):
        pids[command_of(child)] = child
    samples: dict[str, list] = {name: [] for name in pids}
    requests = {"plans": 0, "plans_with_candidates": 0, "not_ready": 0, "other_errors": 0, "timeouts": 0, "status": 0}
    status = None
    start = time.monotonic()
    next_sample = next_plan = next_status = start
    with RequestClient(planner_endpoint, timeout_s=1.0, attempts=3) as plan_client, \
            RequestClient(ends["control"], timeout_s=1.0, attempts=3) as control:
        while (now := time.monotonic()) - start < args.duration_s:
            if pipeline.poll() is not None or planner.poll() is not None:
                break
            if now >= next_sample:
                next_sample += args.sample_period_s
                for name, pid in pids.items():
                    mb = rss_mb(pid)
                    if mb is not None:
                        samples[name].append((now - start, mb))
            if now >= next_plan:
                next_plan += args.plan_period_s
                try:
                    reply = plan_client.request(GraspRequest(max_candidates=5))
                    requests["plans"] += 1
                    requests["plans_with_candidates"] += isinstance(reply, GraspPlanReply) and bool(reply.candidates)
                except RemoteError as e:
                    requests["not_ready" if e.code == "not_ready" else "other_errors"] += 1
                except RequestTimeout:
                    requests["timeouts"] += 1
            if now >= next_status:
                next_status += args.status_period_s
                try:
                    status = control.request(StatusRequest())
                    requests["status"] += 1
                except (RemoteError, RequestTimeout):
                    requests["timeouts"] += 1
            time.sleep(max(0.0, min(next_sample, next_plan, next_status) - time.monotonic()))
    elapsed = time.monotonic() - start
    processes = {}
    for name, series in samples.items():
        after = [(t, mb) for t, mb in series if t >= min(args.warmup_s, elapsed / 2)]
        if not after:
            continue
        times, values = zip(*after)
        processes[name] = {"rss_mb_after_warmup": round(values[0], 1), "rss_mb_end": round(values[-1], 1),
                           "rss_mb_max": round(max(mb for _, mb in series), 1),
                           "growth_mb": round(values[-1] - values[0], 1),
                           "slope_mb_per_hour": None if (s := slope_mb_per_hour(times, values)) is None else round(s, 2),
                           "samples": [[round(t, 1), round(mb, 2)] for t, mb in series]}
    counters = None
    if status is not None:
        counters = {k: getattr(status, k) for k in ("state", "frames_received", "frames_tracked", "frames_dropped",
                                                    "frames_rejected", "rejected_by_kind", "messages_malformed",
                                                    "reinitialisations", "latency_ms_median", "latency_ms_p99",
                                                    "tracking_ms_median")}
    return {"duration_s": round(elapsed, 1), "requested_duration_s": args.duration_s, "warmup_s": args.warmup_s,
            "rate_hz": args.rate_hz, "cores": os.cpu_count(), "machine": platform.machine(),
            "python": platform.python_version(), "all_alive": pipeline.poll() is None and planner.poll() is None,
            "processes": processes, "requests": requests, "service_status": counters}


def report(summary: dict) -> None:
    print(f"soak: {summary['duration_s']:.0f} s at {summary['rate_hz']:g} Hz on {summary['cores']} cores; "
          f"all processes alive: {summary['all_alive']}")
    print(f"{'process':<36} {'after warm-up':>14} {'end':>8} {'max':>8} {'growth':>8} {'MB/h':>8}")
    for name, p in summary["processes"].items():
        slope = "-" if p["slope_mb_per_hour"] is None else f"{p['slope_mb_per_hour']:.1f}"
        print(f"{name:<36} {p['rss_mb_after_warmup']:>14.1f} {p['rss_mb_end']:>8.1f} {p['rss_mb_max']:>8.1f} "
              f"{p['growth_mb']:>8.1f} {slope:>8}")
    print(f"requests: {summary['requests']}")
    print(f"service: {summary['service_status']}")


if __name__ == "__main__":
    sys.exit(main())
