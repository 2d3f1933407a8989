"""The results of many trials: REPORT.json and a markdown summary.

REPORT.json: ``success_rate`` and ``trials`` (one record
of ``trial.run_trial`` each, with at least ``seed`` and ``success``), plus the command,
the settings, a Wilson 95 % interval, breakdowns by initial state, cloth and print (and, for
unfold trials, by how the second corner was chosen: ``by_regrasp``), and the Ray nodes that
ran the trials (when Ray did).
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from collections import Counter
from pathlib import Path

import numpy as np

from sim.evaluation.handled import CONFIDENT, LOST_WITHIN, WRONG_MM
from sim.laundry.judge import TOLERANCE_M

log = logging.getLogger(__name__)


def wilson_interval(successes: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % for the default z).

    successes, n : ints, 0 <= successes <= n; returns (low, high) in [0, 1]; (0, 1) for n = 0
    """
    if n < 0 or not 0 <= successes <= max(n, 0):
        raise ValueError(f"Expected 0 <= successes <= n, got successes={successes}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def _rate(records: list[dict], key: str = "success") -> dict:
    n = len(records)
    k = sum(bool(r.get(key)) for r in records)
    low, high = wilson_interval(k, n)
    return {"n": n, "successes": k, "rate": (k / n) if n else None, "wilson_95": [low, high]}


def failure_kind(reason: str) -> str:
    """A failure reason without its numbers, to count alike failures together."""
    if reason.startswith("error:"):
        return "error: " + reason.split(": ", 2)[1]  # the exception type
    return re.sub(r"-?\d+(\.\d+)?", "#", reason)


def nodes(records: list[dict]) -> list[dict]:
    """The Ray nodes that ran the trials (records with a ``node``), in order of first use:
    ``id``, ``ip``, ``host`` and ``trials`` (how many ran there); [] for a run without Ray's."""
    used: dict[str, dict] = {}
    for r in records:
        node = r.get("node")
        if node:
            used.setdefault(node["id"], {"id": node["id"], "ip": node.get("ip"), "host": node.get("host"), "trials": 0})
            used[node["id"]]["trials"] += 1
    return list(used.values())


def summarise(records: list[dict]) -> dict:
    """Success rates (with Wilson 95 % intervals), breakdowns and medians of a run.

    records : trial records (``run_trial``); returns a JSON-ready dict
    """
    ran = [r for r in records if not str(r.get("failure", "")).startswith("error:")]

    def median(values) -> float | None:
        values = [v for v in values if v is not None]
        return round(float(np.median(values)), 3) if values else None

    by = {}
    for key, name_of in (("state", str), ("cloth", str), ("printed", _print_name)):
        groups: dict[str, list] = {}
        for r in records:
            groups.setdefault(name_of(r.get("scene", {}).get(key, "?")), []).append(r)
        by[key] = {name: _rate(group) for name, group in sorted(groups.items())}
    timing = [r.get("timing", {}) for r in records]
    regrasps: dict[str, list] = {}
    for r in records:
        if r.get("task") == "unfold":
            regrasps.setdefault(str(r.get("regrasp", "?")), []).append(r)
    by_regrasp = {name: _unfold_summary(group, median) for name, group in sorted(regrasps.items())}
    return {
        **({"by_regrasp": by_regrasp} if by_regrasp else {}),
        "success": _rate(records),
        "corner_success": _rate(records, "corner_success"),
        "trials_that_could_not_run": len(records) - len(ran),
        "by_state": by["state"],
        "by_cloth": by["cloth"],
        "by_print": by["printed"],
        "failures": dict(Counter(failure_kind(r.get("failure", "")) for r in records if not r.get("success")).most_common()),
        "median_corner_error_m": median(r.get("corner_error_m") for r in ran),
        "median_tracking_error_mm": median(r.get("tracking_error_mm", {}).get("mean") for r in ran),
        "median_tracking_ms": median(t.get("tracking_ms") for t in timing),
        "median_planning_ms": median(t.get("planning_ms") for t in timing),
        "median_total_s": median(t.get("total_s") for t in timing),
        "nodes": nodes(records),
    }


def _print_name(printed) -> str:
    """A trial's cloth by its print, as the report names it: "printed" (a print the tracker's
    features hold on to), "plain" (no texture: its material points are followed by shape alone)
    or "?" (not recorded)."""
    return {True: "printed", False: "plain"}.get(printed, "?")


def _unfold_summary(records: list[dict], median) -> dict:
    """Success, first grasps at a corner, tracking error during the lift and at the second
    plan (medians over trials of their mean and p95, mm) and trial time of unfold trials;
    of the trials that declined the corner they would have taken (unseen, or not confirmed
    by the measured surface, at every look; or no corner of the cloth), how many had a true adjacent corner in the
    camera's sight all the same (``tracking.true_adjacent_seen``); how many took a second
    corner only after turning the cloth (``looks``), and how many of those succeeded; and,
    summed over the trials' lifts and hangs up to the second plan (``tracking.honesty``), the
    frames tracked, those wrong, wrong and confident, wrong yet not flagged lost in time
    (``sim.evaluation.handled``), and right and confident; and the looks at the second corner
    judged by ground truth (``_looks_judged``)."""
    def err(key: str, stat: str):
        errors = [(r.get("tracking") or {}).get(key) for r in records]
        return median(e.get(stat) if e else None for e in errors)

    declined = [r for r in records if "declined" in (r.get("second_grasp") or {})]
    honesty = [h for h in ((r.get("tracking") or {}).get("honesty") for r in records) if h]
    frames = {key: sum(h.get(key, 0) for h in honesty)
              for key in ("frames", "wrong", "wrong_confident", "wrong_not_lost_after_3", "right_confident")}
    in_sight = sum(any(((r.get("tracking") or {}).get("true_adjacent_seen") or {}).values()) for r in declined)
    turned = [r for r in records if (r.get("looks") or {}).get("count", 1) > 1 and "plan_cam" in (r.get("second_grasp") or {})]
    return {"success": _rate(records), "first_grasp_at_corner": _rate(records, "corner_success"),
            "declined": {"trials": len(declined), "true_adjacent_corner_in_sight": in_sight},
            "taken_after_turning": _rate(turned),
            "looks": _looks_judged(records),
            "median_lift_error_mm": {"mean": err("lift_error_mm", "mean"), "p95": err("lift_error_mm", "p95")},
            "median_second_plan_error_mm": {"mean": err("second_plan_error_mm", "mean"),
                                            "p95": err("second_plan_error_mm", "p95")},
            "lift_and_hang_frames": frames,
            "median_frames_tracked": median((r.get("tracking") or {}).get("frames_tracked") for r in records),
            "median_total_s": median(r.get("timing", {}).get("total_s") for r in records)}


def _looks_judged(records: list[dict]) -> dict:
    """Every look at the second corner that judged its corner by ground truth
    (``to_true_adjacent_m``: those declined, ``looks.declined``, and the one that took it):
    how many took the corner and how many of those planned it within ``TOLERANCE_M`` of a true
    corner sharing an edge with the held one; how many declined it, and in how many of those
    the planned grasp, or the estimate's corner itself, lay that close to one all the same.
    What the controller's caution costs, and what its trust does."""
    counts = dict.fromkeys(("looks", "taken", "taken_right", "declined", "declined_plan_right",
                            "declined_estimate_right"), 0)
    for r in records:
        second = r.get("second_grasp") or {}
        looks = [(look, False) for look in (r.get("looks") or {}).get("declined", [])]
        looks += [(second, True)] if "plan_cam" in second else []
        for look, took in looks:
            truth = look.get("to_true_adjacent_m")
            if not truth:
                continue
            right = {k: v <= TOLERANCE_M for k, v in truth.items()}
            counts["looks"] += 1
            if took:
                counts["taken"] += 1
                counts["taken_right"] += right["plan"]
            else:
                counts["declined"] += 1
                counts["declined_plan_right"] += right["plan"]
                counts["declined_estimate_right"] += right["estimate_corner"]
    return counts


def report(records: list[dict], command: str, settings: dict) -> dict:
    """REPORT.json's content: records sorted by seed, their summary, the command and settings."""
    records = sorted(records, key=lambda r: r["seed"])
    summary = summarise(records)
    return {"command": command, "settings": settings, "cpu_count": os.cpu_count(),
            "success_rate": summary["success"]["rate"], "wilson_95": summary["success"]["wilson_95"],
            "summary": summary, "trials": records}


def markdown(rep: dict) -> str:
    """A markdown summary of a report: success rate with its 95 % Wilson interval, breakdowns, failures."""
    s = rep["summary"]
    kind = rep["settings"].get("kind", "?")

    def pct(rate: dict) -> str:
        if rate["n"] == 0:
            return "no trials"
        lo, hi = rate["wilson_95"]
        return (f"{rate['successes']}/{rate['n']} = {100 * rate['rate']:.1f} % "
                f"(95 % Wilson interval {100 * lo:.1f}-{100 * hi:.1f} %)")

    seeds = [r["seed"] for r in rep["trials"]]
    parity = "even (development)" if all(x % 2 == 0 for x in seeds) else (
        "odd (evaluation)" if all(x % 2 for x in seeds) else "mixed even and odd")
    unfold = "by_regrasp" in s
    title = "unfolding by two adjacent corners" if unfold else f"{kind} grasps"
    lines = [
        f"# Laundry-grasping trials: {title}",
        "",
        f"Command: `{rep['command']}` ({rep['cpu_count']} CPU cores); seeds {parity}.",
        "",
        f"- **success: {pct(s['success'])}**",
        *([f"- first grasps at a corner (within {100 * TOLERANCE_M:.0f} cm of a true corner): {pct(s['corner_success'])}",
           f"- trials that could not run: {s['trials_that_could_not_run']}"] if unfold else [
          f"- corner grasps (within {100 * TOLERANCE_M:.0f} cm of a true corner, lifted clear): {pct(s['corner_success'])}",
          f"- trials that could not run: {s['trials_that_could_not_run']}",
          (f"- median corner error {s['median_corner_error_m']} m, median tracking error at plan time "
           f"{s['median_tracking_error_mm']} mm (mean over vertices)")]),
        (f"- median tracking {s['median_tracking_ms']} ms/frame, planning {s['median_planning_ms']} ms, "
         f"trial {s['median_total_s']} s"),
        *_nodes_lines(s.get("nodes", [])),
        "",
    ]
    for title, key in (("initial state", "by_state"), ("cloth", "by_cloth"), ("print", "by_print")):
        lines += [f"| {title} | success |", "| --- | --- |", *[f"| {name} | {pct(rate)} |" for name, rate in s[key].items()],
                  ""]
    if unfold:
        lines += ["Second corner chosen by (adjacent: the tracked mesh's outline; lowest: the hanging cloth's "
                  "lowest point; redetect: a tracker started afresh on the hanging cloth). Tracking error: "
                  "material-point error of the estimate, median over trials of the mean / 95th percentile, mm.", "",
                  "Declined: trials that grasped nothing rather than a corner the estimate said was unseen or "
                  "the measured surface did not confirm, and of them how many had a true adjacent corner in the "
                  "camera's sight (ground truth).", "",
                  f"Wrong frames: of the frames of the lifts and hangs up to the second plan, those whose mean "
                  f"error exceeds {WRONG_MM:g} mm: how many, how many of them with confidence {CONFIDENT:g} or more, "
                  f"and how many not flagged lost after {LOST_WITHIN} wrong frames in a row.", "",
                  "| second corner | success | first grasp at a corner | error during the lift | "
                  "error at the second plan | declined (true corner in sight) | wrong frames: all / confident / "
                  "not lost after 3 | frames tracked | trial s |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for name, u in s["by_regrasp"].items():
            lift, second = u["median_lift_error_mm"], u["median_second_plan_error_mm"]
            declined, wrong = u["declined"], u["lift_and_hang_frames"]
            lines.append(f"| {name} | {pct(u['success'])} | {pct(u['first_grasp_at_corner'])} | "
                         f"{lift['mean']} / {lift['p95']} | {second['mean']} / {second['p95']} | "
                         f"{declined['trials']} ({declined['true_adjacent_corner_in_sight']}) | "
                         f"{wrong['wrong']} / {wrong['wrong_confident']} / {wrong['wrong_not_lost_after_3']} of "
                         f"{wrong['frames']} | {u['median_frames_tracked']} | {u['median_total_s']} |")
        lines.append("")
        lines += [f"- {name}: {u['taken_after_turning']['n']} trials took their second corner only after turning "
                  f"the hanging cloth (no look before confirmed one), and {pct(u['taken_after_turning'])} of them "
                  "succeeded" for name, u in s["by_regrasp"].items() if u["taken_after_turning"]["n"]]
        for name, u in s["by_regrasp"].items():
            k = u["looks"]
            if k["looks"]:
                lines.append(f"- {name}: of {k['looks']} looks at the second corner, the robot took the corner it chose "
                             f"in {k['taken']} ({k['taken_right']} planned within {100 * TOLERANCE_M:.0f} cm of a true "
                             f"corner sharing an edge with the held one) and declined it in {k['declined']} (in "
                             f"{k['declined_plan_right']} of them the planned grasp, in {k['declined_estimate_right']} "
                             "the estimate's corner lay that close to one: ground truth)")
        lines += [""]
    if s["failures"]:
        lines += ["| failure | trials |", "| --- | --- |", *[f"| {k} | {n} |" for k, n in s["failures"].items()], ""]
    return "\n".join(lines)


def _nodes_lines(used: list[dict]) -> list[str]:
    """The markdown line listing the Ray nodes that ran the trials, or none without Ray's."""
    if not used:
        return []
    each = "; ".join(f"{n['host']} ({n['ip']}, node {n['id'][:12]}): {n['trials']} trial{'s' if n['trials'] > 1 else ''}"
                     for n in used)
    return [f"- ran on {len(used)} Ray node{'s' if len(used) > 1 else ''}: {each}"]


def write_json(path: Path, content: dict) -> None:
    """Write ``content`` as indented JSON, creating the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(content, indent=1) + "\n")
