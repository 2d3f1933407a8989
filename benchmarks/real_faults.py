"""Faults injected into a real recording: how far each takes the tracker from its clean run,
and whether it says so.

    python benchmarks/real_faults.py [--data DIR] [--recording foam_tube] [--cut-from NAME]
        [--preset default realtime] [--seed 0] [--json OUT.json] [--pictures DIR]

A real recording rarely shows what goes wrong while a robot works. This takes one converted
recording (``python -m launch_scripts.convert_recording``; default the foam tube) with its
reference masks, tracks it clean, then tracks it again with one fault at a time put into
its frames (``perception.recording_faults``), from the same first frame and mask, during the
fault window (frames N/4 to 5N/8 of N):

- ``bar``: a bar as wide as a forearm (8 cm at the object's depth) sweeps across the object
  25 cm in front of it; ``bar, known``: the same with its mask sent as the frame's known
  occluder (``RGBDFrame.occluder_mask``), as a robot that knows where its arm is would;
- ``bar close`` and ``bar close, known``: the bar 2 cm in front of the object (a hand on it);
- ``depth holes``: depth missing in blobs over 30 % of the object's box;
- ``no depth``: three frames with no depth at all (the tracker refuses them, as the
  perception service does, and goes on with the next);
- ``dropped``: every other frame of the whole recording (half the frame rate);
- ``cut``: six frames of another recording in place of the object's (``--cut-from``; by
  default the first other recording found, else this one mirrored): the object is not in
  view, so every estimate then is wrong and should be flagged lost within 3 frames.

Scores, against the clean run with the same preset: the deviation (mean distance of each
vertex from the clean run's, mm) during the fault and after it; how much of the object's
reference mask the mesh covers where the object is in sight (the mask less the bar), at
least and on average over the fault window; frames flagged lost; frames wrong (deviation
over 30 mm, under half the vertices on the object, or under half the object in sight
covered) reported with confidence 0.5 or more,
and wrong frames not flagged lost 3 wrong frames in a row later (issue 11's loss target);
and how many frames after the fault ends the deviation takes to fall under 10 mm. A run
whose tracker built a new mesh has no deviation from there (it starts new material points);
its coverage still counts. Writes a JSON summary, a markdown table, a plot of deviation and
confidence over time per preset and a strip of the mesh over the faulted frames.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from perception.overlay import draw_mesh, outlined_text  # noqa: E402
from perception.raster import bounding_box  # noqa: E402
from perception.recording_faults import bar_in_front, cut_to, depth_holes, no_depth  # noqa: E402
from perception.recording_scores import mask_coverage, vertices_on_mask  # noqa: E402
from perception.recordings import data_root, read_reference_masks  # noqa: E402
from perception.segmentation import valid_depth  # noqa: E402
from perception.sequence import open_sequence  # noqa: E402
from perception.tracker import MeshTracker, TrackerConfig, TrackingError  # noqa: E402
from sim.evaluation.figures import error_with_occlusion  # noqa: E402
from sim.evaluation.handled import CONFIDENT, WRONG_MM, unflagged_late  # noqa: E402

PRESETS = {"default": TrackerConfig, "realtime": TrackerConfig.realtime}
#: The fault window, as fractions of the recording's length.
WINDOW = (0.25, 0.625)
BAR_WIDTH_M = 0.08
BAR_GAP_M = 0.25
CLOSE_GAP_M = 0.02
HOLE_FRACTION = 0.3
NO_DEPTH_FRAMES = 3
CUT_FRAMES = 6
#: Deviation under which a run is back with the clean one, mm.
RECOVERED_MM = 10.0
#: A frame is also wrong when fewer than this fraction of its vertices lie on the object, or
#: when its mesh covers less than this fraction of the object in sight (slid off most of it).
MIN_ON_OBJECT = 0.5
MIN_COVERAGE = 0.5
SCENARIOS = ("bar", "bar, known", "bar close", "bar close, known", "depth holes", "no depth", "dropped", "cut")


def _frames(seq) -> list:
    return [seq.frame(i) for i in range(len(seq))]


def _object_box(masks: dict, shape) -> tuple[int, int, int, int] | None:
    """The bounding box of the object over the recording (its reference masks), None if they are empty."""
    union = np.zeros(shape, bool)
    for m in masks.values():
        union |= m
    return bounding_box(union)


def faulted(name: str, frames: list, box, other: list, window: tuple[int, int], seed: int):
    """(frames to track as (index into the recording, frame), {index: bar mask}, {indices of
    frames that do not show the object}) for scenario ``name``; ``box`` is the object's
    (``_object_box``)."""
    a, b = window
    if name == "dropped":
        return [(i, f) for i, f in enumerate(frames) if i % 2 == 0], {}, set()
    out, bars, away = [], {}, set()
    rng = np.random.default_rng(seed)
    y0, y1, x0, x1 = box
    box_depth = frames[0].depth_m[y0:y1, x0:x1]
    depth = float(np.median(box_depth[valid_depth(box_depth)]))
    width_px = max(1, round(frames[0].camera.K[0, 0] * BAR_WIDTH_M / depth))
    for i, frame in enumerate(frames):
        if a <= i < b and name.startswith("bar"):
            gap = CLOSE_GAP_M if name.startswith("bar close") else BAR_GAP_M
            frame, bar = bar_in_front(frame, box, (i - a) / max(1, b - a - 1), width_px, gap)
            bars[i] = bar
            if name.endswith("known"):
                frame = dataclasses.replace(frame, occluder_mask=bar)
        elif a <= i < b and name == "depth holes":
            frame = depth_holes(frame, box, HOLE_FRACTION, rng)
        elif a <= i < a + NO_DEPTH_FRAMES and name == "no depth":
            frame = no_depth(frame)
        elif a <= i < a + CUT_FRAMES and name == "cut":
            frame = cut_to(frame, other[(i - a) % len(other)])
            away.add(i)
        out.append((i, frame))
    return out, bars, away


def track(frames: list, mask0: np.ndarray, config: TrackerConfig, label: str, quiet: bool) -> dict:
    """{recording index: MeshEstimate} of the frames tracked; refused frames are left out."""
    tracker = MeshTracker(config)
    estimates, refused = {}, []
    for k, (i, frame) in enumerate(tqdm(frames, desc=label, unit="frame", disable=quiet, leave=False)):
        try:
            estimates[i] = tracker.initialise(frame, mask=mask0) if k == 0 else tracker.track(frame)
        except TrackingError as exc:  # the service refuses such a frame and goes on with the next
            refused.append((i, str(exc).splitlines()[0]))
    return {"estimates": estimates, "refused": refused}


def score(run: dict, clean: dict, masks: dict, bars: dict, away: set, window: tuple[int, int], K) -> dict:
    """The scenario's figures (module docstring) and its per-frame series."""
    est, ref = run["estimates"], clean["estimates"]
    a, b = window
    seqs = sorted(est)
    canonical0 = est[seqs[0]].canonical
    same_mesh, deviation, coverage, on_object = True, {}, {}, {}
    for i in seqs:
        same_mesh = same_mesh and np.array_equal(est[i].canonical, canonical0)
        if same_mesh and i in ref and i not in away:
            deviation[i] = 1000.0 * float(np.linalg.norm(est[i].vertices - ref[i].vertices, axis=1).mean())
        if i in masks and i not in away:
            seen = masks[i] & ~bars.get(i, np.zeros_like(masks[i]))
            coverage[i] = mask_coverage(est[i].vertices, est[i].faces, K, seen)
            on_object[i] = vertices_on_mask(est[i].vertices, K, masks[i], 3.0)
    wrong = np.array([i in away or deviation.get(i, 0.0) > WRONG_MM or on_object.get(i, 1.0) < MIN_ON_OBJECT
                      or coverage.get(i, 1.0) < MIN_COVERAGE for i in seqs])
    confident = np.array([est[i].confidence >= CONFIDENT for i in seqs])
    lost = np.array([est[i].lost for i in seqs])
    during = [i for i in seqs if a <= i < b]
    after = [i for i in seqs if i >= b]
    recovered = next((k for k, i in enumerate(after) if deviation.get(i, np.inf) < RECOVERED_MM), None)

    def stat(values, f):
        return round(float(f(values)), 1) if len(values) else None

    cov_during = [coverage[i] for i in during if i in coverage]
    return {
        "frames": len(seqs), "refused": len(run["refused"]), "new_mesh": not same_mesh,
        "deviation_during_mm": stat([deviation[i] for i in during if i in deviation], np.mean),
        "deviation_max_mm": stat(list(deviation.values()), np.max),
        "deviation_after_mm": stat([deviation[i] for i in after if i in deviation], np.mean),
        "coverage_during_min": None if not cov_during else round(min(cov_during), 3),
        "coverage_during_mean": None if not cov_during else round(float(np.mean(cov_during)), 3),
        "lost": int(lost.sum()), "wrong": int(wrong.sum()), "wrong_confident": int((wrong & confident).sum()),
        "wrong_not_lost_after_3": int(unflagged_late(wrong, lost).sum()),
        "frames_to_recover": recovered,
        "series": {"frame": seqs, "deviation_mm": [deviation.get(i) for i in seqs],
                   "confidence": [round(float(est[i].confidence), 3) for i in seqs],
                   "lost": [bool(est[i].lost) for i in seqs]},
    }


def _cell(s: dict, key: str) -> str:
    return "-" if s.get(key) is None else str(s[key])


def _table(results: dict) -> str:
    head = ("| preset | fault | deviation during / after (max), mm | coverage during min / mean | lost | "
            "wrong & confident / wrong | wrong, not lost after 3 | frames to recover | refused | new mesh |")
    rows = [head, "| --- " * 10 + "|"]
    for preset, runs in results.items():
        for name, s in runs.items():
            rows.append(f"| {preset} | {name} | {_cell(s, 'deviation_during_mm')} / {_cell(s, 'deviation_after_mm')} "
                        f"({_cell(s, 'deviation_max_mm')}) | {_cell(s, 'coverage_during_min')} / "
                        f"{_cell(s, 'coverage_during_mean')} | {s['lost']}/{s['frames']} | "
                        f"{s['wrong_confident']}/{s['wrong']} | {s['wrong_not_lost_after_3']} | "
                        f"{_cell(s, 'frames_to_recover')} | {s['refused']} | {'yes' if s['new_mesh'] else 'no'} |")
    return "\n".join(rows)


def _strip(frames_by_index: dict, estimates: dict, picks: list[int], box, K, label: str,
           width: int = 1600) -> np.ndarray:
    """The mesh over the frames ``picks``, cropped round the object's box, side by side,
    scaled down to at most ``width`` pixels."""
    y0, y1, x0, x1 = box
    pad = max(y1 - y0, x1 - x0) // 4
    tiles = []
    for i in picks:
        frame = frames_by_index[i]
        image = draw_mesh(frame.rgb, estimates[i], K) if i in estimates else frame.rgb.copy()
        h, w = image.shape[:2]
        tile = np.ascontiguousarray(image[max(0, y0 - pad):min(h, y1 + pad), max(0, x0 - pad):min(w, x1 + pad)])
        outlined_text(tile, f"{label}, frame {i}", (5, tile.shape[0] - 8), 0.5)
        tiles.append(tile)
    strip = np.hstack(tiles)
    scale = min(1.0, width / strip.shape[1])
    return cv2.resize(strip, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1.0 else strip


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=None, help="folder of converted recordings (default: $CLOTHKIT_DATA, "
                   "else /work/data)")
    p.add_argument("--recording", default="foam_tube", help="the recording to put faults in (needs reference masks)")
    p.add_argument("--cut-from", default=None, help="recording whose frames the cut shows (default: the first other "
                   "one found, else this one mirrored)")
    p.add_argument("--preset", nargs="+", choices=sorted(PRESETS), default=["default", "realtime"])
    p.add_argument("--scenario", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    p.add_argument("--seed", type=int, default=0, help="places of the depth holes")
    p.add_argument("--json", type=Path, default=Path("out/real_faults/summary.json"))
    p.add_argument("--pictures", type=Path, default=Path("out/real_faults"))
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    root = args.data if args.data is not None else data_root()
    path = root / args.recording
    if not path.is_dir():
        print(f"no recording {args.recording!r} under {root}: convert it first (README, 'Real recordings')")
        return 2
    seq = open_sequence(path)
    frames = _frames(seq)
    masks = read_reference_masks(seq)
    box = _object_box(masks, frames[0].depth_m.shape)
    if 0 not in masks or box is None:
        print(f"recording {args.recording!r} has no reference mask, or an empty one, for its first frame")
        return 2
    others = sorted(d.name for d in root.iterdir() if d.is_dir() and d.name != args.recording
                    and (d / "rgb.txt").exists())
    cut_name = args.cut_from or (others[0] if others else None)
    if cut_name is not None:
        other = _frames(open_sequence(root / cut_name))
    else:
        other = [dataclasses.replace(f, rgb=np.ascontiguousarray(f.rgb[:, ::-1]),
                                     depth_m=np.ascontiguousarray(f.depth_m[:, ::-1])) for f in frames]
        cut_name = f"{args.recording} mirrored"
    n = len(frames)
    window = (round(WINDOW[0] * n), round(WINDOW[1] * n))
    K = frames[0].camera.K
    time_s = np.array([f.timestamp_s for f in frames])
    args.pictures.mkdir(parents=True, exist_ok=True)
    print(f"machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, "
          f"Python {platform.python_version()}")
    print(f"recording {args.recording}: {n} frames, fault window {window[0]}-{window[1] - 1}, cut from {cut_name}")
    results: dict = {}
    for preset in args.preset:
        config = PRESETS[preset]
        clean = track(list(enumerate(frames)), masks[0], config(), f"{preset} clean", args.quiet)
        results[preset] = {}
        runs_for_plot = {}
        for name in args.scenario:
            tracked, bars, away = faulted(name, frames, box, other, window, args.seed)
            run = track(tracked, masks[0], config(), f"{preset} {name}", args.quiet)
            s = score(run, clean, masks, bars, away, window, K)
            results[preset][name] = s
            t = time_s[s["series"]["frame"]]
            dev = np.array([np.nan if d is None else d for d in s["series"]["deviation_mm"]])
            runs_for_plot[name] = {"time_s": t, "mean_mm": dev, "confidence": s["series"]["confidence"],
                                   "lost": s["series"]["lost"]}
            if name == "bar" and preset == args.preset[0]:
                picks = [int(v) for v in np.linspace(window[0], window[1] - 1, 5).round()] + [min(n - 1, window[1] + 5)]
                picks = [i for i in picks if i in run["estimates"]]
                strip = _strip(dict(tracked), run["estimates"], picks, box, K, name)
                cv2.imwrite(str(args.pictures / f"real_faults_{args.recording}_bar.png"), strip[:, :, ::-1])
        in_window = ((np.arange(n) >= window[0]) & (np.arange(n) < window[1])).astype(float)
        error_with_occlusion(args.pictures / f"real_faults_{args.recording}_{preset}.png",
                             f"{args.recording}, {preset}: each fault against the clean run",
                             runs_for_plot, time_s, in_window, WRONG_MM, CONFIDENT, shaded="the fault window",
                             error_label="deviation from the clean run (mm)")
    table = _table(results)
    print(table)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"recording": args.recording, "cut_from": cut_name, "window": window,
                                     "cpu_count": os.cpu_count(), "results": results}, indent=1))
    (args.json.parent / "summary.md").write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
