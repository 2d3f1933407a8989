"""Offline tracking of a recorded sequence folder: the offline tracking command.

    python -m perception.track SEQ --output EST.npz [--init-mask MASK.png] [options]

(``perception.track`` is the command's documented name; it runs this module.)

Writes EST.npz with ``vertices`` (T, N, 3) float32 metres in the camera frame, ``faces``
(M, 3), ``boundary`` (B,), ``canonical`` (N, 3) float32, ``timestamps`` (T,) float64 and
``timing_ms`` (T,) float64 (tracking time only), plus ``confidence`` (T,), ``lost`` (T,) and
``visible`` (T, N) bool (the vertices the camera saw in each frame). ``--occluder-masks DIR``
gives known occluders (the robot's gripper or arm, a hand): one 8-bit PNG per frame, named
as the frame's depth image, non-zero on the occluder.
Optionally the mesh drawn over every RGB frame (PNG) and a PLY mesh per frame.
Bad input ends with exit status 2 and one line on stderr naming the problem.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from launch_scripts.cli import (
    add_log_level_argument,
    add_tracker_arguments,
    configure_logging,
    tracker_config_from_args,
)
from perception.overlay import draw_mesh, ply_bytes
from perception.sequence import SequenceError, open_sequence, read_mask
from perception.tracker import MeshTracker, TrackingError

log = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m perception.track", description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path, help="sequence folder (rgb.txt, depth.txt, camera_intrinsic.json)")
    p.add_argument("--output", "-o", type=Path, required=True, help="EST.npz to write")
    p.add_argument("--init-mask", type=Path, help="8-bit PNG, non-zero on the object in the first frame")
    p.add_argument("--occluder-masks", type=Path, metavar="DIR",
                   help="folder of 8-bit PNGs named as the depth images, non-zero on known occluders")
    p.add_argument("--max-frames", type=int, help="track at most this many frames")
    p.add_argument("--overlay-dir", type=Path, help="write the mesh drawn over each RGB frame here (PNG)")
    p.add_argument("--ply-dir", type=Path, help="write each frame's mesh here (PLY)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    add_log_level_argument(p)
    add_tracker_arguments(p)
    return p


def track_sequence(args) -> dict:
    seq = open_sequence(args.sequence)
    if len(seq) == 0:
        raise ValueError(f"{args.sequence}: no frame pairs rgb/depth within 0.02 s")
    config = tracker_config_from_args(args)
    if args.occluder_masks is not None and not args.occluder_masks.is_dir():
        raise ValueError(f"--occluder-masks {args.occluder_masks}: not a directory")
    n = len(seq) if args.max_frames is None else max(1, min(len(seq), args.max_frames))
    tracker = MeshTracker(config)
    for d in (args.overlay_dir, args.ply_dir):
        if d is not None:
            d.mkdir(parents=True, exist_ok=True)
    out = {k: [] for k in ("vertices", "timestamps", "timing_ms", "confidence", "lost", "visible")}
    estimate = None
    for i in tqdm(range(n), desc="tracking", unit="frame", disable=args.quiet):
        frame = seq.frame(i, occluder_dir=args.occluder_masks)
        if i == 0:
            mask = read_mask(args.init_mask, frame.depth_m.shape) if args.init_mask else None
            estimate = tracker.initialise(frame, mask=mask)
        else:
            estimate = tracker.track(frame)
        out["vertices"].append(estimate.vertices.astype(np.float32))
        out["timestamps"].append(frame.timestamp_s)
        out["timing_ms"].append(estimate.timing_ms)
        out["confidence"].append(estimate.confidence)
        out["lost"].append(estimate.lost)
        out["visible"].append(estimate.visible)
        if args.overlay_dir is not None:
            img = draw_mesh(frame.rgb, estimate, frame.camera.K)
            cv2.imwrite(str(args.overlay_dir / f"{i:06d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        if args.ply_dir is not None:
            (args.ply_dir / f"{i:06d}.ply").write_bytes(ply_bytes(estimate.vertices, estimate.faces))
    result = dict(
        vertices=np.stack(out["vertices"]), faces=estimate.faces.astype(np.int32),
        boundary=estimate.boundary.astype(np.int32), canonical=estimate.canonical.astype(np.float32),
        timestamps=np.asarray(out["timestamps"], np.float64), timing_ms=np.asarray(out["timing_ms"], np.float64),
        confidence=np.asarray(out["confidence"], np.float64), lost=np.asarray(out["lost"], bool),
        visible=np.stack(out["visible"]).astype(bool))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.output, **result)
    return result


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level, "%(levelname)s %(name)s: %(message)s")
    try:
        result = track_sequence(args)
    except (SequenceError, TrackingError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    t = result["timing_ms"][1:] if len(result["timing_ms"]) > 1 else result["timing_ms"]
    if not args.quiet:
        print(f"tracked {len(result['timestamps'])} frames, {result['vertices'].shape[1]} vertices, "
              f"median {np.median(t):.1f} ms/frame, lost in {int(result['lost'].sum())}; wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
