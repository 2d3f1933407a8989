"""Start a whole perception pipeline on loopback: frame source -> perception service -> monitor.

    python -m launch_scripts.pipeline [options] SOURCE [source options]

SOURCE and its options are those of ``python -m launch_scripts.publish_frames``, e.g.

    python -m launch_scripts.pipeline --preset realtime sim --scene towel_sway --loop
    python -m launch_scripts.pipeline sequence SEQ --loop --pacing rate --rate-hz 10

Two child processes are started (the frame publisher, then the perception service) and
this process monitors them: it prints a summary of the newest estimate every
--print-period-s and the service's status every --status-period-s. By default every
endpoint is a free loopback port; --default-endpoints uses the fixed ones of ipc.endpoints
so that a controller can connect to known ports. The first line on stdout is the endpoints
as one JSON object, {"frames": ..., "estimates": ..., "control": ...}; the lines after it
are for a person.

Ctrl-C (or SIGTERM) stops everything; when a child ends, the others are stopped too.
Children never outlive this process: they are stopped on every exit path, and on Linux
the kernel sends them SIGTERM if this process dies without cleaning up.
Exit status: 0 after Ctrl-C, --duration-s, or the source's normal end; 1 if a child failed.
"""

from __future__ import annotations

import argparse
import json
import shlex
import signal
import sys
import threading
import time

from ipc import endpoints
from ipc.messages import MeshEstimate, StatusReply, StatusRequest
from ipc.transport import CurveKeys, RemoteError, RequestClient, RequestTimeout, Subscriber
from launch_scripts.cli import OneLineParser, stop_on_signals
from launch_scripts.processes import Children

FREE_PORT = "tcp://127.0.0.1:*"
#: Seconds a child gets to bind its sockets (imports of NumPy, OpenCV, PyBullet included).
STARTUP_TIMEOUT_S = 60.0


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m launch_scripts.pipeline", description=__doc__.split("\n\n")[0],
                                usage="%(prog)s [options] SOURCE [source options]")
    p.add_argument("--default-endpoints", action="store_true", help="bind the fixed ports of ipc.endpoints")
    p.add_argument("--preset", choices=("paper", "realtime"), default="realtime", help="tracker preset (default realtime)")
    p.add_argument("--features", help="feature detector, overrides the preset")
    p.add_argument("--no-auto-init", action="store_true", help="the service waits for an InitialiseRequest")
    p.add_argument("--reinit-after-lost", type=int, default=0, metavar="N",
                   help="re-initialise after N consecutive lost frames (default 0: never)")
    p.add_argument("--viewer", action="store_true", help="live Rerun viewer in the service (rerun-sdk)")
    p.add_argument("--service-args", default="", help="more perception_service options, one quoted string")
    p.add_argument("--print-period-s", type=float, default=1.0, help="seconds between estimate lines (default 1)")
    p.add_argument("--status-period-s", type=float, default=2.0, help="seconds between status lines (default 2)")
    p.add_argument("--duration-s", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--curve-keys", metavar="DIR",
                   help="CURVE on every socket, the children's and this monitor's: a key directory made by "
                        "python -m launch_scripts.curve_keys")
    p.add_argument("source", nargs=argparse.REMAINDER, help="SOURCE [options] for launch_scripts.publish_frames")
    return p


def describe(estimate: MeshEstimate) -> str:
    """One line for a person about an estimate."""
    z = estimate.vertices[:, 2]
    return (f"estimate seq {estimate.seq}: {len(estimate.vertices)} vertices at z {z.min():.3f}..{z.max():.3f} m, "
            f"confidence {estimate.confidence:.2f}{', LOST' if estimate.lost else ''}, {estimate.timing_ms:.1f} ms")


def describe_status(status: StatusReply) -> str:
    """One line for a person about the perception service's StatusReply."""
    latency = "none" if status.latency_ms_median is None else f"{status.latency_ms_median:.1f} ms"
    line = (f"status: {status.state}, {status.frames_processed} frames since init; source {status.source}, "
            f"{status.frames_received} frames in, {status.frames_tracked} tracked, {status.frames_dropped} dropped, "
            f"{status.frames_rejected} rejected; median latency {latency}")
    return f"{line}; {status.message}" if status.message else line


def monitor(ends: dict, procs: dict, stop: threading.Event, args, curve: CurveKeys | None = None) -> int:
    """Print estimates and status until ``stop``, ``--duration-s`` or a child's end; returns the exit status."""
    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    next_print = next_status = time.monotonic()
    client = curve.client if curve is not None else None
    with Subscriber(ends["estimates"], accept=(MeshEstimate,), curve=client) as estimates, \
            RequestClient(ends["control"], timeout_s=1.0, attempts=1, curve=client) as control:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            for name, proc in procs.items():
                if proc.poll() is not None:
                    print(f"{name} exited with status {proc.returncode}; stopping the pipeline", flush=True)
                    return 0 if (name == "frame source" and proc.returncode == 0) else 1
            estimate = estimates.recv_latest(timeout_s=0.1)
            now = time.monotonic()
            if estimate is not None and now >= next_print:
                print(describe(estimate), flush=True)
                next_print = now + args.print_period_s
            if now >= next_status:
                next_status = now + args.status_period_s
                try:
                    status = control.request(StatusRequest())
                    print(describe_status(status), flush=True)
                except (RequestTimeout, RemoteError) as e:
                    print(f"status: no answer ({e})", flush=True)
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if not args.source:
        build_parser().error("a SOURCE is required (sim, sequence, realsense, kinect or rosbag)")
    try:
        curve = CurveKeys.from_directory(args.curve_keys) if args.curve_keys else None
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    security = ["--curve-keys", args.curve_keys] if curve is not None else []
    stop = threading.Event()
    stop_on_signals(stop, (signal.SIGTERM,))
    ports = {"frames": endpoints.FRAMES, "estimates": endpoints.ESTIMATES, "control": endpoints.PERCEPTION_CONTROL}
    if not args.default_endpoints:
        ports = dict.fromkeys(ports, FREE_PORT)
    children = Children(log_dir=None, startup_timeout_s=STARTUP_TIMEOUT_S)  # their messages go to this stderr
    try:
        bound = children.start("frame source", "launch_scripts.publish_frames",
                               [*args.source, "--endpoint", ports["frames"], "--print-endpoints", *security])
        service_args = ["--frames", bound["frames"], "--estimates", ports["estimates"], "--control", ports["control"],
                        "--print-endpoints", "--preset", args.preset, "--reinit-after-lost", str(args.reinit_after_lost),
                        *security]
        service_args += ["--features", args.features] if args.features else []
        service_args += ["--no-auto-init"] if args.no_auto_init else []
        service_args += ["--viewer"] if args.viewer else []
        ends = children.start("perception service", "launch_scripts.perception_service",
                              service_args + shlex.split(args.service_args))
        # The first line, as perception_service --print-endpoints prints it: a controller parses it.
        print(json.dumps({name: ends[name] for name in ("frames", "estimates", "control")}), flush=True)
        return monitor(ends, children.procs, stop, args, curve)
    except KeyboardInterrupt:
        return 0
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    finally:
        children.stop_all()


if __name__ == "__main__":
    sys.exit(main())
