"""Tracking a cloth lifted off a table by one corner: the tracker's error during the lift and
while the cloth hangs, with and without what the robot knows (its empty table, the vertex it
holds and where, the material point hanging lowest and where), the stretch term, the
tethers (no point of the cloth farther from the held one than along the cloth) and, on a
printed cloth, its first frame's texture found again in each frame.

    python benchmarks/lift_tracking.py --seeds 2 4 22 [--state flat] [--variants I ...] [--markdown OUT.md]

For each seed: the laundry scene of the unfold trials (``sim.laundry``, the "room" view), the
first gripper grasps the true corner nearest the camera, lifts it straight up at 0.3 m/s until
the cloth hangs clear and holds still for 1.5 s while it comes to rest; every frame (30 Hz) is
recorded with the true cloth. The frames are then tracked in-process by each variant, from the
same first frame and mask (the cloth against the empty table). Error: the material-point
metric of ``sim.ground_truth`` (mean over vertices and the frames of each phase, mm); while
hanging, also how far the estimate's vertices lie from the true cloth's surface, wherever on
it (a mesh can lie on the cloth with its material points in the wrong places: that is small
then while the material-point error is large); and for each true corner the distance at the
last frame from where the estimate puts the vertex laid nearest it at frame 0 (what a second
grasp at a corner would need).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from perception.geometry import invert_transform, transform_points  # noqa: E402
from perception.trackable import MIN_TEXTURE_SNR  # noqa: E402
from perception.tracker import MeshTracker  # noqa: E402
from sim.ground_truth import bind_to_surface, surface_points, vertex_errors  # noqa: E402

#: The variants: (name, changes to the unfold trials' tracker, send the background, send the
#: hold, send the lowest point while the cloth hangs at rest: ``perception.hanging.HangingCue``).
#: That tracker measures depth along the surface's normal, has the fold test
#: (``self_occlusion``) and the outside term (``lambda_o``), two variants go without them; and
#: it keeps every vertex within reach of the held points along the cloth (``tether``,
#: ``perception.tether``), which the third to seventh variants go without; and on a printed
#: cloth it finds its first frame's texture again in each frame (``anchor_points``,
#: ``perception.anchors``), which the first eight go without; the last lays KLT points only
#: where the image has texture above its noise (``perception.trackable``), as the tracker does
#: by default and the unfold trials' does not.
NO_ANCHORS = {"anchor_points": 0}
VARIANTS = (
    ("without the stretch term", {**NO_ANCHORS, "lambda_l": 0.0}, False, False, False),
    ("+ stretch term", NO_ANCHORS, False, False, False),
    ("+ background, hold", {**NO_ANCHORS, "lambda_l": 0.0, "tether": False}, True, True, False),
    ("+ stretch, background, hold; depth along rays, no fold test, no outside term",
     {**NO_ANCHORS, "depth_residual": "ray", "self_occlusion": False, "lambda_o": 0.0, "tether": False},
     True, True, False),
    ("+ stretch, background, hold; depth along rays", {**NO_ANCHORS, "depth_residual": "ray", "tether": False},
     True, True, False),
    ("+ stretch, background, hold", {**NO_ANCHORS, "tether": False}, True, True, False),
    ("+ stretch, background, hold, lowest point", {**NO_ANCHORS, "tether": False}, True, True, True),
    ("+ stretch, background, hold, lowest point, tethers", NO_ANCHORS, True, True, True),
    ("+ stretch, background, hold, lowest point, tethers, texture anchors (the unfold trials')", {}, True, True, True),
    ("the unfold trials', KLT points only on texture above the image's noise (the tracker's default)",
     {"min_texture_snr": MIN_TEXTURE_SNR}, True, True, True),
)


def record_lift(seed: int, state: str | None) -> dict:
    """The frames of one lift, the true cloth at each, the phase and the gripper (camera frame)."""
    from sim.grasp_execution import ExecutionConfig, GraspPose, close_fingers, fingertip_target, move_grippers
    from sim.laundry import TABLE_STATES, LaundryScene, laundry_spec, mask_from_reference
    from sim.laundry.unfold import UnfoldConfig, arm_for, lift_target

    spec = laundry_spec(seed, view="room", states=TABLE_STATES, **({"state": state} if state else {}))
    out = {"frames": [], "truth": [], "phase": [], "grip": []}
    with LaundryScene(spec, noise=True, known_occluders=True) as scene:
        reference = scene.render_empty()
        T_cam_world = invert_transform(scene.T_world_cam)
        hand = None
        phase = ["still"]

        def on_frame() -> None:
            out["frames"].append(scene.render())
            out["truth"].append(scene.cloth_vertices_cam())
            out["phase"].append(phase[0])
            held = hand is not None and hand.gripper.is_closed
            out["grip"].append(transform_points(T_cam_world, hand.gripper.position[None])[0] if held else None)

        on_frame()
        corners_cam = scene.cloth_vertices_cam()[scene.corner_vertices()]
        first = int(np.argmin(corners_cam[:, 2]))
        down = np.column_stack([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
        pose = GraspPose(scene.corners_world()[first], down, 0.04)
        execution, motion = ExecutionConfig(), UnfoldConfig()
        top = spec.table_top_z
        tip = fingertip_target(pose, top, execution)
        hand = scene.add_robot_hand(tip + [0.0, 0.0, 0.1], pose.quat_xyzw, arm_for(tip, top, motion))
        phase[0] = "approach"
        move_grippers(scene, [(hand.gripper, tip, None)], 0.25, on_frame)
        close_fingers(scene, hand.gripper, pose, tip, execution)
        hand.opening_m = 0.0
        rest = np.column_stack([scene.uv_m, np.zeros(len(scene.uv_m))])
        target = lift_target(tip, rest, scene.corner_vertices()[first], top, motion)
        phase[0] = "lift"
        move_grippers(scene, [(hand.gripper, target, None)], np.linalg.norm(target - tip) / motion.lift_speed_m_s,
                      on_frame)
        phase[0] = "hang"
        for _ in range(round(motion.hang_s * scene.fps)):
            scene.step_coming_to_rest()
            on_frame()
        out.update(reference=reference, mask=mask_from_reference(out["frames"][0], reference), faces=scene.faces,
                   corners=scene.corner_vertices(), first=first, describe=spec.describe(),
                   T_world_cam=scene.T_world_cam, table_top_m=top)
    out["truth"] = np.stack(out["truth"])
    return out


def _off_surface(points: np.ndarray, true_vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N,) metres from each of ``points`` (N, 3) to the nearest point of the true cloth."""
    nearest = surface_points(true_vertices, faces, *bind_to_surface(points, true_vertices, faces))
    return np.linalg.norm(points - nearest, axis=1)


def track(lift: dict, changes: dict, background: bool, hold: bool, lowest: bool) -> dict:
    """Track the recorded lift with the unfold trials' tracker changed by ``changes``."""
    from launch_scripts.trial_runner.trial import UNFOLD_TRACKER
    from perception.hanging import HangingCue
    from sim.laundry import seen_cloth_points

    tracker = MeshTracker(dataclasses.replace(UNFOLD_TRACKER, **changes))
    frames, truth = lift["frames"], lift["truth"]
    first = tracker.initialise(frames[0], lift["mask"], background=lift["reference"] if background else None)
    held = int(np.argmin(np.linalg.norm(first.vertices - truth[0][lift["corners"][lift["first"]]], axis=1)))
    cue = HangingCue(first.canonical, first.faces, held, lift["T_world_cam"], support_height_m=lift["table_top_m"])
    estimates = [first]
    for frame, grip in zip(frames[1:], lift["grip"][1:]):
        if hold and grip is not None:
            ids, points = [held], [grip]
            low = cue.update(seen_cloth_points(frame, lift["reference"]), grip) if lowest else None
            if low is not None:
                ids.append(low[0])
                points.append(low[1])
            frame = dataclasses.replace(frame, held_vertices=np.array(ids), held_points_m=np.stack(points))
        estimates.append(tracker.track(frame))
    errors = vertex_errors(np.stack([e.vertices for e in estimates]), truth, lift["faces"])
    phases = np.array(lift["phase"])
    off_surface_mm = [1000 * _off_surface(estimates[i].vertices, truth[i], lift["faces"]).mean()
                      for i in np.flatnonzero(phases == "hang")]
    laid = [int(np.argmin(np.linalg.norm(first.vertices - truth[0][c], axis=1))) for c in lift["corners"]]
    corner_mm = [1000 * float(np.linalg.norm(estimates[-1].vertices[v] - truth[-1][c]))
                 for v, c in zip(laid, lift["corners"])]
    return {"lift_mm": 1000 * float(errors[phases == "lift"].mean()),
            "hang_mm": 1000 * float(errors[phases == "hang"].mean()),
            "hang_surface_mm": float(np.mean(off_surface_mm)),
            "held_corner_mm": corner_mm[lift["first"]],
            "other_corners_mm": [round(c) for i, c in enumerate(corner_mm) if i != lift["first"]],
            "lost_frames": sum(bool(e.lost) for e in estimates), "frames": len(estimates),
            "ms": float(np.median([e.timing_ms for e in estimates[1:]]))}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python benchmarks/lift_tracking.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[2, 4, 22])
    p.add_argument("--state", default="flat", help="initial state forced on every seed (default flat; '' for drawn)")
    p.add_argument("--markdown", type=Path, help="also write the table there")
    p.add_argument("--variants", type=int, nargs="+", metavar="I",
                   help=f"run only these trackers, by position in the list (1-{len(VARIANTS)}; default all)")
    return p


def main(argv=None) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    if any(not 1 <= i <= len(VARIANTS) for i in args.variants or ()):
        p.error(f"--variants: positions run from 1 to {len(VARIANTS)}, got {args.variants}")
    variants = [VARIANTS[i - 1] for i in args.variants] if args.variants else VARIANTS
    rows = ["| seed | cloth | tracker | error during the lift mm | while hanging mm | hanging: off the cloth's "
            "surface mm | held corner mm | other corners mm | frames flagged lost | ms/frame |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    results = {name: [] for name, *_ in variants}
    for seed in tqdm(args.seeds, desc="lifts", unit="seed"):
        lift = record_lift(seed, args.state or None)
        for name, changes, background, hold, lowest in variants:
            r = track(lift, changes, background, hold, lowest)
            results[name].append(r)
            rows.append(f"| {seed} | {lift['describe'].split(': ', 1)[1]} | {name} | {r['lift_mm']:.0f} | "
                        f"{r['hang_mm']:.0f} | {r['hang_surface_mm']:.0f} | {r['held_corner_mm']:.0f} | "
                        f"{', '.join(map(str, r['other_corners_mm']))} | "
                        f"{r['lost_frames']}/{r['frames']} | {r['ms']:.0f} |")
    rows += ["", f"Over the {len(args.seeds)} seeds:", "",
             "| tracker | error during the lift mm, mean | while hanging mm, mean (median) | other corners mm, median "
             "| frames flagged lost |", "| --- | --- | --- | --- | --- |"]
    for name, runs in results.items():
        hang = [r["hang_mm"] for r in runs]
        corners = [c for r in runs for c in r["other_corners_mm"]]
        lost = sum(r["lost_frames"] for r in runs) / sum(r["frames"] for r in runs)
        rows.append(f"| {name} | {np.mean([r['lift_mm'] for r in runs]):.0f} | {np.mean(hang):.0f} "
                    f"({np.median(hang):.0f}) | {np.median(corners):.0f} | {100 * lost:.0f} % |")
    table = "\n".join(rows)
    print(f"{os.cpu_count()} CPU cores\n{table}")
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
