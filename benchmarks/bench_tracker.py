"""Tracking speed per feature type, with pycpd's deformable CPD as the peer in the same run.

    python benchmarks/bench_tracker.py [--scene towel_sway] [--frames 40] [--repeats 3] [--spacing-m 0.027]

Records the scene once (PyBullet, 640x480, sensor noise on), then tracks the same frames
``--repeats`` times with each configuration and reports the median over repeats of each
run's median ``timing_ms`` (per-frame tracking time, frame I/O excluded), its spread, and
the run's mean ground-truth error. The CPD peer runs on the same frames and masks. Each
round runs every configuration once, and the peer, in turn: a slower spell of a shared
machine falls on all of them alike rather than on whichever was running.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from perception.features import surf_available  # noqa: E402
from perception.tracker import TrackerConfig  # noqa: E402
from sim.evaluation import cpd_recording, record_scene, track_recording  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="towel_sway")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--spacing-m", type=float, default=0.027, help="mesh spacing (0.027 gives ~500 vertices on the towel)")
    p.add_argument("--no-cpd", action="store_true")
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.frames < 2:
        parser.error(f"expected --repeats >= 1 and --frames >= 2, got {args.repeats} and {args.frames}")

    rec = record_scene(args.scene, seed=0, noise=True, n_frames=args.frames)
    h, w = rec.frames[0].depth_m.shape
    configs = {"paper (sift)": TrackerConfig(features="sift", spacing_m=args.spacing_m)}
    if surf_available():
        configs["paper (surf)"] = TrackerConfig(features="surf", spacing_m=args.spacing_m)
    configs["orb"] = TrackerConfig(features="orb", spacing_m=args.spacing_m)
    configs["klt"] = TrackerConfig(features="klt", spacing_m=args.spacing_m)
    configs["realtime preset (klt)"] = TrackerConfig.realtime(spacing_m=args.spacing_m)

    print(f"machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, Python {platform.python_version()}")
    print(f"scene {args.scene}: {args.frames} frames of {w}x{h}, {args.repeats} repeats, median of per-run medians")
    print(f"{'configuration':24s} {'vertices':>8s} {'ms/frame':>9s} {'min..max':>14s} {'mean err mm':>12s}")
    medians = {label: [] for label in configs}
    errors, vertices = {}, {}
    peer, peer_error, start, masks = [], None, None, None
    progress = tqdm(total=args.repeats * (len(configs) + (not args.no_cpd)), desc="runs", unit="run", leave=False)
    for _ in range(args.repeats):
        for label, cfg in configs.items():
            run = track_recording(rec, cfg, label)
            progress.update()
            medians[label].append(float(np.median(run.timing_ms[1:])))
            errors[label], vertices[label] = run.summary(rec)["mean_mm"], run.vertices.shape[1]
            if masks is None:  # the peer starts from the first tracker's first mesh and follows its masks
                masks, start = run.masks, run.vertices[0]
        if not args.no_cpd:
            run = cpd_recording(rec, start, masks)
            peer.append(float(np.median(run.timing_ms[1:])))
            peer_error = run.summary(rec)["mean_mm"]
            progress.update()
    progress.close()
    for label, times in medians.items():
        print(f"{label:24s} {vertices[label]:8d} {np.median(times):9.1f} "
              f"{min(times):6.1f}..{max(times):6.1f} {errors[label]:12.1f}")
    if peer:
        print(f"{'pycpd deformable (peer)':24s} {start.shape[0]:8d} {np.median(peer):9.1f} "
              f"{min(peer):6.1f}..{max(peer):6.1f} {peer_error:12.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
