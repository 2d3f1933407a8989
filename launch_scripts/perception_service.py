"""Run the perception service: frames in, mesh estimates out, control requests answered.

    python -m launch_scripts.perception_service [--frames EP] [--estimates EP] [--control EP]
        [--preset {paper,realtime}] [--features KIND] [tracker options]
        [--no-auto-init] [--reinit-after-lost N] [--viewer | --viewer-save FILE.rrd]
        [--curve-keys DIR] [--insecure]

Endpoints default to ipc.endpoints (loopback); binding an address other machines can reach
needs --curve-keys (or --insecure). The protocol and the service's states are
in docs/protocol.md, section "Services". Ctrl-C or SIGTERM stops cleanly. Bad arguments
end with exit status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading

from ipc import endpoints
from ipc.transport import STALE_AFTER_S
from launch_scripts.cli import (
    OneLineParser,
    add_log_level_argument,
    add_print_endpoints_argument,
    add_security_arguments,
    add_tracker_arguments,
    configure_logging,
    curve_keys_from_args,
    endpoint,
    stop_on_signals,
    tracker_config_from_args,
)
from perception.service import PerceptionService, ServiceConfig


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m launch_scripts.perception_service", description=__doc__.split("\n\n")[0])
    g = p.add_argument_group("endpoints")
    g.add_argument("--frames", type=endpoint, default=endpoints.FRAMES,
                   help=f"frame publisher to connect to (default {endpoints.FRAMES})")
    g.add_argument("--estimates", type=endpoint, default=endpoints.ESTIMATES,
                   help=f"endpoint to publish estimates on (default {endpoints.ESTIMATES})")
    g.add_argument("--control", type=endpoint, default=endpoints.PERCEPTION_CONTROL,
                   help=f"endpoint to answer control requests on (default {endpoints.PERCEPTION_CONTROL})")
    add_print_endpoints_argument(g, '{"frames": ..., "estimates": ..., "control": ...}')
    g = p.add_argument_group("behaviour")
    g.add_argument("--no-auto-init", action="store_true",
                   help="wait for an InitialiseRequest instead of initialising on the first frame")
    g.add_argument("--reinit-after-lost", type=int, default=0, metavar="N",
                   help="re-initialise after N consecutive lost or rejected frames (default 0: never)")
    g.add_argument("--stale-after-s", type=float, default=STALE_AFTER_S,
                   help=f"seconds of silence after which the frame source counts as gone (default {STALE_AFTER_S:g})")
    g.add_argument("--viewer", action="store_true", help="show frames and meshes live in a Rerun viewer (rerun-sdk)")
    g.add_argument("--viewer-save", metavar="FILE.rrd", help="save the Rerun recording to a file instead")
    add_log_level_argument(g)
    add_tracker_arguments(p)  # the same options as the offline command, python -m perception.track
    add_security_arguments(p)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.no_auto_init and args.reinit_after_lost:
        parser.error("--reinit-after-lost re-initialises by itself, which --no-auto-init rules out: give one of them")
    configure_logging(args.log_level)
    stop = threading.Event()
    stop_on_signals(stop)
    viewer = "spawn" if args.viewer else args.viewer_save
    try:
        curve = curve_keys_from_args(args, [args.estimates, args.control])
        config = ServiceConfig(frames=args.frames, estimates=args.estimates, control=args.control,
                               auto_init=not args.no_auto_init, reinit_after_lost=args.reinit_after_lost,
                               stale_after_s=args.stale_after_s, viewer=viewer, curve=curve)
        service = PerceptionService(tracker_config_from_args(args), config)
    except (ValueError, RuntimeError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    with service:
        if args.print_endpoints:
            print(json.dumps(service.endpoints), flush=True)
        service.run(stop)
    return 0


if __name__ == "__main__":
    sys.exit(main())
