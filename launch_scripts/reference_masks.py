"""Make reference masks for a converted recording that has none (perception.reference_masks).

    python -m launch_scripts.reference_masks SEQ [--seed-mask PNG] [--review DIR] [--replace]

Writes SEQ/reference_masks/<depth name>.png (255 on the object) for every frame and notes
the procedure and its settings in SEQ/reference_masks.json. ``--review DIR`` also writes
contact sheets (the mask tinted green over each frame, other pixels at its depth magenta,
cropped to the object) to look at.
Bad input ends with exit status 2 and one line naming the problem.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from launch_scripts.cli import OneLineParser, add_log_level_argument, configure_logging
from perception.overlay import outlined_text
from perception.raster import bounding_box
from perception.recordings import MASKS_DIR, write_reference_masks
from perception.reference_masks import MaskConfig, ReferenceMaskError, depth_band, follow_object
from perception.sequence import SequenceError, open_sequence, read_mask


def contact_sheets(rgbs: list[np.ndarray], depths: list[np.ndarray], masks: list[np.ndarray], columns: int = 4,
                   rows: int = 3, tile_width: int = 400) -> list[np.ndarray]:
    """Pictures (RGB uint8) of every frame cropped to the masks' joint box: the mask tinted green,
    other pixels with depth in the mask's depth band tinted magenta, the frame number;
    ``columns`` x ``rows`` tiles a sheet."""
    union = np.logical_or.reduce(masks)
    y0, y1, x0, x1 = bounding_box(union, pad=25)
    scale = tile_width / (x1 - x0)
    tiles = []
    for i, (rgb, depth_m, mask) in enumerate(zip(rgbs, depths, masks)):
        img = rgb.astype(np.float32)
        others = depth_band(depth_m, mask, MaskConfig().depth_margin_m) & ~mask
        img[mask] = 0.6 * img[mask] + 0.4 * np.array([0, 255, 0])
        img[others] = 0.6 * img[others] + 0.4 * np.array([255, 0, 255])
        img = img.astype(np.uint8)
        tile = cv2.resize(img[y0:y1, x0:x1], None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        outlined_text(tile, f"{i}", (6, 18))
        tiles.append(tile)
    blank = np.zeros_like(tiles[0])
    per_sheet = columns * rows
    sheets = []
    for start in range(0, len(tiles), per_sheet):
        chunk = tiles[start:start + per_sheet]
        chunk += [blank] * (per_sheet - len(chunk))
        sheets.append(np.vstack([np.hstack(chunk[r * columns:(r + 1) * columns]) for r in range(rows)]))
    return sheets


def build_parser() -> OneLineParser:
    p = OneLineParser(prog="python -m launch_scripts.reference_masks", description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path, help="converted sequence folder")
    p.add_argument("--seed-mask", type=Path, help="8-bit PNG, non-zero on the object in the first frame "
                                                   "(default: found automatically)")
    p.add_argument("--review", type=Path, help="write contact sheets of the masks to this folder")
    p.add_argument("--replace", action="store_true", help="overwrite masks the folder already has")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    add_log_level_argument(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level, "%(levelname)s %(name)s: %(message)s")
    try:
        seq = open_sequence(args.sequence)
        if (seq.path / MASKS_DIR).is_dir() and any((seq.path / MASKS_DIR).iterdir()) and not args.replace:
            raise ValueError(f"{seq.path / MASKS_DIR}: already holds masks; pass --replace to overwrite them")
        seed = read_mask(args.seed_mask, (seq.camera.height, seq.camera.width), "--seed-mask") if args.seed_mask else None
        config = MaskConfig()
        rgbs, depths, masks = [], [], []

        def frames():
            for i in tqdm(range(len(seq)), desc="masks", unit="frame", disable=args.quiet):
                frame = seq.frame(i)
                if args.review is not None:
                    rgbs.append(frame.rgb)
                    depths.append(frame.depth_m)
                yield frame.rgb, frame.depth_m

        masks = list(follow_object(frames(), seed, config))
        how = (f"made by perception.reference_masks (seed: {args.seed_mask or 'automatic'}; "
               f"MaskConfig {config.to_dict()})")
        write_reference_masks(seq, dict(enumerate(masks)), {i: how for i in range(len(masks))})
        if args.review is not None:
            args.review.mkdir(parents=True, exist_ok=True)
            for k, sheet in enumerate(contact_sheets(rgbs, depths, masks)):
                cv2.imwrite(str(args.review / f"masks_{k:02d}.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    except (SequenceError, ReferenceMaskError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        areas = [int(m.sum()) for m in masks]
        print(f"wrote {len(masks)} masks to {seq.path / MASKS_DIR} ({min(areas)}..{max(areas)} pixels)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
