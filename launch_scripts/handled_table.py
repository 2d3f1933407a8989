"""The "Tracking while handled" table of ``python -m launch_scripts.evaluate --handled``.

For each handled scene (``sim.scenes.HANDLED_SCENES``) and seed, the scene is recorded twice:
with its occluder drawn, and as its twin without it (same physics, same noise draws). Each
tracker of ``PRESETS`` (the defaults, the realtime preset, the defaults without the stretch
term) then tracks:

- ``clear``: the twin, every frame;
- ``occluder``: the scene with its occluder, every frame (30 Hz);
- ``dropped``: the same frames with every other one dropped (15 Hz, timestamps kept);

the last two three times, by what the frames tell the tracker (``MASKS``): nothing
("unknown"); the occluder's exact mask (``RGBDFrame.occluder_mask``, "known"); everything
a robot knows of its own doing ("robot"): that mask, the cloth vertex its closed gripper
holds (``sim.evaluation.handled.HOLD_REACH_M``) and where the fingers are
(``RGBDFrame.held_vertices``), and the empty workspace
seen before the cloth was there (the tracker's background). Every run starts from the true
mask of the cloth as seen in its first frame (without what the occluder hides), so the
table measures tracking, not the first frame's segmentation.
Scores (``sim.evaluation.handled``) are pooled over the seeds in the table; the JSON keeps
every seed's scores and per-frame series.

This module is the table's code; ``python -m launch_scripts.handled_table --help`` says how to
run it (``python -m launch_scripts.evaluate --handled``), and nothing else is done.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from launch_scripts.cli import OneLineParser
from launch_scripts.evaluate import write_section
from perception.tracker import TrackerConfig
from sim.evaluation import SceneRecording, record_scene
from sim.evaluation.figures import error_with_occlusion, overlay_strip
from sim.evaluation.handled import (
    CONFIDENT,
    HOLD_REACH_M,
    LOST_WITHIN,
    WORST_AREA_MIN,
    WRONG_MM,
    HandledScore,
    cloth_hidden_fraction,
    score_run,
    track_frames,
)

log = logging.getLogger("launch_scripts.evaluate")

BEGIN, END = "<!-- handled-results:begin -->", "<!-- handled-results:end -->"

#: The trackers compared: the defaults, the realtime preset, and the defaults without the
#: stretch term (the paper's energy, which lets a hidden part shrink).
PRESETS = {"default": TrackerConfig, "realtime": TrackerConfig.realtime,
           "no-stretch": lambda: TrackerConfig(lambda_l=0.0)}
#: What the frames tell the tracker of the occluder and the robot's grasp, in the table's order.
MASKS = ("unknown", "known", "robot")
#: (variant, masks) in the table's order; the twin has nothing to mask
VARIANTS = (("clear", None),) + tuple((variant, masks) for variant in ("occluder", "dropped") for masks in MASKS)


def variant_key(variant: str, masks: str | None) -> str:
    return variant if masks is None else f"{variant}/{masks}"


def evaluate_handled(name: str, seed: int, noise: bool, fig_dir: Path | None, progress: bool = True) -> dict:
    """Record one handled scene and its twin, track every variant with both presets, score them."""
    recs = {"occluder": record_scene(name, seed=seed, noise=noise, n_frames=None, progress=progress),
            "clear": record_scene(name, seed=seed, noise=noise, n_frames=None, progress=progress, occluders=False)}
    recs["dropped"] = recs["occluder"].every(2)
    hidden = cloth_hidden_fraction(recs["occluder"])
    out = {"frames": len(recs["occluder"].frames), "cloth_vertices": int(recs["occluder"].gt_vertices.shape[1]),
           "cloth_hidden_fraction": [round(float(x), 4) for x in hidden], "runs": {}, "series": {}}
    scores: dict[tuple, HandledScore] = {}
    for preset, make_config in PRESETS.items():
        for variant, masks in VARIANTS:
            rec = recs[variant]
            frames = rec.known_occluder_frames() if masks in ("known", "robot") else rec.frames
            robot = masks == "robot"
            label = f"{name} s{seed} {preset} {variant_key(variant, masks)}"
            estimates, failure = track_frames(frames, make_config(), rec.masks[0], label, progress,
                                              background=rec.background if robot else None,
                                              grips=rec.grips if robot else None)
            scores[preset, variant, masks] = score_run(rec, estimates, failure)
        for variant, masks in VARIANTS:
            score = scores[preset, variant, masks]
            summary = score.summary()
            if variant == "occluder":  # the frames the dropped variant keeps, for its ratio to full rate
                summary["even_frames_mean_mm"] = score.summary(np.arange(0, score.n_frames, 2)).get("mean_mm")
            out["runs"].setdefault(preset, {})[variant_key(variant, masks)] = summary
            out["series"].setdefault(preset, {})[variant_key(variant, masks)] = score.series()
    if fig_dir is not None:
        _figures(name, seed, recs, scores, hidden, fig_dir)
    return out


def _figures(name: str, seed: int, recs: dict[str, SceneRecording], scores: dict, hidden: np.ndarray,
             fig_dir: Path) -> None:
    times = {v: np.array([f.timestamp_s for f in rec.frames]) for v, rec in recs.items()}
    runs = {}
    for variant, masks in VARIANTS:
        score = scores["default", variant, masks]
        t = times[variant][:score.n_frames]
        runs[variant_key(variant, masks)] = {"time_s": t, "mean_mm": score.frame_mean_mm(),
                                             "confidence": score.confidence, "lost": score.lost}
    error_with_occlusion(fig_dir / f"handled_error_{name}_s{seed}.png",
                         f"{name}, seed {seed}, default tracker (wrong: > {WRONG_MM:.0f} mm; confident: >= {CONFIDENT})",
                         runs, times["occluder"], hidden, WRONG_MM, CONFIDENT)
    for masks in MASKS:
        score = scores["default", "occluder", masks]
        if score.n_frames == 0:
            continue
        last = score.n_frames - 1
        hidden_now = np.nonzero(hidden[:score.n_frames] > 0)[0]
        picks = [0, last]
        if len(hidden_now):
            picks += [int(hidden_now[0]), int(hidden_now[np.argmax(hidden[hidden_now])]), int(hidden_now[-1])]
        picks = sorted(set(min(p, last) for p in picks))
        overlay_strip(fig_dir / f"handled_overlay_{name}_s{seed}_{masks}.png",
                      recs["occluder"].frames, score.estimates, picks,
                      region=np.logical_or.reduce(recs["occluder"].masks))


def _ratio(a, b):
    return None if a is None or b is None or b <= 0 else a / b


def pooled_rows(results: dict) -> list[dict]:
    """One row per (scene, variant, masks, preset), pooled over the seeds of ``results``
    (scene -> seed -> evaluate_handled's output)."""
    rows = []
    for name, by_seed in results.items():
        for variant, masks in VARIANTS:
            for preset in PRESETS:
                key = variant_key(variant, masks)
                runs = [r["runs"][preset] for r in by_seed.values()]
                mine = [r[key] for r in runs]
                scored = [m for m in mine if m.get("frames")]
                row = {"scene": name, "variant": variant, "masks": masks, "preset": preset, "seeds": len(mine),
                       "failures": [m["failure"] for m in mine if m.get("failure")]}
                if scored:
                    row["mean_mm"] = float(np.mean([m["mean_mm"] for m in scored]))
                    row["p95_mm"] = float(np.mean([m["p95_mm"] for m in scored]))
                    to_twin = [_ratio(m.get("mean_mm"), r["clear"].get("mean_mm")) for m, r in zip(mine, runs)]
                    if variant == "dropped":
                        full = variant_key("occluder", masks)
                        to_full = [_ratio(m.get("mean_mm"), r[full].get("even_frames_mean_mm")) for m, r in zip(mine, runs)]
                        row["to_full_rate"] = [x for x in to_full if x is not None]
                    if variant != "clear":
                        row["to_twin"] = [x for x in to_twin if x is not None]
                    areas = [m["occluded_area_ratio"] for m in scored if m["occluded_area_ratio"] is not None]
                    worst = [m["occluded_area_ratio_worst"] for m in scored if m["occluded_area_ratio_worst"] is not None]
                    row["area_ratio"] = float(np.mean(areas)) if areas else None
                    row["area_ratio_worst"] = float(worst[np.argmax(np.abs(np.subtract(worst, 1.0)))]) if worst else None
                    for k in ("frames", "lost_frames", "wrong_frames", "wrong_confident_frames",
                              "wrong_unflagged_late_frames", "new_meshes"):
                        row[k] = int(sum(m[k] for m in scored))
                    row["median_ms"] = float(np.median([m["median_ms"] for m in scored if m["median_ms"] is not None]))
                rows.append(row)
    return rows


def _mean_max(values) -> str:
    if not values:
        return "—"
    return f"{np.mean(values):.2f} (max {np.max(values):.2f})" if len(values) > 1 else f"{values[0]:.2f}"


def markdown(results: dict, seeds: list[int], noises: tuple, command: str | None = None,
             fig_dir: Path = Path("docs/figures")) -> str:
    """The handled table's section of results.md; ``command`` made it (default: the command with
    ``seeds``), its figures are in ``fig_dir``."""
    rows = pooled_rows(results)
    noise_words = " and ".join("noisy" if n else "noise-free" for n in noises)
    command = command or f"python -m launch_scripts.evaluate --handled --seeds {' '.join(map(str, seeds))}"
    lines = [BEGIN, "", "## Tracking while handled", "",
             f"Generated by `{command}` on "
             f"{os.cpu_count()} CPU cores ({noise_words} frames). Scenes (`sim/scenes.py`): `occluder_sweep` (an arm- "
             "or hand-sized bar sweeps in front of a hanging printed cloth), `gripper_corner_move` (a drawn gripper "
             "with wrist and arm grasps a hanging cloth's bottom corner, lifts it and carries it sideways), "
             "`table_lift` (a gripper lifts a cloth lying on a table by one corner at 0.3-0.5 m/s until it hangs). "
             "Variants: `clear` is the same scene without the occluder drawn (same cloth motion); `occluder` "
             "every frame at 30 Hz; `dropped` every other frame (15 Hz, true timestamps). Masks: what the frames "
             "tell the tracker: `unknown` nothing; `known` the occluder's exact mask (`RGBDFrame.occluder_mask`); "
             "`robot` what a robot knows of its own doing: that mask, the cloth vertex its closed gripper holds "
             f"(the mesh's vertex nearest its fingers when they closed, if within {100 * HOLD_REACH_M:.0f} cm of them; "
             "on a mesh the tracker builds anew, bound again the same way) and where its fingers are "
             "(`RGBDFrame.held_vertices`), and the empty workspace seen before the cloth was there (the tracker's "
             "background). Every run starts from the true mask of the cloth as seen in "
             "its first frame. Presets: `default` (`TrackerConfig()`), `realtime` (`TrackerConfig.realtime()`), "
             "`no-stretch` (the defaults without the stretch term, `lambda_l` = 0).", "",
             "Columns, pooled over the seeds: error = material-point error, mean / 95th percentile in mm (means "
             "over seeds); ÷ clear = mean error over the clear twin's (mean over seeds, worst seed); ÷ full rate "
             "= the dropped run's mean error over the full-rate run's on the same frames; occluded area = area of "
             "the estimated faces whose three vertices are truly hidden (their material point projects onto the "
             "occluder's exact mask and lies behind it), over the same faces' true area (where their material "
             "points really are: cloth bunched in a gripper's fingers is not counted as squeezed), area-weighted over "
             "frames (1 = kept its size; in brackets the frame farthest from 1 among frames whose hidden faces "
             f"hold at least {100 * WORST_AREA_MIN:.0f} % of the mesh); lost = frames flagged lost; wrong & "
             f"confident = frames whose mean vertex error exceeds {WRONG_MM:.0f} mm (wrong) while the tracker's "
             f"confidence is {CONFIDENT} or more; not lost after {LOST_WITHIN} = wrong frames not flagged lost "
             f"after {LOST_WITHIN} wrong frames in a row (issue 11: right, or lost within {LOST_WITHIN} frames); "
             "new meshes = times the tracker re-acquired the object by segmenting it again and laid a new mesh "
             "on it (its material coordinates start afresh: the errors count from there, each vertex bound to "
             "the material point it was laid on); ms = median tracking time per frame.",
             "",
             "| scene | variant | masks | preset | error (mm) | ÷ clear | ÷ full rate | occluded area | lost | "
             f"wrong & confident | wrong, not lost after {LOST_WITHIN} | new meshes | ms |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        masks = r["masks"] or "—"
        head = f"| {r['scene']} | {r['variant']} | {masks} | {r['preset']} | "
        if "mean_mm" not in r:
            lines.append(head + "failed: " + "; ".join(r["failures"]) + " | | | | | | | | |")
            continue
        area = "—" if r["area_ratio"] is None else f"{r['area_ratio']:.2f}"
        if r["area_ratio_worst"] is not None:
            area += f" ({r['area_ratio_worst']:.2f})"
        cells = [f"{r['mean_mm']:.1f} / {r['p95_mm']:.1f}", _mean_max(r.get("to_twin", [])),
                 _mean_max(r.get("to_full_rate", [])), area, f"{r['lost_frames']}/{r['frames']}",
                 f"{r['wrong_confident_frames']}/{r['frames']}", f"{r['wrong_unflagged_late_frames']}/{r['frames']}",
                 str(r["new_meshes"]), f"{r['median_ms']:.1f}"]
        lines.append(head + " | ".join(cells) + " |")
        if r["failures"]:
            lines[-1] += " " + "; ".join(f"failed at {f}" for f in r["failures"])
    load = "/".join(f"{x:.2f}" for x in os.getloadavg())
    lines += ["", f"Load average (1/5/15 min) when the run ended: {load}.", "",
              f"Figures (in `{Path(fig_dir).as_posix()}/`, first seed): `handled_error_<scene>_s<seed>.png` (mean error and "
              "confidence over time for every variant, the occluder's passage shaded, lost frames marked), "
              "`handled_overlay_<scene>_s<seed>_<masks>.png` (the default tracker's mesh over the RGB frames before, "
              "during and after the occlusion).", "", END]
    return "\n".join(lines)


def run_handled(scenes: list[str], seeds: list[int], noises: tuple, out: Path, fig_dir: Path,
                progress: bool = True, command: str | None = None) -> int:
    """Evaluate the handled scenes and write ``out/handled_results.json``, figures and the
    section of ``out/results.md`` (``command`` is its "Generated by" line's); returns the exit status."""
    results: dict = {}
    jobs = [(name, seed, noise) for name in scenes for seed in seeds for noise in noises]
    for name, seed, noise in tqdm(jobs, desc="handled scenes", unit="scene", disable=not progress):
        key = name if len(noises) == 1 else f"{name}/{'noisy' if noise else 'clean'}"
        result = evaluate_handled(name, seed, noise, fig_dir if seed == seeds[0] else None, progress)
        results.setdefault(key, {})[str(seed)] = result
        for preset in PRESETS:
            runs = result["runs"][preset]
            tqdm.write(f"{key} seed {seed} {preset}: clear {runs['clear'].get('mean_mm', float('nan')):.1f} mm, "
                       f"occluder {runs['occluder/unknown'].get('mean_mm', float('nan')):.1f} mm, "
                       f"dropped {runs['dropped/unknown'].get('mean_mm', float('nan')):.1f} mm")
    (out / "handled_results.json").write_text(json.dumps(results, indent=1))
    write_section(out / "results.md", markdown(results, seeds, noises, command, fig_dir), BEGIN, END)
    print(f"wrote {out / 'results.md'}, {out / 'handled_results.json'} and figures in {fig_dir}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The module's command line: only ``--help``, which says what it is and how to run it."""
    return OneLineParser(
        prog="python -m launch_scripts.handled_table", description=__doc__.split("\n\n")[0].replace("``", ""),
        epilog="The table is made by python -m launch_scripts.evaluate --handled [--scenes NAME ...] "
               "[--seeds 0 2 4] [--noise {noisy,clean,both}] [--out DIR] (see its --help): for each handled scene "
               "and seed it records the scene and its twin without the occluder, tracks them with the default, "
               "realtime and no-stretch trackers, with every frame and every other frame, and writes "
               "OUT/handled_results.json, OUT/figures/handled_*.png and its section of OUT/results.md. "
               "This module on its own runs nothing.")


def main(argv=None) -> int:
    build_parser().parse_args(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
