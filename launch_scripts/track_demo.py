"""Record a simulated scene, track it with the offline command, and score it against ground truth.

    python -m launch_scripts.track_demo [--scene towel_sway] [--frames 60] [--seed 0] [--out out/track_demo]
                                        [-- extra options for perception.track, e.g. --preset realtime]

The same steps a user takes with a real recording: ``python -m launch_scripts.record_scene``
writes the sequence folder, ``python -m perception.track`` tracks it, and the result is
compared with the simulation's ``groundtruth_mesh.npz`` (the metric of ``sim.ground_truth``). Outputs: the sequence,
EST.npz, the mesh drawn over every frame, an error-over-time plot and summary.json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from launch_scripts import record_scene, track
from launch_scripts.cli import OneLineParser, exit_130_on_ctrl_c, positive_int
from sim.evaluation.figures import error_over_time
from sim.ground_truth import error_summary, vertex_errors
from sim.scenes import SCENES


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m launch_scripts.track_demo", description=__doc__.split("\n\n")[0],
                                epilog="Options after -- go to python -m launch_scripts.track (e.g. -- --preset "
                                       "realtime). Ctrl-C stops with exit status 130.")
    p.add_argument("--scene", default="towel_sway",
                   help=f"simulated scene to record, one of: {', '.join(sorted(SCENES))} (default towel_sway)")
    p.add_argument("--frames", type=positive_int, default=60, help="number of frames to record and track (default 60)")
    p.add_argument("--seed", type=int, default=0, help="scene and sensor-noise seed (default 0)")
    p.add_argument("--out", type=Path, default=Path("out/track_demo"),
                   help="output folder: sequence/ (replaced on each run), est.npz, overlays/, error_over_time.png, "
                        "summary.json (default out/track_demo)")
    return p


@exit_130_on_ctrl_c
def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    own = argv[: argv.index("--")] if "--" in argv else argv
    args = build_parser().parse_args(own)

    seq = args.out / "sequence"
    if seq.exists():
        shutil.rmtree(seq)  # the demo's own output from an earlier run
    args.out.mkdir(parents=True, exist_ok=True)
    status = record_scene.main([args.scene, str(seq), "--frames", str(args.frames), "--seed", str(args.seed)])
    if status:
        return status
    est_path = args.out / "est.npz"
    status = track.main([str(seq), "--output", str(est_path), "--overlay-dir", str(args.out / "overlays")] + extra)
    if status:
        return status

    est = np.load(est_path)
    gt = np.load(seq / "groundtruth_mesh.npz")
    # the material points of frame 0 are followed as far as the first mesh went: a mesh laid anew
    # (the object found again) has material points of its own, not frame 0's
    tracked = int(np.sum(est["mesh"] == 0))
    if tracked < len(est["mesh"]):
        print(f"the tracker lost the cloth and laid a new mesh at frame {tracked}: frames 0-{tracked - 1} are scored")
    errors = vertex_errors(est["vertices"][:tracked], gt["vertices"][:tracked], gt["faces"])
    summary = error_summary(errors)
    summary["median_ms"] = float(np.median(est["timing_ms"][1:])) if len(est["timing_ms"]) > 1 else None
    summary["lost_frames"] = int(est["lost"].sum()) if "lost" in est.files else 0
    summary.update(scene=args.scene, seed=args.seed, frames=args.frames, frames_scored=tracked,
                   vertices=int(est["vertices"].shape[1]))
    error_over_time(args.out / "error_over_time.png", f"{args.scene}: tracking error against ground truth",
                    {"tracker": errors})
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"error: mean {summary['mean_mm']:.1f} mm, 95th percentile {summary['p95_mm']:.1f} mm"
          + (f"; median {summary['median_ms']:.0f} ms/frame" if summary["median_ms"] is not None else ""))
    print(f"outputs in {args.out}/: overlays/ (mesh over each frame), error_over_time.png, summary.json, est.npz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
