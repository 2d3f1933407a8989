"""Record a simulated scene as a sequence folder with ground truth.

    python -m sim.record SCENE OUT_DIR [--frames N] [--seed S] [--no-noise] [--width W --height H]
                                       [--frame-step K] [--no-occluders]

Writes OUT_DIR in the recorded sequence folder layout (rgb.txt, depth.txt, rgb/, depth/,
camera_intrinsic.json, groundtruth_mesh.npz). Frames are 1/30 s apart, timestamps start
at 0; ``--frame-step K`` keeps every K-th frame only (a camera dropping frames or running
at 30/K Hz), with its true timestamp. Ground truth: the cloth's vertices in the camera
frame at every written frame (float32 metres), its faces, and its material coordinates
``uv`` in metres on the flat cloth (u right, v down from the top-left of its bounding box).

Scenes with occluders (a swept bar, a robot's gripper and arm) also get
``occluder_masks/``: one 8-bit PNG per frame, named as the frame's depth image, 255 where
the drawn occluder is seen and 0 elsewhere (the input of ``perception.track
--occluder-masks``). ``--no-occluders`` records the scene's twin: the same cloth motion with
nothing drawn in front of it (its masks are all 0).

Bad arguments end the program with a one-line message and exit status 2.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from perception.sequence import SequenceWriter, read_file_list
from sim.scenes import FPS, SCENES, make_scene

log = logging.getLogger(__name__)

OCCLUDER_MASKS = "occluder_masks"


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
    parser.add_argument("--frames", type=_positive_int,
                        help=f"number of simulated frames, 1/{FPS:g} s apart (default: the scene's script, 60 for "
                             "the paper's scenes)")
    parser.add_argument("--frame-step", type=_positive_int, default=1,
                        help="write every K-th simulated frame only, timestamps kept (default 1: every frame)")
    parser.add_argument("--no-occluders", action="store_true",
                        help="the scene's twin: its occluders are not drawn (same cloth motion)")
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
    with make_scene(args.scene, seed=args.seed, noise=not args.no_noise, width=args.width, height=args.height,
                    occluders=not args.no_occluders) as scene:
        total = args.frames or scene.n_frames
        vertices, occluder_masks = [], []
        with SequenceWriter(args.out_dir, scene.camera) as writer:
            for i, frame in enumerate(tqdm(scene.frames(total), total=total, desc=args.scene, unit="frame",
                                           disable=args.quiet)):
                if i % args.frame_step:
                    continue  # rendered all the same: the kept frames equal those of a full-rate recording
                writer.write(frame)
                vertices.append(scene.cloth_vertices_cam().astype(np.float32))
                if scene.has_occluders:
                    occluder_masks.append(scene.occluder_mask())
            writer.close(groundtruth={"vertices": np.stack(vertices), "faces": scene.faces, "uv": scene.uv_m})
        if occluder_masks:
            write_occluder_masks(args.out_dir, occluder_masks)
    if not args.quiet:
        print(f"{args.out_dir}: {len(vertices)} frames of {args.scene} (seed {args.seed}) in "
              f"{time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


def write_occluder_masks(seq_dir: Path, masks: list) -> None:
    """Write ``masks`` ((H, W) bool, one per frame in depth.txt's order) as 8-bit PNGs (255 on the
    occluder) into SEQ/occluder_masks/, each named as its frame's depth image."""
    _, depth_files = read_file_list(seq_dir / "depth.txt")
    if len(depth_files) != len(masks):
        raise ValueError(f"write_occluder_masks: {len(masks)} masks for {len(depth_files)} frames in {seq_dir}")
    folder = seq_dir / OCCLUDER_MASKS
    folder.mkdir(exist_ok=True)
    for rel, mask in zip(depth_files, masks):
        path = folder / Path(rel).name
        if not cv2.imwrite(str(path), np.where(mask, 255, 0).astype(np.uint8)):
            raise OSError(f"{path}: could not write the occluder mask")


if __name__ == "__main__":
    sys.exit(main())
