"""The unfold task of a trial: first corner, lift while tracked, second corner, stretch.

``run_unfold(scene, link, config, record, observe)`` runs once the services are up (see
``launch_scripts.trial_runner.trial``). After the still frames that initialise the tracker
and the first corner plan (as the corner task), every frame the camera takes until the
end goes through the perception service at the camera's rate in simulation time (30 Hz),
each after the previous one's estimate arrived: the first gripper's approach, the lift
(``sim.laundry.unfold``), the hanging cloth coming to rest, the second gripper's approach
and the stretch. The robot's hands and arms are drawn in the frames, and their mask goes
with each frame as the known occluder. The second corner is chosen by
``config.regrasp``:

- "adjacent": the planner's ``AdjacentCornersRequest``: the corners next to the held one
  along the tracked mesh's canonical outline, at their tracked positions, asked
  ``even_if_lost``; the robot takes a reachable one joined to the held corner by a straight
  edge, sharp rather than blunt, seen by the camera and confirmed by the measured surface
  (``sim.laundry.controller.stretchable_corner``), and never one the canonical outline says is
  where two edges meet rather than a corner (``why_not_a_corner``: blunt at the end of a long
  edge, a T-shirt's neck corner); when the one it would take was not seen
  enough (``why_not_seen``) or not confirmed (``why_not_confirmed``), the first gripper turns
  the hanging cloth a quarter turn at its wrist and the robot asks again, up to
  ``UnfoldConfig.look_turns`` times, and grasps nothing if no look gave a corner to take;
- "lowest": the lowest point of the hanging cloth as the camera sees it (the classic
  regrasp heuristic; ``grasping.lowest_point_grasp``), no tracking needed;
- "redetect": the perception service is initialised afresh on the hanging cloth and the
  planner's best corner away from the first gripper is taken, without the lift's history.

The record gains ``task``, ``regrasp``, ``first_grasp``, ``second_grasp`` (for a corner
declined, only ``declined``: its visibility and measured tip's offset at the last look, or
its angle and edge length when it was no corner; for "adjacent", at each look, how far the
corner's planned grasp and the estimate's corner lay from a true adjacent corner:
``to_true_adjacent_m``),
``looks`` (how many times the robot asked for the second corner, and how far it turned the
cloth in all, degrees), ``unfold``
(the judgement), ``tracking`` (error during the lift and at the second plan, frames
tracked, confidence, how many frames of the lift and the hang the estimate got wrong and
reported with confidence all the same (``honesty``), and by ground truth which true corners
adjacent to the held one the camera saw then: ``true_adjacent_seen``; how far below the
gripper the cloth hung at rest against how far the tracked mesh reaches: ``hang``) and a picture strip
through the lift.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from grasping import from_the_side, lowest_point_grasp
from ipc.messages import (
    AdjacentCornersRequest,
    GraspPlan,
    InitialiseRequest,
    MeshEstimate,
    StatusReply,
    StatusRequest,
)
from perception.geometry import invert_transform, rigid_transform, transform_points
from perception.hanging import HangingCue
from perception.mesh import material_reach
from sim.evaluation.handled import CONFIDENT, WRONG_MM, unflagged_late
from sim.grasp_execution import close_fingers, fingertip_target, move_grippers, plan_to_world, pull_apart
from sim.ground_truth import error_summary, vertex_errors
from sim.laundry.controller import (
    View,
    corner_angles_deg,
    corner_to_lift_first,
    default_controller,
    edge_straightness,
    stretchable_corner,
    why_not_a_corner,
    why_not_confirmed,
    why_not_seen,
)
from sim.laundry.judge import TOLERANCE_M, judge_unfold, seen_by_camera
from sim.laundry.pictures import caption, draw_plan, save_png, strip
from sim.laundry.segment import cloth_seen, mask_from_reference, seen_cloth_points
from sim.laundry.truth import material_extent, nearest_corner, share_an_edge
from sim.laundry.unfold import (
    TautSensor,
    arm_for,
    lift_target,
    rolled,
    second_fingertip,
    stretch_targets,
)

log = logging.getLogger(__name__)

#: How the second corner is chosen (see the module docstring).
REGRASPS = ("adjacent", "lowest", "redetect")


class _Tracking:
    """Every frame from now on: rendered, sent to the perception service, its estimate kept.

    Keeps per frame the estimate's vertices, the true cloth, confidence, ``lost`` and the
    tracking time; frames themselves only where a picture is taken (``keep``). Each frame
    carries what the robot holds, where and in what orientation its grippers are (``holds``)
    and, while one hand holds the cloth
    and it hangs at rest, the material point it has lowest and where (``hanging``, on the
    cloth seen against ``reference``, the empty workspace).
    """

    def __init__(self, scene, link, frames: dict, truth: dict, estimates: dict, reference):
        self.scene, self.link, self.reference = scene, link, reference
        self.holds: list[tuple[int, object]] = []  # (mesh vertex, RobotHand holding it)
        self.hanging: HangingCue | None = None  # while one hand holds the cloth: what hangs lowest, and where
        self.lowest_sent = 0  # frames that carried the hanging cloth's lowest point
        self._T_cam_world = invert_transform(scene.T_world_cam)
        self._R_cam_world = Rotation.from_matrix(self._T_cam_world[:3, :3])
        self.frames, self.truth, self.estimates = frames, truth, estimates
        self.kept: dict[str, tuple] = {}
        self.plans: dict[str, GraspPlan | None] = {}  # the plan drawn on a kept frame
        self.phase = "approach"
        self.phases: dict[int, str] = {}

    def __call__(self) -> None:
        frame = self.scene.render()
        if self.holds:  # what the robot holds and where, from its own kinematics
            ids = [v for v, _ in self.holds]
            points = list(transform_points(self._T_cam_world, np.stack([hand.gripper.position for _, hand in self.holds])))
            quats = [(self._R_cam_world * Rotation.from_quat(hand.gripper.quat_xyzw)).as_quat() for _, hand in self.holds]
            lowest = None
            if len(self.holds) == 1 and self.hanging is not None:
                lowest = self.hanging.update(seen_cloth_points(frame, self.reference), points[0])
            if lowest is not None and lowest[0] not in ids:
                ids.append(lowest[0])
                points.append(lowest[1])
                quats.append(np.full(4, np.nan))  # found by the camera, held by no gripper
                self.lowest_sent += 1
            frame = dataclasses.replace(frame, held_vertices=np.array(ids, np.int32), held_points_m=np.stack(points),
                                        held_quats_xyzw=np.stack(quats))
        self.truth[frame.seq] = self.scene.cloth_vertices_cam()
        estimate = self.estimates[frame.seq] = self.link.estimate_of(frame)
        self.phases[frame.seq] = self.phase
        log.debug("frame %d (%s): %d vertices, confidence %.2f%s", frame.seq, self.phase, len(estimate.vertices),
                  estimate.confidence, ", lost" if estimate.lost else "")
        self.frames["last"] = frame

    def keep(self, name: str) -> None:
        """Keep the last frame and its estimate for the picture, as ``name``."""
        frame = self.frames["last"]
        self.kept[name] = (frame, self.estimates[frame.seq], self.truth[frame.seq])

    @property
    def last_seq(self) -> int:
        return self.frames["last"].seq


def _held_vertex(plan: GraspPlan, reply, estimate: MeshEstimate) -> int:
    """The canonical vertex of the first grasp: the plan's own for a planner candidate,
    else the estimate's vertex nearest the planned position (a lowest-point plan)."""
    if any(c is plan for c in reply.candidates):
        return int(plan.vertex_id)
    return int(np.argmin(np.linalg.norm(estimate.vertices - plan.position, axis=1)))


def _frame_errors(estimates: dict, truth: dict, faces: np.ndarray, last_seq: int) -> dict:
    """{seq: (N,) material-point error in metres} of the estimates up to ``last_seq``, measured
    from the first estimate on, as far as the tracker kept its first mesh."""
    first = min(estimates)
    n = estimates[first].vertices.shape[0]
    upto = []
    for s in sorted(estimates):
        if s > last_seq or estimates[s].vertices.shape[0] != n:
            break
        upto.append(s)
    errors = vertex_errors(np.stack([estimates[s].vertices for s in upto]), np.stack([truth[s] for s in upto]), faces)
    return dict(zip(upto, errors))


def _lift_errors(errors: dict, seqs: list[int]) -> dict | None:
    """Mean and 95th percentile (mm) of ``errors`` (``_frame_errors``) over ``seqs``; None
    when some of them have none (the tracker changed its mesh before)."""
    if not seqs or any(s not in errors for s in seqs):
        return None
    summary = error_summary(np.stack([errors[s] for s in seqs]))
    return {"mean": round(summary["mean_mm"], 2), "p95": round(summary["p95_mm"], 2)}


def _honesty(errors: dict, estimates: dict, seqs: list[int]) -> dict | None:
    """Over the frames ``seqs`` (the lift and the hang, up to the second plan), how many the
    estimate got wrong (mean error over ``sim.evaluation.handled.WRONG_MM``), how many of those
    it reported with confidence ``CONFIDENT`` or more, and how many it had not flagged lost
    ``LOST_WITHIN`` wrong frames later: issue 11's loss target, on the robot's own lift; and
    how many right frames it reported with that confidence (what a stricter confidence costs).
    None when some of them have no error (the tracker changed its mesh before)."""
    if not seqs or any(s not in errors for s in seqs):
        return None
    wrong = np.array([1000.0 * errors[s].mean() > WRONG_MM for s in seqs], bool)
    confident = np.array([estimates[s].confidence >= CONFIDENT for s in seqs], bool)
    lost = np.array([estimates[s].lost for s in seqs], bool)
    return {"frames": len(seqs), "wrong": int(wrong.sum()), "wrong_confident": int((wrong & confident).sum()),
            "wrong_not_lost_after_3": int(unflagged_late(wrong, lost).sum()),
            "right_confident": int((~wrong & confident).sum())}


def _second_plan(scene, link, config, tracking: _Tracking, reference, held_vertex: int, first_hand,
                 held_uv: np.ndarray | None = None) -> tuple:
    """The second grasp for ``config.regrasp``: (plan or None, the canonical distance between
    the two held points in metres, the mesh vertex the plan grasps, details for the record).
    ``held_uv`` (2,), metres: the material point the first gripper holds, by ground truth; for
    "adjacent", the details then judge the corner the robot took or declined against it
    (``_judged``); None judges nothing."""
    frame = tracking.frames["last"]
    estimate = tracking.estimates[frame.seq]
    if config.regrasp == "adjacent":
        reply, _ = link.ask(AdjacentCornersRequest(request_id=frame.seq, held_vertex=held_vertex, max_candidates=2,
                                                   even_if_lost=True),
                            frame.seq, lambda: link.frames_pub.publish(frame))
        candidates = reply.candidates
        if scene.arm != "drawn":  # only corners the second arm can take
            why = [_second_grasp_out_of_reach(scene, config, c.plan, first_hand.shoulder_world) for c in candidates]
            if candidates and all(why):
                return None, None, -1, {"reason": why[0], "n_candidates": len(candidates)}
            candidates = tuple(c for c, w in zip(candidates, why) if not w)
        held_cam = transform_points(invert_transform(scene.T_world_cam), first_hand.gripper.position[None])[0]
        if not candidates:
            return None, None, -1, {"reason": "the planner found no adjacent corner on the estimate's outline"}
        angles_deg, window_m = corner_angles_deg(estimate)
        best = stretchable_corner(candidates, estimate.canonical, held_vertex, held_cam, angles_deg, window_m)
        judged = {} if held_uv is None else {"to_true_adjacent_m": _judged(scene, best, estimate, held_uv)}
        blunt = why_not_a_corner(best, angles_deg, window_m)
        if blunt:  # the canonical outline says so: no other look changes it
            return None, None, -1, {"reason": f"adjacent corner not a corner of the cloth ({blunt}): not grasped",
                                    "angle_deg": round(angles_deg[int(best.plan.vertex_id)], 1),
                                    "material_distance_m": round(best.material_distance_m, 4),
                                    "n_candidates": len(reply.candidates), **judged}
        seen = {"visible": round(best.visible, 3), "n_candidates": len(reply.candidates),
                "tip_offset_m": None if best.tip_offset_m is None else round(best.tip_offset_m, 4), **judged}
        unseen = why_not_seen(best)
        if unseen:  # too little of it seen, and no tip close to it to confirm it
            return None, None, -1, {"reason": f"adjacent corner not seen ({unseen}): not grasped blind", **seen}
        unconfirmed = why_not_confirmed(best, held_cam)
        if unconfirmed:
            return None, None, -1, {"reason": f"adjacent corner not confirmed by the measured surface ({unconfirmed}): "
                                              "not grasped", **seen}
        distance = float(np.linalg.norm(estimate.canonical[best.plan.vertex_id] - estimate.canonical[held_vertex]))
        angle = angles_deg.get(int(best.plan.vertex_id))
        return best.plan, distance, int(best.plan.vertex_id), {
            "side": best.side, "material_distance_m": round(best.material_distance_m, 4),
            "straightness": round(edge_straightness(best, estimate.canonical, held_vertex), 3),
            "angle_deg": None if angle is None else round(angle, 1), **seen}
    if config.regrasp == "lowest":
        points = seen_cloth_points(frame, reference)
        if len(points) < 3:
            return None, None, -1, {"reason": "no cloth seen below the gripper"}
        try:
            plan = lowest_point_grasp(points, scene.T_world_cam, frame_id=frame.camera.frame_id,
                                      timestamp_s=frame.timestamp_s)
        except ValueError as exc:  # a few scattered points, no surface to grasp
            return None, None, -1, {"reason": f"no lowest point on the cloth seen below the gripper ({exc})"}
        k = int(np.argmin(np.linalg.norm(estimate.vertices - plan.position, axis=1)))
        return plan, float(np.linalg.norm(estimate.canonical[k] - estimate.canonical[held_vertex])), k, {}
    # redetect: a fresh mesh on the hanging cloth, the planner's best corner away from the first gripper
    tracking.holds, tracking.hanging = [], None  # both belong to the old mesh
    status = link.control.request(InitialiseRequest(request_id=frame.seq, mask=cloth_seen(frame, reference),
                                                    background=reference))
    if not isinstance(status, StatusReply) or status.state != "initialising":
        raise RuntimeError(f"perception service did not accept the re-detection ({status})")
    scene.step_coming_to_rest()
    try:
        tracking()
    except TimeoutError:  # the service refused to build the mesh (it says why in its status)
        status = link.control.request(StatusRequest(request_id=frame.seq))
        refused = ", ".join(f"{n} {kind}" for kind, n in sorted(status.rejected_by_kind.items())) or "none"
        return None, None, -1, {"reason": f"no mesh laid afresh on the hanging cloth (frames rejected: {refused})"}
    fresh = tracking.estimates[tracking.last_seq]
    first_cam = transform_points(invert_transform(scene.T_world_cam), first_hand.gripper.position[None])[0]
    held_new = int(np.argmin(np.linalg.norm(fresh.vertices - first_cam, axis=1)))
    tracking.holds = [(held_new, first_hand)]
    reply, _ = link.plan("corner", tracking.last_seq, lambda: link.frames_pub.publish(tracking.frames["last"]))
    away = [c for c in reply.candidates if np.linalg.norm(c.position - first_cam) > 2 * TOLERANCE_M]
    if not away:
        return None, None, -1, {"reason": "the re-detected mesh has no corner away from the first gripper"}
    plan = away[0]
    return plan, float(np.linalg.norm(fresh.canonical[plan.vertex_id] - fresh.canonical[held_new])), \
        int(plan.vertex_id), {}


def _turn(scene, config, tracking: _Tracking, hand) -> bool:
    """Turn the cloth hanging from ``hand`` by ``config.unfold.look_turn_deg``, the wrist
    turning the gripper about its approach axis (``sim.laundry.unfold.rolled``), then hold
    still while it comes to rest, every frame tracked; False, nothing moved, when the arm
    cannot reach the turned pose."""
    motion = config.unfold
    quat = rolled(hand.gripper.quat_xyzw, motion.look_turn_deg)
    if _out_of_reach(scene, hand.shoulder_world, rigid_transform(Rotation.from_quat(quat).as_matrix(),
                                                                 hand.gripper.position), "the turn"):
        return False
    tracking.phase = "turn"
    move_grippers(scene, [(hand.gripper, hand.gripper.position, quat)], motion.look_turn_deg / motion.turn_speed_deg_s,
                  tracking)
    tracking.phase = "hang"
    for _ in range(max(1, round(motion.look_rest_s * scene.fps))):
        scene.step_coming_to_rest()
        tracking()
    return True


def _out_of_reach(scene, shoulder_world, T_world_gripper: np.ndarray, what: str) -> str | None:
    """The failure to record when the arm mounted at ``shoulder_world`` cannot bring its
    gripper to the pose ``T_world_gripper`` (4, 4), naming ``what`` was out of reach; None
    when it can, or when the arms are drawn (``LaundryScene(arm="drawn")``), which reach anywhere."""
    reach = scene.can_reach(shoulder_world, T_world_gripper)
    if reach is None or reach.reachable:
        return None
    at = ", ".join(f"{v:.2f}" for v in T_world_gripper[:3, 3])
    return f"unreachable: the arm cannot bring its gripper to {what} at ({at}) m in the world ({reach.describe()})"


def _lift_over(scene) -> float | None:
    """Where the lift ends, in world x: a Panda lifts the cloth to the middle between the two
    arms, where the other can reach it (``sim.panda``); a drawn arm straight up (None)."""
    return 0.0 if scene.arm == "panda" else None


def _grasp_out_of_reach(scene, config, shoulder_world, pose, fingertip: np.ndarray, what: str) -> str | None:
    """Why the arm at ``shoulder_world`` could not take a grasp of ``pose`` (``GraspPose``,
    world) closing at ``fingertip`` (3,): its approach, then the grasp itself; None when it can."""
    stand_off = fingertip - config.execution.pregrasp_distance_m * pose.approach
    return _out_of_reach(scene, shoulder_world, rigid_transform(pose.R, stand_off), f"{what}'s approach") \
        or _out_of_reach(scene, shoulder_world, rigid_transform(pose.R, fingertip), what)


def _first_arm(scene, config, plan: GraspPlan, estimate: MeshEstimate) -> tuple[np.ndarray, str | None]:
    """The shoulder of the arm that takes ``plan`` first, and why it cannot (None when it can:
    its approach, the grasp and the lift's top). The arm on the corner's side, or the other
    one when only that one reaches (a Panda cannot point its gripper back at its own base)."""
    execution, motion, top = config.execution, config.unfold, scene.spec.table_top_z
    pose = plan_to_world(plan, scene.T_world_cam)
    fingertip = fingertip_target(pose, float(scene.support_height(pose.position[None, :2])[0]), execution)
    lift = lift_target(fingertip, estimate.canonical, int(plan.vertex_id), top, motion, _lift_over(scene))
    near = arm_for(fingertip, top, motion, arm=scene.arm)
    first_why = None
    for shoulder in (near, arm_for(fingertip, top, motion, taken=near, arm=scene.arm)):
        why = _grasp_out_of_reach(scene, config, shoulder, pose, fingertip, "the first corner") \
            or _out_of_reach(scene, shoulder, rigid_transform(pose.R, lift), "the lift's top")
        if why is None:
            return shoulder, None
        first_why = first_why or why
    return near, first_why


def _from_a_side_reached(scene, config, plan: GraspPlan,
                         estimate: MeshEstimate) -> tuple[GraspPlan, np.ndarray, str | None]:
    """A lowest-point ``plan`` (a cloth held up, grasped from below) turned to come in from
    the side an arm reaches (``grasping.from_the_side``): no arm brings its hand up under a
    cloth hanging a few centimetres above the table. Returns that plan with ``_first_arm``'s
    answer for it: the first side's, saying why, when neither is reached."""
    tried = []
    for side in (1, -1):
        turned = from_the_side(plan, scene.T_world_cam, side)
        shoulder, why = _first_arm(scene, config, turned, estimate)
        if why is None:
            return turned, shoulder, None
        tried.append((turned, shoulder, why))
    return tried[0]


def _second_grasp_out_of_reach(scene, config, plan: GraspPlan, first_shoulder) -> str | None:
    """Why the second arm could not take ``plan`` (its approach, the grasp), or None."""
    pose = plan_to_world(plan, scene.T_world_cam)
    fingertip = second_fingertip(pose.position, pose.approach, config.unfold)
    shoulder = arm_for(fingertip, scene.spec.table_top_z, config.unfold, taken=first_shoulder, arm=scene.arm)
    return _grasp_out_of_reach(scene, config, shoulder, pose, fingertip, "the second corner")


def run_unfold(scene, link, config, record: dict, observe) -> None:
    """The unfold task (module docstring); fills ``record``.

    observe : (scene, link, config, reference) -> (frames, truth, estimates), the still
        frames that initialise the tracker (``trial._observe``)
    """
    reference = scene.render_empty()
    frames, truth, estimates = observe(scene, link, config, reference)
    last = max(frames)
    first_frame = frames[last]
    reply, planning_ms = link.plan("corner", last, lambda: link.frames_pub.publish(first_frame))
    planned_on = reply.estimate_seq if reply.estimate_seq in estimates else last
    view = View(first_frame, reference, mask_from_reference(first_frame, reference))
    if scene.arm != "drawn":  # the controller chooses among the corners the first arm can take
        why = [_first_arm(scene, config, c, estimates[planned_on])[1] for c in reply.candidates]
        if reply.candidates and all(why):
            record["failure"] = why[0]
            return
        reply = dataclasses.replace(reply, candidates=tuple(c for c, w in zip(reply.candidates, why) if not w))
    if scene.holder is None:  # on the table: the corner it hangs facing the camera from
        plan = corner_to_lift_first(reply.candidates, estimates[planned_on], scene.T_world_cam)
    else:
        plan = default_controller("corner")(reply, scene, view)
    record["timing"] = {"init_ms": round(estimates[min(estimates)].timing_ms, 1), "planning_ms": round(planning_ms, 1)}
    if plan is None:
        record["failure"] = f"no corner grasp found on estimate {planned_on}"
        return
    held_vertex = _held_vertex(plan, reply, estimates[planned_on])
    tracking = _Tracking(scene, link, {"last": first_frame}, truth, estimates, reference)
    tracking.keep("first plan")
    tracking.plans["first plan"] = plan
    try:
        _unfold(scene, link, config, record, tracking, plan, held_vertex, estimates[planned_on], reference)
    finally:
        if config.pictures_dir is not None and tracking.kept:
            record["picture"] = _pictures(scene, tracking, record, config)


def _unfold(scene, link, config, record: dict, tracking: _Tracking, plan: GraspPlan, held_vertex: int,
            planned_on: MeshEstimate, reference) -> None:
    """``run_unfold`` from the first grasp on; ``planned_on`` is the estimate the first grasp was planned on."""
    execution, motion = config.execution, config.unfold
    estimates = tracking.estimates

    # first grasp
    top = scene.spec.table_top_z
    if plan.vertex_id < 0:  # a lowest-point plan, not checked before
        plan, shoulder, why = _from_a_side_reached(scene, config, plan, planned_on)
        tracking.plans["first plan"] = plan
    else:
        shoulder, why = _first_arm(scene, config, plan, planned_on)
    if why:
        record["failure"] = why
        return
    pose = plan_to_world(plan, scene.T_world_cam)
    fingertip = fingertip_target(pose, float(scene.support_height(pose.position[None, :2])[0]), execution)
    hand1 = scene.add_robot_hand(fingertip - execution.pregrasp_distance_m * pose.approach, pose.quat_xyzw, shoulder)
    move_grippers(scene, [(hand1.gripper, fingertip, None)], execution.pregrasp_distance_m / execution.approach_speed_m_s,
                  tracking)
    first = close_fingers(scene, hand1.gripper, pose, fingertip, execution)
    hand1.opening_m = 0.0
    record["first_grasp"] = _grasp_record(first, scene)
    record["corner_success"] = bool(record["first_grasp"].get("at_corner"))
    if first.grasped_uv is None:
        record["failure"] = "missed: the first gripper holds no cloth"
        return
    scene.release_holder()
    tracking.holds = [(held_vertex, hand1)]
    tracking.hanging = HangingCue(planned_on.canonical, planned_on.faces, held_vertex, scene.T_world_cam,
                                  support_height_m=top)

    # lift, tracked
    tracking.phase = "lift"
    lift_from = tracking.last_seq + 1
    target = lift_target(fingertip, planned_on.canonical, held_vertex, top, motion, _lift_over(scene))
    move_grippers(scene, [(hand1.gripper, target, None)],
                  float(np.linalg.norm(target - hand1.gripper.position)) / motion.lift_speed_m_s, tracking)
    tracking.keep("lifted")
    lift_seqs = list(range(lift_from, tracking.last_seq + 1))
    tracking.phase = "hang"
    for _ in range(max(1, round(motion.hang_s * scene.fps))):
        scene.step_coming_to_rest()
        tracking()
    plan_seq = tracking.last_seq
    weight_n = float(np.linalg.norm(hand1.gripper.cloth_force_n()))  # the wrist sensor, the cloth hanging at rest
    hang = _hang_record(scene, tracking.frames["last"], reference, hand1, planned_on.canonical, held_vertex)

    # second corner: looked for again, the cloth turned, while the frame confirms none
    second_plan, distance, second_vertex, details = _second_plan(scene, link, config, tracking, reference,
                                                                 held_vertex, hand1, first.grasped_uv)
    declined, turns = [], 0  # each look that gave no corner to take: why, and what the camera saw; quarter turns made

    def decline() -> None:
        declined.append({**details, "second_plan_error_mm": _lift_errors(
            _frame_errors(tracking.estimates, tracking.truth, scene.faces, plan_seq), [plan_seq]),
            "true_adjacent_seen": _true_adjacent_seen(scene, tracking.frames["last"], first.grasped_uv)})
        log.info("look %d at the second corner: %s", len(declined), details["reason"])

    max_turns = motion.look_turns if config.regrasp == "adjacent" else 0
    while second_plan is None and "visible" in details:  # no plan, and a corner a turn may show
        decline()
        if turns == max_turns or not _turn(scene, config, tracking, hand1):
            break
        turns += 1
        plan_seq = tracking.last_seq
        second_plan, distance, second_vertex, details = _second_plan(scene, link, config, tracking, reference,
                                                                     held_vertex, hand1, first.grasped_uv)
    record["looks"] = {"count": turns + 1, "turned_deg": motion.look_turn_deg * turns, "declined": declined}
    tracking.keep("second plan")
    tracking.plans["second plan"] = second_plan
    record["tracking"] = _tracking_record(tracking, scene, lift_seqs, plan_seq)
    record["tracking"]["hang"] = hang
    record["tracking"]["true_adjacent_seen"] = _true_adjacent_seen(scene, tracking.frames["last"], first.grasped_uv)
    if second_plan is None:
        record["failure"] = details.get("reason", "no second grasp")
        if "visible" in details or "angle_deg" in details:  # a corner declined: what the robot knew of it
            record["second_grasp"] = {"declined": {k: v for k, v in details.items() if k != "reason"}}
        return
    record["second_grasp"] = {"plan_cam": [round(float(v), 4) for v in second_plan.position],
                              "vertex_id": int(second_plan.vertex_id), **details}
    why = _second_grasp_out_of_reach(scene, config, second_plan, hand1.shoulder_world)  # the baselines' plans
    if why:
        record["failure"] = why
        return
    pose2 = plan_to_world(second_plan, scene.T_world_cam)
    fingertip2 = second_fingertip(pose2.position, pose2.approach, motion)
    hand2 = scene.add_robot_hand(fingertip2 - execution.pregrasp_distance_m * pose2.approach, pose2.quat_xyzw,
                                 arm_for(fingertip2, top, motion, taken=hand1.shoulder_world, arm=scene.arm))
    tracking.phase = "second approach"
    move_grippers(scene, [(hand2.gripper, fingertip2, None)], execution.pregrasp_distance_m / execution.approach_speed_m_s,
                  tracking)
    second = close_fingers(scene, hand2.gripper, pose2, fingertip2, execution)
    hand2.opening_m = 0.0
    if second.grasped_uv is not None:
        tracking.holds.append((second_vertex, hand2))
    record["second_grasp"].update(_grasp_record(second, scene))

    # stretch: to the tracked mesh's distance, then on until the wrists feel the edge taut
    felt_taut = None
    if second.grasped_uv is not None:
        if distance is None or not math.isfinite(distance) or distance <= 0:
            distance = float(np.linalg.norm(hand1.gripper.position - hand2.gripper.position))
        t1, t2 = stretch_targets(hand1.gripper.position, hand2.gripper.position, motion.pull_from * distance,
                                 scene.T_world_cam)
        why = _out_of_reach(scene, hand1.shoulder_world, rigid_transform(hand1.T_world_gripper()[:3, :3], t1), "the stretch") \
            or _out_of_reach(scene, hand2.shoulder_world, rigid_transform(hand2.T_world_gripper()[:3, :3], t2), "the stretch")
        if why:
            record["failure"] = why
            return
        tracking.phase = "stretch"
        move_grippers(scene, [(hand1.gripper, t1, None), (hand2.gripper, t2, None)], motion.stretch_s, tracking)
        for _ in range(round(motion.pull_pause_s * scene.fps)):  # the swing of that motion is no pull on the edge
            scene.step_coming_to_rest()
            tracking()
        g1, g2 = hand1.gripper, hand2.gripper
        sensor = TautSensor(weight_n, motion)
        felt_taut = pull_apart(scene, g1, g2, motion.pull_speed_m_s, motion.max_stretch * distance,
                               lambda: sensor(g1.cloth_force_n(), g2.cloth_force_n(), g1.position, g2.position),
                               tracking)
        tracking.phase = "settle"
        for _ in range(max(1, round(motion.settle_s * scene.fps))):
            scene.step_coming_to_rest()
            tracking()
    tracking.keep("stretched")
    apart = float(np.linalg.norm(hand1.gripper.position - hand2.gripper.position))
    clearance = float(scene.clearance_above_support().min())
    verdict = judge_unfold(scene.spec.cloth_kind, first.grasped_uv, second.grasped_uv, apart,
                           clearance >= execution.clear_margin_m, scene.spec.corners_uv)
    names = scene.spec.corner_names
    record.update(success=verdict.success, failure=verdict.reason)
    record["unfold"] = {"first_corner": names[verdict.first_corner] if verdict.first_corner >= 0 else None,
                        "second_corner": names[verdict.second_corner] if verdict.second_corner >= 0 else None,
                        "first_error_m": _finite(verdict.first_error_m), "second_error_m": _finite(verdict.second_error_m),
                        "adjacent": verdict.adjacent, "stretch": round(verdict.stretch, 3),
                        "lowest_clearance_m": round(clearance, 4), "held_apart_m": round(apart, 4),
                        "felt_taut": felt_taut, "cloth_weight_n": round(weight_n, 3)}
    record["tracking"].update(_tracking_record(tracking, scene, lift_seqs, plan_seq, errors=False))
    timings = [estimates[s].timing_ms for s in tracking.phases]
    record["timing"]["tracking_ms"] = round(float(np.median(timings)), 1) if timings else None


def _finite(value: float) -> float | None:
    return None if not math.isfinite(value) else round(float(value), 4)


def _grasp_record(closing, scene) -> dict:
    """What a gripper closed on: the material point, the nearest true corner and the distance
    to it, and how far apart on the flat cloth the material in its jaw lies
    (``material_extent_m``: far more than the jaw's width when it closed on two layers)."""
    if closing.grasped_uv is None:
        return {"held": False}
    k, error = nearest_corner(closing.grasped_uv, scene.spec.corners_uv)
    return {"held": True, "uv": [round(float(v), 4) for v in closing.grasped_uv],
            "nearest_corner": scene.spec.corner_names[k], "corner_error_m": round(error, 4),
            "at_corner": error <= TOLERANCE_M,
            "material_extent_m": round(material_extent(scene.uv_m, closing.held_nodes), 4)}


def _hang_record(scene, frame, reference, hand, canonical: np.ndarray, held_vertex: int) -> dict:
    """How far below the gripper ``hand`` the cloth hangs at rest in ``frame``, as the robot
    measures it (its lowest point seen off the table, ``seen_cloth_points``), against how far
    the tracked mesh's material reaches from the held vertex (``canonical`` (N, 3)), and the
    gripper's height above the table: a cloth hanging farther than its mesh reaches has
    material the mesh lacks (a mesh laid on a folded cloth). Metres; ``below_gripper_m``
    None when no cloth was seen."""
    points = seen_cloth_points(frame, reference)
    grip_z = float(hand.gripper.position[2])
    below = None if len(points) == 0 else grip_z - float(scene.to_world(points)[:, 2].min())
    reach = float(material_reach(canonical, held_vertex)[0])
    return {"below_gripper_m": None if below is None else round(below, 4), "mesh_reach_m": round(reach, 4),
            "gripper_above_table_m": round(grip_z - float(scene.spec.table_top_z), 4)}


def _true_adjacent_corners(scene, first_uv) -> tuple[list[int], np.ndarray]:
    """The true corners sharing an edge with the one nearest the material point ``first_uv``
    (2,) (``sim.laundry.truth.CORNER_EDGES``): their indices and where they are now, (K, 3)
    metres in the camera frame."""
    held, _ = nearest_corner(np.asarray(first_uv), scene.spec.corners_uv)
    kind = scene.spec.cloth_kind
    others = [k for k in range(len(scene.spec.corner_names)) if k != held and share_an_edge(kind, held, k)]
    return others, scene.cloth_vertices_cam()[scene.corner_vertices()[others]]


def _true_adjacent_seen(scene, frame, first_uv) -> dict:
    """Ground truth at the second plan: for each true corner sharing an edge with the one the
    first gripper holds, whether the camera saw it in ``frame`` (``seen_by_camera``), by
    corner name. Says whether a corner the robot declined to grasp blind was hidden, or in
    sight while the estimate put it elsewhere."""
    others, corners_cam = _true_adjacent_corners(scene, first_uv)
    names = scene.spec.corner_names
    return {names[k]: bool(seen) for k, seen in zip(others, seen_by_camera(corners_cam, frame))}


def _judged(scene, corner, estimate: MeshEstimate, first_uv) -> dict:
    """Ground truth for the adjacent corner the robot took or declined (``AdjacentCorner``
    ``corner`` on ``estimate``): how far its planned grasp (``plan``) and the estimate's corner
    vertex (``estimate_corner``) lie from the nearest true corner sharing an edge with the one
    the first gripper holds (material point ``first_uv``), metres; a look where one of them
    lies within the judge's ``TOLERANCE_M`` had a right corner to grasp, taken or not."""
    _, corners_cam = _true_adjacent_corners(scene, first_uv)  # every true corner shares an edge with another
    at = {"plan": np.asarray(corner.plan.position, np.float64), "estimate_corner": estimate.vertices[corner.plan.vertex_id]}
    return {name: round(float(np.linalg.norm(corners_cam - p, axis=1).min()), 4) for name, p in at.items()}


def _tracking_record(tracking: _Tracking, scene, lift_seqs: list[int], plan_seq: int, errors: bool = True) -> dict:
    """Frames tracked (by phase, how many flagged lost, how many carried the hanging cloth's
    lowest point) and, with ``errors``, the tracking error during the lift and at the second
    plan, the confidence then, and how honest the confidence was over the lift and the hang
    (``_honesty``)."""
    estimates = tracking.estimates
    by_phase: dict[str, int] = {}
    for phase in tracking.phases.values():
        by_phase[phase] = by_phase.get(phase, 0) + 1
    counts = {"frames_tracked": len(tracking.phases), "frames_by_phase": by_phase,
              "frames_lost": sum(bool(estimates[s].lost) for s in tracking.phases),
              "frames_with_lowest_point": tracking.lowest_sent}
    if not errors:
        return counts
    frame_errors = _frame_errors(estimates, tracking.truth, scene.faces, plan_seq)
    return {"lift_error_mm": _lift_errors(frame_errors, lift_seqs),
            "second_plan_error_mm": _lift_errors(frame_errors, [plan_seq]),
            "confidence_at_second_plan": round(float(estimates[plan_seq].confidence), 3),
            "lost_at_second_plan": bool(estimates[plan_seq].lost),
            "honesty": _honesty(frame_errors, estimates, list(range(lift_seqs[0], plan_seq + 1)) if lift_seqs else []),
            **counts}


def _pictures(scene, tracking: _Tracking, record: dict, config) -> str:
    """A strip through the trial as far as it went: the first plan, the lifted cloth with its
    tracked mesh, the second plan, the stretched cloth, the verdict on the last panel."""
    K = scene.camera.K
    captions = {"first plan": "first corner (red), true corners (green)", "lifted": "lifted: tracked mesh",
                "second plan": f"second corner ({config.regrasp})", "stretched": "stretched"}
    panels = []
    for name, text in captions.items():
        if name not in tracking.kept:
            continue
        frame, estimate, truth = tracking.kept[name]
        plans = [tracking.plans[name]] if tracking.plans.get(name) is not None else []
        panels.append(caption(draw_plan(frame.rgb, K, plans, truth[scene.corner_vertices()], estimate), text))
    verdict = "SUCCESS" if record["success"] else f"FAILURE: {record['failure']}"
    panels[-1] = caption(panels[-1], verdict, row=1)
    path = Path(config.pictures_dir) / f"unfold_seed{record['seed']}_{config.regrasp}.png"
    save_png(path, strip(panels))
    return str(path)
