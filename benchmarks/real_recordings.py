"""The mesh tracker on real recordings, scored against their reference masks and ground-truth flow.

    python benchmarks/real_recordings.py [--data DIR] [--recording NAME ...] [--preset default realtime]
        [--set NAME=VALUE ...] [--init mask|depth] [--tolerance-px 3] [--max-frames N]
        [--json OUT.json] [--pictures DIR]

Recordings are sequence folders made by ``python -m launch_scripts.convert_recording`` under
``--data`` (default: $CLOTHKIT_DATA, else /work/data). Each is tracked with every preset
(``default`` = ``TrackerConfig()``, ``realtime`` = ``TrackerConfig.realtime()``), both with
the ``--set`` overrides (any TrackerConfig field, ``segmentation.<field>`` for the
segmentation's). ``--init mask`` (default) starts from the first frame's reference mask when
the recording has one, as a user passing ``--init-mask`` would; ``depth`` lets the tracker
find the object itself.

Per frame: ``coverage``, the fraction of the reference mask covered by the projected mesh;
``on_mask``, the fraction of vertices projecting onto the reference mask or within
``--tolerance-px`` of it (depth and colour of a Kinect v1 are registered only to a few
pixels); confidence, lost and tracking time. Per ground-truth flow pair: the vertices'
error against the scene flow, next to the error of not moving at all. Writes a JSON
summary, a picture strip per run (mesh over the frames, reference mask outlined green) and
prints a table.
"""

from __future__ import annotations

import ast
import json
import os
import platform
import sys
import time
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from launch_scripts.cli import OneLineParser, exit_130_on_ctrl_c, positive_int  # noqa: E402
from perception.geometry import pixel_index, project  # noqa: E402
from perception.overlay import draw_mesh, outlined_text  # noqa: E402
from perception.raster import bounding_box  # noqa: E402
from perception.recording_scores import flow_score, mask_coverage, vertices_on_mask  # noqa: E402
from perception.recordings import data_root, read_groundtruth_flow, read_reference_masks  # noqa: E402
from perception.sequence import SequenceError, open_sequence  # noqa: E402
from perception.tracker import MeshTracker, TrackerConfig, TrackingError  # noqa: E402

PRESETS = {"default": TrackerConfig, "realtime": TrackerConfig.realtime}
TARGET_COVERAGE = 0.8
TARGET_ON_MASK = 0.9


def parse_overrides(items: list[str]) -> dict:
    """``NAME=VALUE`` strings as a dict; values are Python literals (0.01, True, (0.04, 0.02)) or strings."""
    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise ValueError(f"--set {item!r}: expected NAME=VALUE")
        try:
            value = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            value = text
        out[name.strip()] = value
    return out


def with_overrides(config, overrides: dict):
    """``config`` (a dataclass) with ``overrides``; ``a.b`` sets field b of the nested dataclass a."""
    flat, nested = {}, {}
    for name, value in overrides.items():
        head, dot, rest = name.partition(".")
        (nested.setdefault(head, {}).__setitem__(rest, value) if dot else flat.__setitem__(name, value))
    known = {f.name for f in fields(config)}
    unknown = sorted((set(flat) | set(nested)) - known)
    if unknown:
        raise ValueError(f"unknown {type(config).__name__} parameter(s): {', '.join(unknown)}")
    for head, sub in nested.items():
        inner = getattr(config, head)
        if not is_dataclass(inner):
            raise ValueError(f"{type(config).__name__}.{head} has no fields to set")
        flat[head] = with_overrides(inner, sub)
    try:
        return replace(config, **flat)
    except TypeError as exc:
        raise ValueError(f"{type(config).__name__}: {exc}") from None


def recordings_under(root: Path, names: list[str] | None) -> list[Path]:
    if names:
        paths = [root / n for n in names]
        missing = [str(p) for p in paths if not (p / "rgb.txt").is_file()]
        if missing:
            raise ValueError(f"not a converted recording (no rgb.txt): {', '.join(missing)}")
        return paths
    if not root.is_dir():
        raise ValueError(f"{root}: no such folder (set --data or CLOTHKIT_DATA)")
    paths = sorted(p for p in root.iterdir() if (p / "rgb.txt").is_file())
    if not paths:
        raise ValueError(f"{root}: holds no converted recording (folders with rgb.txt)")
    return paths


def picture_strip(tiles: list[tuple[np.ndarray, np.ndarray | None]], crop_to: np.ndarray, width: int = 1800) -> np.ndarray:
    """Tiles (RGB overlay, reference mask or None) in a grid about 16:9, each cropped to
    ``crop_to``'s box, the reference mask outlined green."""
    box = bounding_box(crop_to, pad=40)
    y0, y1, x0, x1 = box if box is not None else (0, crop_to.shape[0], 0, crop_to.shape[1])
    aspect = (x1 - x0) / (y1 - y0)
    columns = min(range(1, len(tiles) + 1), key=lambda c: abs(c * aspect / np.ceil(len(tiles) / c) - 16 / 9))
    tile_w = width // columns
    tile_h = max(1, round((y1 - y0) * tile_w / (x1 - x0)))
    out = []
    for img, mask in tiles:
        img = np.ascontiguousarray(img.copy())
        if mask is not None:
            outline, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(img, outline, -1, (0, 220, 0), 1)
        out.append(cv2.resize(img[y0:y1, x0:x1], (tile_w, tile_h), interpolation=cv2.INTER_AREA))
    out += [np.zeros_like(out[0])] * (-len(out) % columns)
    return np.vstack([np.hstack(out[r:r + columns]) for r in range(0, len(out), columns)])


def run_one(seq, masks: dict, flows: list, config: TrackerConfig, args, label: str) -> dict:
    """Track ``seq`` with ``config``; return the per-frame records, flow scores and picture."""
    n = len(seq) if args.max_frames is None else min(len(seq), args.max_frames)
    pick = set(np.linspace(0, n - 1, min(n, args.strip_frames)).round().astype(int).tolist())
    tracker = MeshTracker(config)
    frames, tiles, kept = [], [], {}
    previous = None
    crop = np.zeros((seq.camera.height, seq.camera.width), bool)
    flow_sources = {p.source for p in flows} | {p.target for p in flows}
    for i in tqdm(range(n), desc=label, unit="frame", disable=args.quiet, leave=False):
        frame = seq.frame(i)
        if i == 0:
            init = masks.get(0) if args.init == "mask" else None
            try:
                estimate = tracker.initialise(frame, mask=init)
            except TrackingError as exc:
                return dict(error=f"initialise: {exc}")
        else:
            estimate = tracker.track(frame)
        K = frame.camera.K
        # a new mesh: the tracker lost the object and laid another on it, its material points anew
        new_mesh = previous is not None and not np.array_equal(estimate.canonical, previous)
        previous = estimate.canonical
        record = dict(frame=i, timestamp_s=frame.timestamp_s, confidence=estimate.confidence,
                      lost=bool(estimate.lost), new_mesh=new_mesh, timing_ms=estimate.timing_ms, coverage=None,
                      on_mask=None)
        if i in masks:
            record["coverage"] = mask_coverage(estimate.vertices, estimate.faces, K, masks[i])
            record["on_mask"] = vertices_on_mask(estimate.vertices, K, masks[i], args.tolerance_px)
            crop |= masks[i]
        frames.append(record)
        if i in flow_sources:
            kept[i] = (estimate.vertices.copy(), frame.depth_m)
        if i in pick:
            tiles.append((draw_mesh(frame.rgb, estimate, K), masks.get(i)))
            cols, rows, inside = pixel_index(project(estimate.vertices, K), seq.camera.width, seq.camera.height)
            crop[rows[inside], cols[inside]] = True  # the strip shows the mesh even where it strayed
    flow_results = []
    for pair in flows:
        if pair.source in kept and pair.target in kept:
            (vs, depth_s), (vt, _) = kept[pair.source], kept[pair.target]
            score = flow_score(vs, vt, depth_s, pair.scene_flow_m, pair.optical_flow_px, seq.camera.K)
            flow_results.append(dict(source=pair.source, target=pair.target, **score.summary()))
    return dict(vertices=int(estimate.vertices.shape[0]), frames=frames, flow=flow_results,
                strip=picture_strip(tiles, crop) if tiles else None)


def summarise(run: dict) -> dict:
    if "error" in run:
        return dict(error=run["error"])
    frames = run["frames"]
    cov = np.array([f["coverage"] for f in frames if f["coverage"] is not None])
    onm = np.array([f["on_mask"] for f in frames if f["on_mask"] is not None])
    conf = np.array([f["confidence"] for f in frames])
    timing = np.array([f["timing_ms"] for f in frames[1:]] or [frames[0]["timing_ms"]])
    out = dict(frames=len(frames), vertices=run["vertices"], frames_with_mask=len(cov),
               lost_frames=int(sum(f["lost"] for f in frames)), meshes=1 + sum(f["new_mesh"] for f in frames),
               confidence_mean=float(conf.mean()),
               confidence_min=float(conf.min()), median_ms=float(np.median(timing)))
    if len(cov):
        ok = (cov >= TARGET_COVERAGE) & (onm >= TARGET_ON_MASK)
        out.update(coverage_min=float(cov.min()), coverage_mean=float(cov.mean()), on_mask_min=float(onm.min()),
                   on_mask_mean=float(onm.mean()), frames_meeting_target=int(ok.sum()))
        # the mesh mostly off the object (on the wrong surface), yet not lost and confidence 0.5 or more
        wrong = [f for f in frames if f["on_mask"] is not None and f["on_mask"] < 0.5 and not f["lost"]
                 and f["confidence"] >= 0.5]
        out["confident_wrong_frames"] = len(wrong)
    if run["flow"]:
        out["flow"] = run["flow"]
    return out


def table_row(name: str, preset: str, s: dict) -> str:
    if "error" in s:
        return f"{name:26s} {preset:9s} error: {s['error']}"

    def fmt(key, scale=1.0, spec="5.2f"):
        return format(s[key] * scale, spec) if key in s else "  -  "
    flow = "-"
    if "flow" in s and s["flow"][0]["error_mm"] is not None:
        f = s["flow"][0]
        flow = f"{f['error_mm']['mean']:.0f} (still {f['zero_motion_mm']['mean']:.0f})"
    meet = f"{s['frames_meeting_target']}/{s['frames_with_mask']}" if "frames_meeting_target" in s else "-"
    return (f"{name:26s} {preset:9s} {s['vertices']:5d} {fmt('coverage_min')} {fmt('coverage_mean')} "
            f"{fmt('on_mask_min')} {fmt('on_mask_mean')} {meet:>7s} {s['lost_frames']:3d}/{s['frames']:<4d} "
            f"{s['meshes']:6d} {s['confidence_mean']:5.2f} {s['confidence_min']:5.2f} {s['median_ms']:7.1f}  {flow}")


def build_parser() -> OneLineParser:
    p = OneLineParser(prog="python benchmarks/real_recordings.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=None, help="folder of converted recordings (default: $CLOTHKIT_DATA, "
                                                           "else /work/data)")
    p.add_argument("--recording", nargs="+", help="names of recordings under --data (default: all)")
    p.add_argument("--preset", nargs="+", choices=sorted(PRESETS), default=["default", "realtime"])
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="NAME=VALUE",
                   help="TrackerConfig override, repeatable (e.g. spacing_m=0.01, segmentation.FIELD=VALUE)")
    p.add_argument("--init", choices=("mask", "depth"), default="mask",
                   help="mask: start from the first reference mask if any (default); depth: let the tracker segment")
    p.add_argument("--tolerance-px", type=float, default=3.0, help="on_mask tolerance around the reference mask")
    p.add_argument("--max-frames", type=positive_int, help="track at most this many frames of each recording")
    p.add_argument("--strip-frames", type=int, default=6, help="frames in each picture strip")
    p.add_argument("--json", type=Path, default=Path("out/real_recordings/summary.json"))
    p.add_argument("--pictures", type=Path, default=Path("out/real_recordings"))
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars")
    return p


@exit_130_on_ctrl_c
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        overrides = parse_overrides(args.overrides)
        configs = {name: with_overrides(PRESETS[name](), overrides) for name in args.preset}
        paths = recordings_under(args.data or data_root(), args.recording)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    args.pictures.mkdir(parents=True, exist_ok=True)
    report = dict(machine=f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}, "
                          f"Python {platform.python_version()}",
                  command=" ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
                  date=time.strftime("%Y-%m-%d %H:%M:%S"), init=args.init, tolerance_px=args.tolerance_px,
                  overrides={k: repr(v) for k, v in overrides.items()}, recordings={})
    rows = []
    for path in paths:
        try:
            seq = open_sequence(path)
            masks = read_reference_masks(seq)
            flows = read_groundtruth_flow(seq)
        except (SequenceError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        entry = report["recordings"].setdefault(path.name, dict(frames=len(seq), reference_masks=len(masks),
                                                                flow_pairs=len(flows), runs={}))
        for preset, config in configs.items():
            run = run_one(seq, masks, flows, config, args, f"{path.name} {preset}")
            summary = summarise(run)
            picture = None
            if run.get("strip") is not None:
                picture = args.pictures / f"{path.name}_{preset}.png"
                strip = run["strip"]
                outlined_text(strip, f"{path.name}, {preset}", (8, strip.shape[0] - 10))
                cv2.imwrite(str(picture), cv2.cvtColor(strip, cv2.COLOR_RGB2BGR))
            entry["runs"][preset] = dict(config=config.to_dict(), summary=summary, picture=str(picture) if picture
                                         else None, frames=run.get("frames", []))
            rows.append(table_row(path.name, preset, summary))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1, default=str) + "\n", encoding="utf-8")

    print(f"machine: {report['machine']}; init: {args.init}; on_mask tolerance {args.tolerance_px:g} px; "
          f"overrides: {overrides or 'none'}")
    print(f"{'recording':26s} {'preset':9s} {'verts':>5s} {'cov':>5s} {'cov':>5s} {'on':>5s} {'on':>5s} "
          f"{'target':>7s} {'lost':>8s} {'meshes':>6s} {'conf':>5s} {'conf':>5s} {'ms':>7s}  flow err mm")
    print(f"{'':26s} {'':9s} {'':5s} {'min':>5s} {'mean':>5s} {'min':>5s} {'mean':>5s} {'frames':>7s} "
          f"{'':8s} {'':6s} {'mean':>5s} {'min':>5s} {'median':>7s}  mean (not moving)")
    for row in rows:
        print(row)
    print(f"wrote {args.json} and pictures in {args.pictures}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
