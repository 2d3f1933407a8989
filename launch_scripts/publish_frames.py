"""Publish RGB-D frames from one source on a ZeroMQ endpoint (docs/protocol.md, FRAMES).

    python -m launch_scripts.publish_frames sim --scene poster_bend [--seed S] [--no-noise] [--frames N]
                                            [--known-occluders] [--no-occluders]
    python -m launch_scripts.publish_frames sequence SEQ
    python -m launch_scripts.publish_frames realsense [--width W --height H --fps F] [--serial SN | --recording FILE.db3]
    python -m launch_scripts.publish_frames kinect [--colour-resolution 720p] [--depth-mode nfov_unbinned] [--fps F]
                                                   [--device N]
    python -m launch_scripts.publish_frames kinect --recording FILE.mkv
    python -m launch_scripts.publish_frames rosbag BAG --rgb-topic T --depth-topic T --info-topic T

Options for every source, after the source's name: --endpoint, --pacing
{realtime,rate,fast}, --rate-hz, --loop, --max-frames, --start-delay-s,
--heartbeat-period-s, --print-endpoints, --log-level, --curve-keys, --insecure (an endpoint other
machines can reach needs one of the last two). Ctrl-C or SIGTERM stops cleanly.
Bad arguments, a missing SDK or device end with exit status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import sys
import threading

from ipc import endpoints
from ipc.transport import HEARTBEAT_PERIOD_S, MIN_HEARTBEAT_PERIOD_S
from launch_scripts.cli import (
    OneLineParser,
    add_log_level_argument,
    add_print_endpoints_argument,
    add_security_arguments,
    configure_logging,
    curve_keys_from_args,
    endpoint,
    endpoint_printer,
    non_negative_float,
    positive_float,
    positive_int,
    stop_on_signals,
)
from perception.sources import (
    KinectSource,
    Pacing,
    RealSenseSource,
    RosbagSource,
    SequenceSource,
    SourceError,
    run_publisher,
)


def build_parser() -> argparse.ArgumentParser:
    common = OneLineParser(add_help=False)
    g = common.add_argument_group("publishing")
    g.add_argument("--endpoint", type=endpoint, default=endpoints.FRAMES,
                   help=f"endpoint to bind (default {endpoints.FRAMES}; tcp://127.0.0.1:* picks a free port)")
    g.add_argument("--pacing", choices=Pacing.MODES,
                   help="realtime: keep the spacing of the frames' timestamps (default for files and sim); "
                        "rate: --rate-hz; fast: no wait (default for cameras, which pace themselves, and RealSense "
                        "recordings, which the SDK plays at their pace)")
    g.add_argument("--rate-hz", type=positive_float, help="frames per second with --pacing rate")
    g.add_argument("--loop", action="store_true", help="start over at the end (files and sim)")
    g.add_argument("--max-frames", type=positive_int, help="stop after this many frames")
    g.add_argument("--start-delay-s", type=non_negative_float, default=0.5,
                   help="wait after binding so that waiting subscribers get the first frame (default 0.5)")
    g.add_argument("--heartbeat-period-s", type=positive_float, default=HEARTBEAT_PERIOD_S,
                   help=f"seconds between heartbeats, at least {MIN_HEARTBEAT_PERIOD_S:g} (default {HEARTBEAT_PERIOD_S:g})")
    add_print_endpoints_argument(g, '{"frames": ENDPOINT}')
    add_log_level_argument(g)
    add_security_arguments(common)

    parser = OneLineParser(prog="python -m launch_scripts.publish_frames",
                                     description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="source", required=True, metavar="{sim,sequence,realsense,kinect,rosbag}")

    p = sub.add_parser("sim", parents=[common], help="a simulated scene (sim.scenes)")
    p.add_argument("--scene", default="poster_bend", help="registered scene name (default poster_bend)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    p.add_argument("--no-noise", action="store_true", help="render without sensor noise")
    p.add_argument("--width", type=positive_int, default=640)
    p.add_argument("--height", type=positive_int, default=480)
    p.add_argument("--frames", type=positive_int, help="frames per pass (default: the scene's script, 60 for the "
                                                         "paper's scenes)")
    p.add_argument("--known-occluders", action="store_true",
                   help="send the exact mask of the drawn occluders (a gripper, an arm) in each frame's occluder_mask")
    p.add_argument("--no-occluders", action="store_true",
                   help="the scene's twin: its occluders are not drawn (same cloth motion)")

    p = sub.add_parser("sequence", parents=[common], help="a recorded sequence folder")
    p.add_argument("path", help="sequence folder (rgb.txt, depth.txt, camera_intrinsic.json)")

    p = sub.add_parser("realsense", parents=[common], help="an Intel RealSense camera (pyrealsense2)")
    p.add_argument("--width", type=positive_int, default=640)
    p.add_argument("--height", type=positive_int, default=480)
    p.add_argument("--fps", type=positive_int, default=30)
    p.add_argument("--serial", help="device serial number (default: the first camera)")
    p.add_argument("--recording", metavar="FILE",
                   help="play a recording (.db3, or .bag from SDKs before 2.56) instead of a camera, at its recorded pace")

    p = sub.add_parser("kinect", parents=[common], help="an Azure Kinect (pyk4a)")
    p.add_argument("--colour-resolution", choices=KinectSource.COLOUR_RESOLUTIONS, default="720p")
    p.add_argument("--depth-mode", choices=KinectSource.DEPTH_MODES, default="nfov_unbinned")
    p.add_argument("--fps", type=int, choices=KinectSource.FRAME_RATES, default=30)
    p.add_argument("--device", type=int, default=0, help="device index (default 0)")
    p.add_argument("--recording", metavar="FILE",
                   help="play a k4a recording (.mkv, e.g. from k4arecorder) instead of a device; it has its own "
                        "resolution, depth mode and rate")

    p = sub.add_parser("rosbag", parents=[common], help="a ROS 1 or ROS 2 bag (rosbags)")
    p.add_argument("path", help="the bag (.bag file or ROS 2 bag folder)")
    p.add_argument("--rgb-topic", required=True,
                   help="colour topic: sensor_msgs/Image (rgb8 or bgr8) or sensor_msgs/CompressedImage (JPEG or PNG)")
    p.add_argument("--depth-topic", required=True,
                   help="sensor_msgs/Image depth topic registered to colour (16UC1 mm or 32FC1 m)")
    p.add_argument("--info-topic", required=True, help="sensor_msgs/CameraInfo topic of the colour camera")
    return parser


def open_source(args):
    """The FrameSource the arguments ask for."""
    if args.source == "sim":
        from sim.frame_source import SceneSource  # PyBullet only for simulated frames
        from sim.scenes import make_scene

        scene = make_scene(args.scene, seed=args.seed, noise=not args.no_noise, width=args.width, height=args.height,
                           occluders=not args.no_occluders, known_occluders=args.known_occluders)
        return SceneSource(scene, n_frames=args.frames or scene.n_frames)
    if args.source == "sequence":
        return SequenceSource(args.path)
    if args.source == "realsense":
        return RealSenseSource(args.width, args.height, args.fps, serial=args.serial, recording=args.recording)
    if args.source == "kinect":
        return KinectSource(args.colour_resolution, args.depth_mode, args.fps, device_id=args.device,
                            recording=args.recording)
    return RosbagSource(args.path, args.rgb_topic, args.depth_topic, args.info_topic)


def default_pacing(args) -> str:
    """The pacing mode when --pacing is not given: "fast" for cameras, which deliver frames at their
    own rate, and RealSense recordings, which the SDK plays at the recorded pace; "realtime" for
    everything read as fast as asked (sim, sequences, bags, Kinect recordings)."""
    camera_paced = args.source == "realsense" or (args.source == "kinect" and not args.recording)
    return "fast" if camera_paced else "realtime"


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.pacing == "rate" and args.rate_hz is None:
        parser.error("--pacing rate needs --rate-hz HZ (frames per second)")
    if args.rate_hz is not None and args.pacing != "rate":
        parser.error("--rate-hz goes with --pacing rate")
    configure_logging(args.log_level)
    stop = threading.Event()
    stop_on_signals(stop)

    try:
        curve = curve_keys_from_args(args, [args.endpoint])
        pacing = Pacing(args.pacing or default_pacing(args), args.rate_hz)
        with open_source(args) as source:
            run_publisher(source, args.endpoint, pacing=pacing, loop=args.loop, max_frames=args.max_frames,
                          start_delay_s=args.start_delay_s, heartbeat_period_s=args.heartbeat_period_s, stop=stop,
                          on_bound=endpoint_printer(args, "frames"), curve=curve.server if curve else None)
    except (SourceError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
