"""Record a simulated scene as a sequence folder with ground truth.

    python -m sim.record SCENE OUT_DIR [--frames N] [--seed S] [--no-noise] [--width W --height H]

Writes OUT_DIR in the "Recorded sequence folder" layout of DESIGN.md (rgb.txt,
depth.txt, rgb/, depth/, camera_intrinsic.json, groundtruth_mesh.npz). Frames are 1/30 s
apart, timestamps start at 0. Ground truth: the cloth's vertices in the camera frame
at every frame (float32 metres), its faces, and its material coordinates ``uv`` in
metres on the flat cloth (u right, v down from the top-left of its bounding box).

Bad arguments end the program with a one-line message and exit status 2.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from perception.sequence import SequenceWriter
from sim.scenes import DEFAULT_FRAMES, FPS, SCENES, make_scene

log = logging.getLogger(__name__)


class _OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (no usage block) and exit 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="python -m sim.record", description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", help="one of: " + ", ".join(sorted(SCENES)))
    parser.add_argument("out_dir", type=Path, help="folder to write (must not exist or be empty)")
    parser.add_argument("--frames", type=_positive_int, default=DEFAULT_FRAMES,
                        help=f"number of frames, 1/{FPS:g} s apart (default {DEFAULT_FRAMES})")
    parser.add_argument("--seed", type=_seed, default=0, help="scene and noise seed (default 0)")
    parser.add_argument("--no-noise", action="store_true", help="exact images, no sensor noise")
    parser.add_argument("--width", type=_positive_int, default=640, help="image width (default 640)")
    parser.add_argument("--height", type=_positive_int, default=480, help="image height (default 480)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scene not in SCENES:
        parser.error(f"unknown scene {args.scene!r}; expected one of {', '.join(sorted(SCENES))}")
    if args.width < 16 or args.height < 16:
        parser.error(f"image size must be at least 16x16, got {args.width}x{args.height}")
    if args.out_dir.exists() and (not args.out_dir.is_dir() or any(args.out_dir.iterdir())):
        parser.error(f"{args.out_dir} exists and is not an empty directory")

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    start = time.perf_counter()
    with make_scene(args.scene, seed=args.seed, noise=not args.no_noise, width=args.width, height=args.height) as scene:
        vertices = []
        with SequenceWriter(args.out_dir, scene.camera) as writer:
            frames = scene.frames(args.frames)
            for frame in tqdm(frames, total=args.frames, desc=args.scene, unit="frame", disable=args.quiet):
                writer.write(frame)
                vertices.append(scene.cloth_vertices_cam().astype(np.float32))
            writer.close(groundtruth={"vertices": np.stack(vertices), "faces": scene.faces, "uv": scene.uv_m})
    if not args.quiet:
        print(f"{args.out_dir}: {args.frames} frames of {args.scene} (seed {args.seed}) in "
              f"{time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
