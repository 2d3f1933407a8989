"""Record a simulated scene as a sequence folder with ground truth (``sim.recorder``).

    python -m launch_scripts.record_scene SCENE OUT_DIR [--frames N] [--seed S] [--no-noise]
        [--width W --height H] [--frame-step K] [--no-occluders] [--quiet]

Writes OUT_DIR in the recorded sequence folder layout (rgb.txt, depth.txt, rgb/, depth/,
camera_intrinsic.json, groundtruth_mesh.npz). Frames are 1/30 s apart, timestamps start
at 0; ``--frame-step K`` keeps every K-th frame only (a camera dropping frames or running
at 30/K Hz), with its true timestamp. Scenes with occluders (a swept bar, a robot's
gripper and arm) also get ``occluder_masks/``; ``--no-occluders`` records the scene's
twin: the same cloth motion with nothing drawn in front of it (its masks are all 0).

Bad arguments, or an output folder that cannot be made or written, end the program with a
one-line message and exit status 2 (checked before simulating); Ctrl-C with ``interrupted``
and exit status 130. Interrupted or failed, it removes what it wrote: the folder it created
(never one that existed before; an existing empty one is emptied again).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

from launch_scripts.cli import (
    OneLineParser,
    add_log_level_argument,
    configure_logging,
    exit_130_on_ctrl_c,
    non_negative_int,
    positive_int,
)
from sim.recorder import record_sequence
from sim.scenes import FPS, SCENES, make_scene


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="python -m launch_scripts.record_scene", description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", help="one of: " + ", ".join(sorted(SCENES)))
    parser.add_argument("out_dir", type=Path, help="folder to write (must not exist or be empty)")
    parser.add_argument("--frames", type=positive_int,
                        help=f"number of simulated frames, 1/{FPS:g} s apart (default: the scene's script, 60 for "
                             "the paper's scenes)")
    parser.add_argument("--frame-step", type=positive_int, default=1,
                        help="write every K-th simulated frame only, timestamps kept (default 1: every frame)")
    parser.add_argument("--no-occluders", action="store_true",
                        help="the scene's twin: its occluders are not drawn (same cloth motion)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="scene and noise seed (default 0)")
    parser.add_argument("--no-noise", action="store_true", help="exact images, no sensor noise")
    parser.add_argument("--width", type=positive_int, default=640, help="image width (default 640)")
    parser.add_argument("--height", type=positive_int, default=480, help="image height (default 480)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_log_level_argument(parser)
    return parser


def make_output_folder(out_dir: Path) -> Path | None:
    """Create ``out_dir`` (with its missing parents) and check that it can be written; return the
    topmost folder this created, or None when ``out_dir`` already existed. raises OSError (the
    folders it created removed again)."""
    created = None
    for folder in (out_dir.resolve(), *out_dir.resolve().parents):  # resolved: "new/../seq" makes only seq
        if folder.exists() or folder.is_symlink():
            break
        created = folder
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        if not os.access(out_dir, os.W_OK | os.X_OK):
            raise PermissionError(13, "Permission denied")
    except OSError:
        remove_output(out_dir, created)  # the parents made before the failure too
        raise
    return created


def remove_output(out_dir: Path, created: Path | None) -> None:
    """Undo a run's writing: remove ``created`` (the topmost folder the run made), or, when
    ``out_dir`` existed before (then empty), what the run put into it."""
    if created is not None:
        shutil.rmtree(created, ignore_errors=True)
        return
    for child in out_dir.iterdir() if out_dir.is_dir() else ():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


@exit_130_on_ctrl_c
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scene not in SCENES:
        parser.error(f"unknown scene {args.scene!r}; expected one of {', '.join(sorted(SCENES))}")
    if args.width < 16 or args.height < 16:
        parser.error(f"image size must be at least 16x16, got {args.width}x{args.height}")
    if args.out_dir.exists() and (not args.out_dir.is_dir() or any(args.out_dir.iterdir())):
        parser.error(f"{args.out_dir} exists and is not an empty directory")
    try:
        created = make_output_folder(args.out_dir)
    except OSError as exc:
        parser.error(f"{args.out_dir}: cannot create the output folder there ({exc.strerror or exc})")

    configure_logging(args.log_level, "%(levelname)s %(name)s: %(message)s")
    start = time.perf_counter()
    try:
        with make_scene(args.scene, seed=args.seed, noise=not args.no_noise, width=args.width, height=args.height,
                        occluders=not args.no_occluders) as scene:
            written = record_sequence(scene, args.out_dir, args.frames or scene.n_frames, args.frame_step,
                                      progress=not args.quiet)
    except BaseException as exc:  # Ctrl-C or an error: leave no half-written folder behind
        remove_output(args.out_dir, created)
        if isinstance(exc, OSError):
            parser.error(f"{args.out_dir}: cannot write the sequence ({exc})")
        raise
    if not args.quiet:
        print(f"{args.out_dir}: {written} frames of {args.scene} (seed {args.seed}) in "
              f"{time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
