"""Play an Azure Kinect recording through ``KinectSource(recording=...)`` and save what it
yields: test tooling, run beside the SDK (tests/k4a_sdk.py), whose NumPy the suite cannot share.

    python -m tests.k4a_play RECORDING OUT.npz [--passes N] [--back-to-back M]

OUT.npz holds, over N passes (default 1) one after the other: ``rgb`` (F, H, W, 3) uint8,
``depth_m`` (F, H, W) float32, ``timestamp_s`` (F,) float64, ``seq`` (F,) int, ``pass_index``
(F,) int; and ``K`` (3, 3), ``D``, ``size`` (width, height), ``name``, ``depth_scale``,
``colour_format``, ``redone`` (transformations the source redid). With ``--back-to-back M``
also the recording's depth images transformed M times in turn, one call straight after the
other (where the SDK's transformation thread drops calls) through ``DepthToColour``:
``back_to_back_frame`` (M,) the index of the depth image, ``back_to_back_row`` (M, W) float32
metres, the colour image's row H / 2, and ``back_to_back_redone``. A SourceError prints
``{"error": MESSAGE}`` as one JSON line on stdout (where the SDK logs
too) and exits with status 3.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

import numpy as np

from perception.sources import KinectSource, SourceError
from perception.sources._kinect import DepthToColour


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.k4a_play")
    parser.add_argument("recording")
    parser.add_argument("output")
    parser.add_argument("--passes", type=int, default=1)
    parser.add_argument("--back-to-back", type=int, default=0)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    frames, passes = [], []
    try:
        with KinectSource(recording=args.recording) as source:
            for p in range(args.passes):
                for frame in source.frames():
                    frames.append(frame)
                    passes.append(p)
            cam = source.camera
            extra = back_to_back(args.recording, cam.height // 2, args.back_to_back) if args.back_to_back else {}
            np.savez_compressed(
                args.output, rgb=np.stack([f.rgb for f in frames]), depth_m=np.stack([f.depth_m for f in frames]),
                timestamp_s=np.array([f.timestamp_s for f in frames]), seq=np.array([f.seq for f in frames]),
                pass_index=np.array(passes), K=cam.K, D=cam.D, size=np.array([cam.width, cam.height]),
                name=source.name, depth_scale=source.depth_scale, colour_format=source.colour_format,
                redone=source.transformations_redone, **extra)
    except SourceError as e:
        print(json.dumps({"error": str(e)}))
        return 3
    return 0


def back_to_back(recording: str, row: int, calls: int) -> dict:
    """The recording's depth images (of captures with colour) transformed ``calls`` times in turn."""
    import pyk4a

    playback = pyk4a.PyK4APlayback(recording)
    playback.open()
    try:
        depths = []
        while True:
            try:
                capture = playback.get_next_capture()
            except EOFError:
                break
            if capture.color is not None and capture.depth is not None:
                depths.append(np.array(capture.depth))
        to_colour = DepthToColour(pyk4a, playback.calibration)
        index = np.arange(calls) % len(depths)
        rows = np.stack([to_colour(depths[i])[row] for i in index]).astype(np.float32) / 1000.0
        return {"back_to_back_frame": index, "back_to_back_row": rows, "back_to_back_redone": to_colour.redone}
    finally:
        playback.close()


if __name__ == "__main__":
    sys.exit(main())
