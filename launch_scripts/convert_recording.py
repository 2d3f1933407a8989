"""Convert a public RGB-D recording to a sequence folder (TUM RGB-D layout).

    python -m launch_scripts.convert_recording FORMAT SRC OUT [--sequence DIR] [--max-frames N]

FORMAT is one of perception.recordings.FORMATS (deformable_tracking, deepdeform, rgbd_tracking); SRC is a
folder or a bare git directory (read at HEAD); OUT is a new folder. Besides the sequence,
OUT gets the dataset's reference masks, ground-truth flow and recording.json (see
perception.recordings). Bad input ends with exit status 2 and one line naming the problem.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tqdm import tqdm

from launch_scripts.cli import OneLineParser, add_log_level_argument, configure_logging, positive_int
from perception.recordings import FORMATS, read_recording, write_sequence
from perception.sequence import SequenceError


def build_parser() -> OneLineParser:
    p = OneLineParser(prog="python -m launch_scripts.convert_recording", description=__doc__.split("\n\n")[0])
    p.add_argument("format", choices=sorted(FORMATS), help="layout of the source recording")
    p.add_argument("source", type=Path, help="the recording: a folder or a bare git directory")
    p.add_argument("output", type=Path, help="sequence folder to create")
    p.add_argument("--sequence", help="deepdeform: the sequence folder inside SRC (e.g. example_data/train/seq258), "
                                      "needed when SRC holds several; rgbd_tracking: the image folder inside SRC "
                                      "(default examples/images/imagesInteraction)")
    p.add_argument("--max-frames", type=positive_int, help="convert only the first N frames")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    add_log_level_argument(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level, "%(levelname)s %(name)s: %(message)s")
    options = {}
    if args.sequence is not None:
        if args.format not in ("deepdeform", "rgbd_tracking"):
            print(f"error: --sequence applies to the deepdeform and rgbd_tracking formats, not {args.format}",
                  file=sys.stderr)
            return 2
        options["sequence"] = args.sequence
    try:
        recording = read_recording(args.format, args.source, **options)
        bar = None if args.quiet else (lambda frames: tqdm(frames, desc="converting", unit="frame"))
        write_sequence(recording, args.output, max_frames=args.max_frames, progress=bar)
    except (SequenceError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        n = min(len(recording.frames), args.max_frames or len(recording.frames))
        print(f"wrote {args.output}: {n} frames {recording.camera.width}x{recording.camera.height}, "
              f"{len(recording.masks)} annotated mask(s), {len(recording.flows)} flow pair(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
