"""Run the grasp planner service (``grasping.service``) until interrupted.

    python -m launch_scripts.planner_service [--estimates EP] [--bind EP] [--frames EP]
        [--kinds corner boundary highest] [--max-estimate-age-s S] [--edge-approach pinch|normal] [--pinch-inset-m M]
        [--T-world-cam 16 numbers] [--workspace-min X Y Z] [--workspace-max X Y Z]
        [--min-score S] [--min-confidence C] [--opening-width-m W] [--outline-window-spacings L]
        [--corner-max-angle-deg A] [--layer-thickness-m T] [--weight-single-layer W] [--print-endpoints]
        [--log-level LEVEL] [--curve-keys DIR] [--insecure]

It subscribes to the perception service's MeshEstimate stream (default
``ipc.endpoints.ESTIMATES``), optionally to the frame stream for the visibility and
single-layer terms,
and answers GraspRequest on a REP socket (default ``ipc.endpoints.PLANNER``) with
GraspPlanReply, best first, and AdjacentCornersRequest (the corners next to a held one,
whatever ``--kinds`` says) with AdjacentCornersReply, or either with ErrorReply:
``not_ready`` before the first estimate, ``invalid`` for a request it cannot serve,
``protocol`` for one it cannot decode; it keeps serving after every bad request.
``--bind tcp://127.0.0.1:*`` picks a free port; ``--print-endpoints`` prints
``{"planner": ENDPOINT}`` as one JSON line on stdout once serving (as
``perception_service --print-endpoints``). SIGINT and SIGTERM stop it cleanly (exit status
0). Bad arguments: one line on stderr, exit status 2. Binding an address other machines can
reach needs --curve-keys (or --insecure).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import threading

import numpy as np

from grasping._planner import EDGE_APPROACHES, GraspPlannerConfig
from grasping.service import PlannerCore, run_planner_service
from ipc import endpoints
from ipc.messages import GraspPlan
from launch_scripts.cli import (
    OneLineParser,
    add_log_level_argument,
    add_print_endpoints_argument,
    add_security_arguments,
    configure_logging,
    curve_keys_from_args,
    endpoint,
    endpoint_printer,
    finite_float,
    stop_on_signals,
)

log = logging.getLogger("launch_scripts.planner_service")


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m launch_scripts.planner_service", description=__doc__.split("\n\n")[0])
    p.add_argument("--estimates", type=endpoint, default=endpoints.ESTIMATES,
                   help=f"MeshEstimate publisher to connect to (default {endpoints.ESTIMATES})")
    p.add_argument("--bind", type=endpoint, default=endpoints.PLANNER,
                   help=f"REP endpoint to bind (default {endpoints.PLANNER})")
    p.add_argument("--frames", type=endpoint, default=None,
                   help="RGBDFrame publisher to connect to for the visibility term (default: none)")
    p.add_argument("--kinds", nargs="+", choices=GraspPlan.KINDS, default=list(GraspPlan.KINDS),
                   help="grasp kinds a GraspRequest may ask for (default: all); AdjacentCornersRequest is "
                        "answered whatever the kinds")
    p.add_argument("--max-estimate-age-s", type=finite_float, default=None,
                   help="answer not_ready when the newest estimate is older than this (default: any age)")
    defaults = GraspPlannerConfig()
    p.add_argument("--edge-approach", choices=EDGE_APPROACHES, default=defaults.edge_approach,
                   help=f"corner and boundary approach (default {defaults.edge_approach})")
    p.add_argument("--pinch-inset-m", type=finite_float, default=defaults.pinch_inset_m,
                   help=f"how far inside the outline edge grasps close, metres (default {defaults.pinch_inset_m})")
    p.add_argument("--T-world-cam", dest="T_world_cam", type=finite_float, nargs=16, default=None, metavar="T",
                   help="camera-to-world transform, 16 numbers row-major (default: world = camera frame)")
    p.add_argument("--workspace-min", type=finite_float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="lower corner of the reachable box, world frame, metres (default unbounded)")
    p.add_argument("--workspace-max", type=finite_float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="upper corner of the reachable box, world frame, metres (default unbounded)")
    p.add_argument("--up", type=finite_float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="up direction in the world frame (default z up with --T-world-cam, else image up)")
    p.add_argument("--min-score", type=finite_float, default=defaults.min_score, help="drop plans scoring lower (0-1)")
    p.add_argument("--min-confidence", type=finite_float, default=defaults.min_confidence,
                   help="no plans on estimates less confident (0-1)")
    p.add_argument("--opening-width-m", type=finite_float, default=defaults.opening_width_m,
                   help=f"finger opening, metres (default {defaults.opening_width_m})")
    p.add_argument("--outline-window-spacings", type=finite_float, default=defaults.outline_window_spacings,
                   help="half-length of the chords measuring the outline's turn, in mesh spacings "
                        f"(default {defaults.outline_window_spacings:g}); features shorter than ~1.5 times it are not resolved")
    p.add_argument("--corner-max-angle-deg", type=finite_float, default=math.degrees(defaults.corner_max_angle_rad),
                   help=f"largest interior angle of a corner, degrees (default {math.degrees(defaults.corner_max_angle_rad):g})")
    p.add_argument("--layer-thickness-m", type=finite_float, default=defaults.layer_thickness_m,
                   help="one layer of the cloth as the depth sensor sees it, metres: corners standing higher above the "
                        f"surface beyond score lower, as a fold's end (default {defaults.layer_thickness_m:g}; "
                        "--weight-single-layer 0 turns this off)")
    p.add_argument("--weight-single-layer", type=finite_float, default=defaults.weight_single_layer,
                   help=f"weight of that term in the score (default {defaults.weight_single_layer:g})")
    p.add_argument("--tip-search-radius-m", type=finite_float, default=defaults.tip_search_radius_m,
                   help="adjacent corners, when the frame is received (--frames): place each at the tip of the "
                        "measured surface beyond the estimate's corner when one lies within this distance, metres "
                        f"(default {defaults.tip_search_radius_m:g}: on the estimate alone)")
    p.add_argument("--tip-max-step-m", type=finite_float, default=defaults.tip_max_step_m,
                   help="largest depth step between neighbouring pixels of one surface in that search, metres "
                        f"(default {defaults.tip_max_step_m:g})")
    add_print_endpoints_argument(p, '{"planner": ENDPOINT}')
    add_log_level_argument(p, default="INFO")
    add_security_arguments(p)
    return p


def config_from_args(args) -> GraspPlannerConfig:
    """GraspPlannerConfig of the parsed options; raises ValueError (one line) for bad values."""
    kw = {"edge_approach": args.edge_approach, "pinch_inset_m": args.pinch_inset_m, "min_score": args.min_score,
          "min_confidence": args.min_confidence, "opening_width_m": args.opening_width_m,
          "outline_window_spacings": args.outline_window_spacings,
          "corner_max_angle_rad": math.radians(args.corner_max_angle_deg),
          "layer_thickness_m": args.layer_thickness_m, "weight_single_layer": args.weight_single_layer,
          "tip_search_radius_m": args.tip_search_radius_m, "tip_max_step_m": args.tip_max_step_m}
    if args.T_world_cam is not None:
        kw["T_world_cam"] = np.asarray(args.T_world_cam, dtype=np.float64).reshape(4, 4)
    if args.up is not None:
        kw["up_world"] = np.asarray(args.up)
    if args.workspace_min is not None:
        kw["workspace_min_world"] = np.asarray(args.workspace_min)
    if args.workspace_max is not None:
        kw["workspace_max_world"] = np.asarray(args.workspace_max)
    return GraspPlannerConfig(**kw)


#: The planner settings these options set (``config_from_args``); every other field of
#: GraspPlannerConfig keeps its default in the service.
OPTION_FIELDS = ("edge_approach", "pinch_inset_m", "T_world_cam", "workspace_min_world", "workspace_max_world",
                 "up_world", "min_score", "min_confidence", "opening_width_m", "outline_window_spacings",
                 "corner_max_angle_rad", "layer_thickness_m", "weight_single_layer", "tip_search_radius_m",
                 "tip_max_step_m")


def arguments_from_config(config: GraspPlannerConfig) -> list[str]:
    """The planner options (``build_parser``) that give a service ``config``: the inverse of
    ``config_from_args``, every number written exactly (shortest round trip, positional). ``config.kind`` is not
    among them: the kinds served are ``--kinds``.

    raises ValueError naming a field that differs from its default but has no option
    """
    defaults = GraspPlannerConfig()
    for f in dataclasses.fields(GraspPlannerConfig):
        if f.name in OPTION_FIELDS or f.name == "kind":
            continue
        if not np.array_equal(getattr(config, f.name), getattr(defaults, f.name)):
            raise ValueError(f"GraspPlannerConfig.{f.name}: the planner service has no option for it (it keeps "
                             f"{getattr(defaults, f.name)!r})")

    def numbers(values) -> list[str]:
        # positional, never "-1.2e-16": argparse takes a negative number in exponent notation
        # for an option and the list option before it ends short (a camera looking straight down)
        return [np.format_float_positional(float(v), unique=True, trim="0") for v in np.ravel(values)]

    argv = ["--edge-approach", config.edge_approach, "--pinch-inset-m", *numbers(config.pinch_inset_m),
            "--T-world-cam", *numbers(config.T_world_cam), "--up", *numbers(config.up_world)]
    for option, corner in (("--workspace-min", config.workspace_min_world), ("--workspace-max", config.workspace_max_world)):
        if np.all(np.isfinite(corner)):
            argv += [option, *numbers(corner)]
        elif np.any(np.isfinite(corner)):
            raise ValueError(f"{option}: the planner service takes a bounded or an unbounded corner, got {corner.tolist()}")
    for option, value in (("--min-score", config.min_score), ("--min-confidence", config.min_confidence),
                          ("--opening-width-m", config.opening_width_m),
                          ("--outline-window-spacings", config.outline_window_spacings),
                          ("--corner-max-angle-deg", math.degrees(config.corner_max_angle_rad)),
                          ("--layer-thickness-m", config.layer_thickness_m),
                          ("--weight-single-layer", config.weight_single_layer),
                          ("--tip-search-radius-m", config.tip_search_radius_m),
                          ("--tip-max-step-m", config.tip_max_step_m)):
        argv += [option, *numbers(value)]
    return argv


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if len(set(args.kinds)) != len(args.kinds):
        parser.error(f"--kinds: repeated kind in {' '.join(args.kinds)}")
    try:
        core = PlannerCore(config_from_args(args), kinds=args.kinds, max_age_s=args.max_estimate_age_s)
        curve = curve_keys_from_args(args, [args.bind])
    except ValueError as e:
        parser.error(str(e))
    configure_logging(args.log_level)

    stop = threading.Event()
    stop_on_signals(stop)

    try:
        run_planner_service(core, estimates_endpoint=args.estimates, planner_endpoint=args.bind,
                            frames_endpoint=args.frames, stop=stop, on_bound=endpoint_printer(args, "planner"),
                            curve=curve)
    except ValueError as e:  # an endpoint that cannot be bound or connected
        print(f"{parser.prog}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
