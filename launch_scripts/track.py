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

A tracker that loses the object and finds it again with a new mesh (a plain cloth, whose
material points cannot be found again) goes on with that mesh. The keys above are the first
mesh's: its material points from frame 0 on, NaN (``visible`` False) in the frames tracked
on a later mesh. ``mesh`` (T,) int says which mesh each frame's estimate is on (0 the first),
and each later mesh K has the same keys prefixed ``meshK_``: ``meshK_vertices`` (T, N_K, 3)
(NaN in the frames not on it), ``meshK_faces``, ``meshK_boundary``, ``meshK_canonical`` and
``meshK_visible``.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from launch_scripts.cli import (
    OneLineParser,
    add_log_level_argument,
    add_tracker_arguments,
    configure_logging,
    output_problem,
    positive_int,
    tracker_config_from_args,
)
from perception.overlay import draw_mesh, ply_bytes
from perception.sequence import SequenceError, open_sequence, read_mask
from perception.tracker import MeshTracker, TrackingError

log = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m perception.track", description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path, help="sequence folder (rgb.txt, depth.txt, camera_intrinsic.json)")
    p.add_argument("--output", "-o", type=Path, required=True, help="EST.npz to write")
    p.add_argument("--init-mask", type=Path, help="8-bit PNG, non-zero on the object in the first frame")
    p.add_argument("--occluder-masks", type=Path, metavar="DIR",
                   help="folder of 8-bit PNGs named as the depth images, non-zero on known occluders")
    p.add_argument("--max-frames", type=positive_int, help="track at most this many frames")
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
    n = len(seq) if args.max_frames is None else min(len(seq), args.max_frames)
    problem = output_problem(args.output, is_file=True)
    if problem:
        raise ValueError(f"--output {args.output}: {problem}")
    tracker = MeshTracker(config)
    for d in (args.overlay_dir, args.ply_dir):
        if d is not None:
            d.mkdir(parents=True, exist_ok=True)
    estimates, timestamps = [], []
    for i in tqdm(range(n), desc="tracking", unit="frame", disable=args.quiet):
        frame = seq.frame(i, occluder_dir=args.occluder_masks)
        if i == 0:
            mask = read_mask(args.init_mask, frame.depth_m.shape) if args.init_mask else None
            estimate = tracker.initialise(frame, mask=mask)
        else:
            estimate = tracker.track(frame)
        estimates.append(estimate)
        timestamps.append(frame.timestamp_s)
        if args.overlay_dir is not None:
            img = draw_mesh(frame.rgb, estimate, frame.camera.K)
            cv2.imwrite(str(args.overlay_dir / f"{i:06d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        if args.ply_dir is not None:
            (args.ply_dir / f"{i:06d}.ply").write_bytes(ply_bytes(estimate.vertices, estimate.faces))
    result = estimate_arrays(estimates, timestamps)
    # written beside it, then moved over it: an interrupted write leaves an earlier EST.npz whole
    partial = args.output.with_name(args.output.name + ".partial")
    try:
        with open(partial, "wb") as f:  # a file object: numpy adds no ".npz" to the name given
            np.savez_compressed(f, **result)
        os.replace(partial, args.output)
    finally:
        partial.unlink(missing_ok=True)
    return result


def estimate_arrays(estimates: list, timestamps: list) -> dict:
    """EST.npz's arrays (module docstring) of one estimate per frame: the first mesh's under the
    documented keys, each later one's (a new mesh laid when the object was found again) under
    ``meshK_``, and ``mesh``, the mesh of each frame."""
    meshes, index = [], []
    for e in estimates:
        if not meshes or not np.array_equal(meshes[-1].canonical, e.canonical):
            meshes.append(e)
        index.append(len(meshes) - 1)
    index = np.asarray(index)
    result = {"timestamps": np.asarray(timestamps, np.float64),
              "timing_ms": np.asarray([e.timing_ms for e in estimates], np.float64),
              "confidence": np.asarray([e.confidence for e in estimates], np.float64),
              "lost": np.asarray([e.lost for e in estimates], bool), "mesh": index.astype(np.int32)}
    for k, first in enumerate(meshes):
        n = len(first.vertices)
        vertices = np.full((len(estimates), n, 3), np.nan, np.float32)
        visible = np.zeros((len(estimates), n), bool)
        for t in np.flatnonzero(index == k):
            vertices[t], visible[t] = estimates[t].vertices, estimates[t].visible
        prefix = f"mesh{k}_" if k else ""
        result.update({f"{prefix}vertices": vertices, f"{prefix}faces": first.faces.astype(np.int32),
                       f"{prefix}boundary": first.boundary.astype(np.int32),
                       f"{prefix}canonical": first.canonical.astype(np.float32), f"{prefix}visible": visible})
        if k:
            log.warning("frame %d: a new mesh of %d vertices (the object found again): EST.npz's vertices are NaN "
                        "from there, the new mesh's are in mesh%d_vertices", int(np.argmax(index == k)), n, k)
    return result


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level, "%(levelname)s %(name)s: %(message)s")
    try:
        result = track_sequence(args)
    except (SequenceError, TrackingError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"interrupted; {args.output} not written", file=sys.stderr)
        return 130
    t = result["timing_ms"][1:] if len(result["timing_ms"]) > 1 else result["timing_ms"]
    meshes = int(result["mesh"].max()) + 1
    if not args.quiet:
        print(f"tracked {len(result['timestamps'])} frames, {result['vertices'].shape[1]} vertices"
              f"{f' ({meshes - 1} new mesh(es) after the object was found again)' if meshes > 1 else ''}, "
              f"median {np.median(t):.1f} ms/frame, lost in {int(result['lost'].sum())}; wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
