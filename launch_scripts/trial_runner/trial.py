"""One laundry-grasping trial, end to end through the real ZeroMQ services.

``run_trial(seed, config)`` is the one trial function, used by the pool, by Ray and by
the tests. This process owns the simulation and plays the robot's controller::

    this process: LaundryScene --RGBDFrame (PUB, free port)--> perception service process
    perception service --MeshEstimate--> planner service process (and this process)
    this process --InitialiseRequest (mask)--> perception;  --GraspRequest--> planner
    this process: execute a plan in the simulation, judge it by ground truth

Steps: build the scene from the seed (``sim.laundry``); start both services on free
loopback ports; find the cloth against a picture of the empty table
(``sim.laundry.mask_from_reference``: depth cannot see a cloth lying on a table) and ask
the perception service to initialise on it; publish ``observe_frames`` frames of the
scene as a frame source (``sim.frame_source.SceneSource``) one at a time, each after the
estimate of the previous one arrived (republished with back-off until it does, so a slow
joiner or a loaded machine only delays the trial); request a plan of the configured
kind; execute the plan the controller chooses (``sim.laundry.controller``: the planner's
best; when the robot holds the cloth up, the lowest point of the cloth it sees through a
full turn, taken from the side: ``grasping.from_the_side``) with ``sim.grasp_execution``;
judge it (``sim.laundry.judge``). This module only orchestrates: the task's logic is
``sim.laundry``'s. Children are stopped on every exit path and every wait is bounded.

The record (a JSON-ready dict) holds at least ``seed`` and ``success``; see ``run_trial``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from grasping import GraspPlannerConfig, from_the_side
from ipc.messages import (
    GraspPlan,
    GraspPlanReply,
    GraspRequest,
    InitialiseRequest,
    MeshEstimate,
    SetParametersRequest,
    StatusReply,
    StatusRequest,
)
from launch_scripts.processes import ChildError, Children
from perception.parameters import tracker_parameters
from perception.tracker import TrackerConfig
from sim.grasp_execution import ExecutionConfig, execute_grasp
from sim.ground_truth import error_summary, vertex_errors
from sim.laundry.controller import View, default_controller
from sim.laundry.judge import judge
from sim.laundry.pictures import caption, draw_plan, draw_point, save_png, strip
from sim.laundry.scene import RobotHand
from sim.laundry.segment import mask_from_reference
from sim.laundry.unfold import UnfoldConfig
from sim.robot_drawing import GripperLook

log = logging.getLogger(__name__)

FREE_PORT = "tcp://127.0.0.1:*"

#: The tracker of the perception service in trials, and why (measured on even seeds,
#: frames recorded once and tracked with each variant):
#: spacing_m 0.015: the corner vertex of the canonical hex mesh lies up to about a
#:   spacing inside the true corner; at the default 3 cm that alone is ~2.3 cm (median) of
#:   the 3 cm tolerance, and the chord window (4 spacings) cannot resolve a small shirt's
#:   10 cm sleeve end; at 1.5 cm the planned corner is ~1 cm (median) from the true one.
#: use_boundary off: depth segmentation cannot tell a cloth lying on a table from the table,
#:   so the tracked mask grows into the table and the boundary term drags the mesh
#:   outward (20-50 mm mean vertex error after four frames of a still cloth).
#: features "klt": on plain cloth SIFT finds keypoints in the sensor noise, whose wrong
#:   matches drag the mesh 8-20 mm in four frames; KLT's tracked points drift 1-3 mm, and
#:   on printed cloth both hold it within a millimetre. KLT now lays points only on texture
#:   above the image's noise (``min_texture_snr``), on a plain cloth next to none: the
#:   development seeds' corner trials were 50/50 again with it.
TRIAL_TRACKER = TrackerConfig(spacing_m=0.015, use_boundary=False, features="klt")
#: The tracker in unfold trials: the trials' tracker, never re-acquiring on its own. A
#: re-acquired plain cloth gets a new mesh laid over what is seen then, and with it new
#: material coordinates: the held corner's neighbours along the outline would be lost.
#: Its depth residual is measured along the surface's normal ("plane"): a cloth lifted by a
#: corner is seen edge-on, and along the camera's rays the depth term slid its material
#: points across it. Its outside term (``lambda_o``) pulls the mesh off the table the
#: cloth has left; the trial gives the tracker the empty table, so the segmented cloth can
#: be trusted there (``python benchmarks/lift_tracking.py`` measures both). On a printed
#: cloth, 200 points of its first frame's texture are found again in each frame
#: (``anchor_points``): KLT points bound anew while the mesh slid during the lift hold it there.
#: On a plain cloth it lays KLT points on whatever corners there are (``min_texture_snr`` 0):
#: they are noise over the shading of its folds, and while a cloth hangs from one hand the
#: folds go with the material well enough to hold the mesh: without them (the tracker's
#: default), on eight plain cloths of the even seeds, 78 mm mean error while hanging against
#: 56, and the other corners 109 mm from where the mesh puts them against 61 (medians;
#: ``python benchmarks/lift_tracking.py --seeds 4 6 10 16 24 26 34 38 --state '' --variants 9 10``).
#: Depth residuals beyond 1.5 cm count for nothing (``depth_outlier_m``, 8 cm by default): a
#: cloth hanging from one hand folds into layers a few centimetres apart, and the depth of the
#: layer in front, or of the table below, pulled the vertices it did not belong to. Set to the
#: truth as the cloth began to hang, the mesh drifted 13 -> 52 mm (mean) in 44 frames with the
#: default and stayed at 13-15 mm with this (a held-out seed, 1123).
UNFOLD_TRACKER = dataclasses.replace(TRIAL_TRACKER, reacquire_every=0, depth_residual="plane", lambda_o=0.3,
                                     anchor_points=200, min_texture_snr=0.0, depth_outlier_m=0.015)
#: The planner in trials: no inset, since the canonical corner vertex is already inside
#: the cloth by up to a grid spacing (the inset would add a centimetre of error). An
#: adjacent corner goes to the tip of the measured surface within 10 cm beyond the
#: tracked one (the unfold task's second grasp; the corner task asks for none). Each
#: trial adds its scene's camera pose and the robot's workspace (``planner_config``).
TRIAL_PLANNER = GraspPlannerConfig(pinch_inset_m=0.0, tip_search_radius_m=0.10)
#: The services a trial starts, as modules run with ``python -m``.
SERVICES = {"perception": "launch_scripts.perception_service", "planner": "launch_scripts.planner_service"}
#: The trial tasks: grasp one corner and lift (``corner``), or unfold by two adjacent
#: corners, tracking the cloth through the lift (``unfold``, ``trial_runner.unfold``).
TASKS = ("corner", "unfold")


@dataclass(frozen=True)
class TrialConfig:
    """Settings of a trial (seconds, metres).

    task : ``TASKS``: "corner" (default: one grasp of ``kind``, lifted and judged) or
        "unfold" (two adjacent corners, the edge between them stretched; ``kind`` must be
        "corner")
    regrasp : how an unfold trial chooses its second corner (``trial_runner.unfold.REGRASPS``):
        "adjacent" (default, the tracked mesh's outline), "lowest" or "redetect" (baselines)
    unfold : UnfoldConfig, the unfolding robot's motions
    kind : grasp kind requested (``GraspPlan.KINDS``): "corner" (default), "boundary" or "highest"
    observe_frames : frames shown to the perception service before planning: the first
        initialises the tracker, the others are tracked (1/30 s apart in the simulation)
    max_candidates : candidates asked of the planner (``run_trial``'s ``choose_plan`` picks one)
    tracker : TrackerConfig of the perception service, sent to it over its control socket
        (every field a SetParametersRequest carries; the others must keep the paper
        preset's values, which the service starts with); None for the task's own,
        ``TRIAL_TRACKER`` or ``UNFOLD_TRACKER``
    planner : GraspPlannerConfig of the planner service (its kind, camera pose and
        workspace are the trial's: ``planner_config``), given on its command line
    noise : sensor noise on the frames
    pictures_dir : write ``trial_seed<S>.png`` there, or None for no pictures
    log_dir : where the services' logs go (``seed<S>/``), or None for a temporary folder
    execution : ExecutionConfig of the simulated gripper
    frame_timeout_s : longest wait for the estimate of one frame (republishing it)
    plan_timeout_s : longest wait for a plan on the newest estimate
    request_timeout_s : per-attempt timeout of a control or planner request
    scene_options : passed to ``sim.laundry.laundry_spec`` (e.g. ``{"state": "flat"}``)
    arm : the unfold task's robot arms (``sim.laundry.scene.ARMS``): "drawn" (default) or
        "panda", a Franka Panda for each gripper, its reach checked before each motion
    """

    task: str = "corner"
    regrasp: str = "adjacent"
    unfold: UnfoldConfig = field(default_factory=UnfoldConfig)
    kind: str = "corner"
    observe_frames: int = 5
    max_candidates: int = 10
    tracker: TrackerConfig | None = None
    planner: GraspPlannerConfig = field(default_factory=lambda: TRIAL_PLANNER)
    noise: bool = True
    pictures_dir: str | None = None
    log_dir: str | None = None
    execution: ExecutionConfig = field(default_factory=ExecutionConfig)
    frame_timeout_s: float = 60.0
    plan_timeout_s: float = 60.0
    request_timeout_s: float = 10.0
    scene_options: dict = field(default_factory=dict)
    arm: str = "drawn"

    def __post_init__(self):
        from launch_scripts.trial_runner.unfold import REGRASPS
        from sim.laundry.scene import ARMS

        if self.task not in TASKS:
            raise ValueError(f"Expected task in {TASKS}, got {self.task!r}")
        if self.regrasp not in REGRASPS:
            raise ValueError(f"Expected regrasp in {REGRASPS}, got {self.regrasp!r}")
        if self.arm not in ARMS:
            raise ValueError(f"Expected arm in {ARMS}, got {self.arm!r}")
        if self.arm != "drawn" and self.task != "unfold":
            raise ValueError(f"Only the unfold task's robot has arms: expected arm 'drawn' for task {self.task!r}")
        if self.task == "unfold" and self.kind != "corner":
            raise ValueError(f"The unfold task grasps corners: expected kind 'corner', got {self.kind!r}")
        if self.tracker is None:
            object.__setattr__(self, "tracker", UNFOLD_TRACKER if self.task == "unfold" else TRIAL_TRACKER)
        if self.kind not in GraspPlan.KINDS:
            raise ValueError(f"Expected kind in {GraspPlan.KINDS}, got {self.kind!r}")
        if int(self.observe_frames) < 1:
            raise ValueError(f"Expected observe_frames >= 1, got {self.observe_frames}")
        if not 1 <= int(self.max_candidates) <= GraspRequest.MAX_CANDIDATES:
            raise ValueError(f"Expected max_candidates in [1, {GraspRequest.MAX_CANDIDATES}], got {self.max_candidates}")


def planner_config(config: TrialConfig, scene) -> GraspPlannerConfig:
    """``config.planner`` for the trial's scene: its grasp kind, the camera pose (world z up)
    and the reachable box of the trial's robot, over the table and up to 1.5 m above it."""
    hx, hy = scene.spec.table_half_xy
    top = scene.spec.table_top_z
    return dataclasses.replace(config.planner, kind=config.kind, T_world_cam=scene.T_world_cam,
                               up_world=np.array([0.0, 0.0, 1.0]),
                               workspace_min_world=np.array([-hx - 0.2, -hy - 0.2, top - 0.02]),
                               workspace_max_world=np.array([hx + 0.2, hy + 0.2, top + 1.5]))


def tracker_parameters_to_send(config: TrackerConfig, current: dict) -> dict:
    """The ``SetParametersRequest.parameters`` that turn a perception service started with the
    paper preset, whose ``StatusReply.parameters`` are ``current``, into ``config``.

    raises ValueError naming a field of ``config`` that a request cannot carry (a tuple or a
    nested setting) and that differs from the paper preset's
    """
    sent = tracker_parameters(config)
    started = TrackerConfig()
    for f in dataclasses.fields(TrackerConfig):
        if f.name not in sent and getattr(config, f.name) != getattr(started, f.name):
            raise ValueError(f"TrialConfig.tracker.{f.name}: a SetParametersRequest cannot carry it, and the "
                             "perception service keeps the paper preset's value")
    return {name: value for name, value in sent.items() if current.get(name) != value}


class _Link:
    """This process's sockets to the services, and the lockstep frame -> estimate exchange."""

    def __init__(self, stack: contextlib.ExitStack, children: Children, frames_pub, perception: dict, planner: dict,
                 config: TrialConfig):
        from ipc.transport import RequestClient, Subscriber

        self.children, self.frames_pub, self.config = children, frames_pub, config
        self.estimates = stack.enter_context(Subscriber(perception["estimates"], accept=(MeshEstimate,)))
        self.control = stack.enter_context(RequestClient(perception["control"], timeout_s=config.request_timeout_s,
                                                         attempts=2))
        self.planner = stack.enter_context(RequestClient(planner["planner"], timeout_s=config.request_timeout_s,
                                                         attempts=2))

    def configure_tracker(self, tracker: TrackerConfig) -> None:
        """Send the perception service the parameters that make its tracker ``tracker``, over
        its control socket, and check that they are in force."""
        status = self.control.request(StatusRequest(request_id=0))
        changes = tracker_parameters_to_send(tracker, status.parameters)
        if changes:
            status = self.control.request(SetParametersRequest(request_id=0, parameters=changes))
        wrong = {k: v for k, v in tracker_parameters(tracker).items() if status.parameters.get(k) != v}
        if wrong:
            raise RuntimeError(f"perception service runs other tracker parameters than the trial's: {wrong}")

    def estimate_of(self, frame) -> MeshEstimate:
        """Publish ``frame`` and wait for its estimate; bounded by ``frame_timeout_s``.

        The frame is published again (checks back off from 0.5 s, doubling to 4 s) only when
        the service's status shows it has not tracked it: a subscriber can lose a message,
        but a frame tracked twice moves the tracker on twice, so a frame that is merely slow
        (a loaded machine) is waited for, and a trial's outcome does not depend on the load.
        A service gone idle (it refused to build the mesh) raises TimeoutError at once, saying why.
        """
        deadline = time.monotonic() + self.config.frame_timeout_s
        self.frames_pub.publish(frame)
        wait = 0.5
        next_check = time.monotonic() + wait
        while time.monotonic() < deadline:
            estimate = self.estimates.recv_latest(timeout_s=0.05)
            if estimate is not None and estimate.seq == frame.seq:
                return estimate
            self.children.check()
            if time.monotonic() >= next_check:
                # answered between frames: after the frame being tracked, if any
                status = self.control.request(StatusRequest(request_id=frame.seq))
                if status.state == "idle":  # e.g. it refused to build the mesh: no estimate will come
                    raise TimeoutError(f"no estimate of frame {frame.seq}: the perception service is idle "
                                       f"({status.message or 'no mesh'})")
                if status.last_seq != frame.seq:
                    self.frames_pub.publish(frame)  # lost on the way, or its estimate was
                else:
                    log.debug("frame %d tracked, its estimate not received yet", frame.seq)
                next_check, wait = time.monotonic() + wait, min(2 * wait, 4.0)
        raise TimeoutError(f"no estimate of frame {frame.seq} within {self.config.frame_timeout_s:.0f} s")

    def plan(self, kind: str, last_seq: int, republish) -> tuple[GraspPlanReply, float]:
        """A plan of ``kind`` on the estimate of frame ``last_seq``; returns the reply and its round trip in ms."""
        request = GraspRequest(request_id=last_seq, max_candidates=self.config.max_candidates, kinds=(kind,))
        return self.ask(request, last_seq, republish)

    def ask(self, request, last_seq: int, republish) -> tuple[object, float]:
        """The planner's reply to ``request`` on the estimate of frame ``last_seq`` (or a newer
        one), and the round trip of the request it answered, in ms.

        ``not_ready`` or a reply on an older estimate (the planner's subscriber has not
        seen the newest yet) is asked again; after a second ``republish()`` shows the last
        frame again so that a new estimate of it is published.
        """
        from ipc.transport import RemoteError

        deadline = time.monotonic() + self.config.plan_timeout_s
        asked = time.monotonic()
        why = "no reply"
        while time.monotonic() < deadline:
            t0 = time.perf_counter()
            try:
                reply = self.planner.request(request)
            except RemoteError as e:
                if e.code != "not_ready":
                    raise
                why = str(e)
            else:
                if reply.estimate_seq >= last_seq:
                    return reply, 1000.0 * (time.perf_counter() - t0)
                why = f"planned on estimate {reply.estimate_seq}, not {last_seq}"
            if time.monotonic() - asked > 1.0:
                republish()
                asked = time.monotonic()
            self.children.check()
            time.sleep(0.1)
        raise TimeoutError(f"no plan on estimate {last_seq} within {self.config.plan_timeout_s:.0f} s ({why})")


def trial_spec(seed: int, config: TrialConfig):
    """The laundry scene (``sim.laundry.LaundrySpec``) a trial of ``config`` runs on ``seed``:
    the unfold task's cloth starts on the table, and its camera stands back to see the lifted
    cloth."""
    from sim.laundry import INITIAL_STATES, TABLE_STATES, laundry_spec

    unfold = config.task == "unfold"
    return laundry_spec(seed, view="room" if unfold else "table", states=TABLE_STATES if unfold else INITIAL_STATES,
                        **config.scene_options)


def scene_record(spec) -> dict:
    """What a trial's seed drew (``LaundrySpec``), for its record: cloth kind, size (m), printed,
    initial state."""
    w, h = spec.cloth.size_m
    return {"cloth": spec.cloth_kind, "size_m": [round(w, 3), round(h, 3)], "printed": spec.printed,
            "state": spec.state}


def _wide_view(scene):
    """A camera 2.5 m back from the table, to see the lifted cloth hanging above it."""
    from perception.geometry import look_at
    from sim.camera import VirtualCamera

    top = scene.spec.table_top_z
    eye = np.array([0.0, -2.3, top + 1.2])
    return VirtualCamera(scene.camera, look_at(eye, np.array([0.0, 0.0, top + 0.45])), lighting=scene.spec.lighting)


def run_trial(seed: int, config: TrialConfig | None = None,
              choose_plan: Callable[[GraspPlanReply, object, View], GraspPlan | None] | None = None) -> dict:
    """Run one trial (see the module docstring) and return its record.

    seed : int >= 0; the scene, its noise and so the whole trial follow from it, in a
        fresh process: run after another trial in the same process, the cloth's physics
        drifts apart within a lift (``launch_scripts.trials`` starts one per trial)
    config : TrialConfig, defaults when None
    choose_plan : (reply, scene, view) -> the GraspPlan to execute, or None for none;
        ``view`` is a ``View`` of the last frame; None for ``default_controller(config.kind)``

    The record (JSON-ready): ``seed``, ``kind``, ``success``, ``corner_success``,
    ``failure`` ("" on success, else one line; "error: ..." when the trial could not
    run), ``scene`` (cloth kind, size, printed, initial state), ``corner_error_m`` and
    ``nearest_corner`` (name), ``boundary_error_m``, ``grasped_uv`` [u, v] metres,
    ``plan`` (the executed plan in the camera frame; ``rank`` 0 for the planner's best,
    None for a plan not among the candidates, such as the lowest point of a held cloth;
    ``chosen_by`` the controller's name),
    ``n_candidates``,
    ``tracking_error_mm`` (mean and p95 of the estimate planned on, the metric of ``sim.ground_truth``),
    ``confidence``, ``lifted_clear``, ``lowest_clearance_m``, ``held_nodes``,
    ``timing`` (``init_ms`` and median ``tracking_ms`` from the tracker, ``planning_ms``
    the request's round trip, ``total_s``), ``picture`` (path or None).
    Never raises: a trial that cannot run (a service that does not start, a timeout, a
    scene option that does not exist) is a record whose ``failure`` starts with "error:", never a
    success (whatever the trial had judged before it failed).
    """
    # zmq and PyBullet are loaded when a trial runs, not when the runner imports this module.
    from ipc.transport import Publisher
    from launch_scripts.planner_service import arguments_from_config
    from launch_scripts.trial_runner.unfold import run_unfold
    from sim.laundry import LaundryScene

    config = config if config is not None else TrialConfig()
    choose_plan = choose_plan if choose_plan is not None else default_controller(config.kind)
    start = time.perf_counter()
    record = {"seed": int(seed), "task": config.task, "kind": config.kind, "success": False, "corner_success": False,
              "failure": ""}
    unfold = config.task == "unfold"
    if unfold:
        record["regrasp"] = config.regrasp
        record["arm"] = config.arm
    with contextlib.ExitStack() as stack:
        try:
            spec = trial_spec(seed, config)
            record["scene"] = scene_record(spec)
            scene = stack.enter_context(LaundryScene(spec, noise=config.noise, known_occluders=unfold, arm=config.arm))
            log_dir = Path(config.log_dir) / f"seed{seed}" if config.log_dir else Path(
                stack.enter_context(tempfile.TemporaryDirectory(prefix="clothkit_trial_")))
            children = stack.enter_context(Children(log_dir))
            frames_pub = stack.enter_context(Publisher(FREE_PORT, source=f"trial seed {seed}"))
            perception = children.start("perception", SERVICES["perception"], [
                "--frames", frames_pub.endpoint, "--estimates", FREE_PORT, "--control", FREE_PORT, "--print-endpoints",
                "--no-auto-init", "--log-level", "INFO"])
            planner = children.start("planner", SERVICES["planner"], [
                "--estimates", perception["estimates"], "--frames", frames_pub.endpoint, "--bind", FREE_PORT,
                "--print-endpoints", "--kinds", config.kind, *arguments_from_config(planner_config(config, scene))])
            link = _Link(stack, children, frames_pub, perception, planner, config)
            link.configure_tracker(config.tracker)
            if unfold:
                run_unfold(scene, link, config, record, _observe)
            else:
                _observe_plan_execute(scene, link, config, choose_plan, record)
        except (ChildError, TimeoutError, OSError, RuntimeError, ValueError) as e:
            log.warning("seed %d: %s: %s", seed, type(e).__name__, e)
            log.debug("seed %d:\n%s", seed, traceback.format_exc())  # a bug looks like a bad option: show where
            _failed(record, e)
        except Exception as e:  # noqa: BLE001 -- an unexpected failure of one trial must not stop a run of many
            log.error("seed %d failed:\n%s", seed, traceback.format_exc())
            _failed(record, e)
    record.setdefault("timing", {})["total_s"] = round(time.perf_counter() - start, 2)
    return record


def _failed(record: dict, error: Exception) -> None:
    """``record`` of a trial that raised ``error``: no success, whatever was judged before."""
    record.update(success=False, corner_success=False, failure=f"error: {type(error).__name__}: {' '.join(str(error).split())}")


def _observe(scene, link: _Link, config: TrialConfig, reference) -> tuple[dict, dict, dict]:
    """Show the perception service the scene's first ``config.observe_frames`` frames, as a
    frame source, one at a time: the first after asking the service to initialise on the
    cloth found in it against the empty table, each after the estimate of the one before
    arrived. Returns (frames, true cloth vertices in the camera frame, estimates), each
    by frame seq. The scene is left at the last frame shown."""
    from perception.sources import Pacing, publish_frames
    from sim.frame_source import SceneSource

    frames, truth, estimates = {}, {}, {}

    def show(frame) -> None:
        if not frames:
            mask = mask_from_reference(frame, reference)
            if not mask.any():
                raise RuntimeError("no cloth found against the empty table")
            # The unfold task lifts the cloth off the table: the tracker must know the empty table.
            background = reference if config.task == "unfold" else None
            status = link.control.request(InitialiseRequest(request_id=1, mask=mask, background=background))
            if not isinstance(status, StatusReply) or status.state != "initialising":
                raise RuntimeError(f"perception service did not accept the initialisation ({status})")
        frames[frame.seq] = frame
        truth[frame.seq] = scene.cloth_vertices_cam()
        estimates[frame.seq] = link.estimate_of(frame)

    # the source is not closed here: the scene it wraps goes on to the grasp
    publish_frames(SceneSource(scene), show, pacing=Pacing("fast"), max_frames=config.observe_frames)
    return frames, truth, estimates


def _one_mesh_run(estimates: dict, last: int) -> list[int]:
    """The frames up to ``last`` since the tracker built the mesh of ``last``'s estimate (a
    tracker that lost the cloth and found it again builds a new one): the frames whose
    vertices can be followed as material points to ``last``."""
    seqs = [s for s in sorted(estimates) if s <= last]
    canonical = estimates[last].canonical
    first = len(seqs) - 1
    while first > 0 and np.array_equal(estimates[seqs[first - 1]].canonical, canonical):
        first -= 1
    return seqs[first:]


def _observe_plan_execute(scene, link: _Link, config: TrialConfig, choose_plan, record: dict) -> None:
    """The body of a trial once the services run; fills ``record``."""
    reference = scene.render_empty()
    frames, truth, estimates = _observe(scene, link, config, reference)
    last = max(frames)

    def show_last_frame_again() -> None:
        link.frames_pub.publish(frames[last])

    reply, planning_ms = link.plan(config.kind, last, show_last_frame_again)
    # Re-tracks of the last frame (while waiting for the planner) may have been published.
    fresh = link.estimates.recv_latest(timeout_s=0.0)
    if fresh is not None and fresh.seq == last:
        estimates[last] = fresh
    seqs = sorted(estimates)
    tracked = [estimates[s].timing_ms for s in seqs[1:]]
    record["timing"] = {"init_ms": round(estimates[seqs[0]].timing_ms, 1),
                        "tracking_ms": round(float(np.median(tracked)), 1) if tracked else None,
                        "planning_ms": round(planning_ms, 1)}
    planned_on = reply.estimate_seq
    if planned_on in estimates:
        run = _one_mesh_run(estimates, planned_on)
        errors = vertex_errors(np.stack([estimates[s].vertices for s in run]), np.stack([truth[s] for s in run]),
                               scene.faces)[-1]
        summary = error_summary(errors)
        record["tracking_error_mm"] = {"mean": round(summary["mean_mm"], 2), "p95": round(summary["p95_mm"], 2)}
        record["confidence"] = round(estimates[planned_on].confidence, 3)
    record["n_candidates"] = len(reply.candidates)
    plan = choose_plan(reply, scene, View(frames[last], reference, mask_from_reference(frames[last], reference)))
    if plan is None:
        record["failure"] = f"no {config.kind} grasp found on estimate {planned_on}"
        return
    if plan.vertex_id < 0:  # the lowest point of a cloth held up: no hand comes up under it
        plan = from_the_side(plan, scene.T_world_cam)
    record["plan"] = {"kind": plan.kind, "position_cam": [round(float(v), 4) for v in plan.position],
                      "approach_cam": [round(float(v), 4) for v in plan.approach], "score": round(plan.score, 4),
                      "vertex_id": plan.vertex_id, "estimate_seq": planned_on,
                      "rank": next((i for i, c in enumerate(reply.candidates) if c is plan), None),
                      "chosen_by": getattr(choose_plan, "__name__", str(choose_plan))}
    panels = []
    if config.pictures_dir is not None:
        panels.append(_plan_panel(scene, frames[last], reply, plan, estimates.get(planned_on), truth[last]))
    wide = _wide_view(scene) if config.pictures_dir is not None else None

    def on_phase(phase: str) -> None:
        if config.pictures_dir is None:
            return
        # the grasp's gripper, drawn in the pictures only: the frames the tracker saw had none
        hand = RobotHand(scene.physics.grippers[-1], GripperLook(), None, 0.0)
        if phase == "closed":
            scene.hands.append(hand)
            try:
                closed = draw_point(scene.render().rgb, scene.camera.K, plan.position)
            finally:
                scene.hands.remove(hand)
            panels.append(caption(closed, "fingers closed (red ring: the plan's grasp point)"))
        else:
            lifted = wide.render(scene.physics, scene.spec.texture_rgb, solids=hand.drawn()).rgb
            panels.append(caption(lifted, "lifted and settled (wide view)"))

    result = execute_grasp(scene, plan, config.execution, on_phase=on_phase)
    verdict = judge(config.kind, result.grasped_uv, result.lifted_clear, scene.spec.corners_uv, scene.spec.outline_uv)
    record.update(
        success=verdict.success, corner_success=verdict.corner_success, failure=verdict.reason,
        corner_error_m=None if math.isinf(verdict.corner_error_m) else round(verdict.corner_error_m, 4),
        nearest_corner=None if verdict.nearest_corner < 0 else scene.spec.corner_names[verdict.nearest_corner],
        boundary_error_m=None if math.isinf(verdict.boundary_error_m) else round(verdict.boundary_error_m, 4),
        grasped_uv=None if result.grasped_uv is None else [round(float(v), 4) for v in result.grasped_uv],
        lifted_clear=result.lifted_clear, lowest_clearance_m=round(result.lowest_clearance_m, 4),
        held_nodes=int(result.held_nodes.size))
    if config.pictures_dir is not None:
        verdict_text = "SUCCESS" if verdict.success else f"FAILURE: {verdict.reason}"
        panels[-1] = caption(panels[-1], verdict_text, row=1)
        path = Path(config.pictures_dir) / f"trial_seed{record['seed']}.png"
        save_png(path, strip(panels))
        record["picture"] = str(path)


def _plan_panel(scene, frame, reply: GraspPlanReply, plan: GraspPlan, estimate, truth_cam) -> np.ndarray:
    others = [c for c in reply.candidates if c is not plan]
    corners_cam = truth_cam[scene.corner_vertices()]
    img = draw_plan(frame.rgb, scene.camera.K, [plan, *others], corners_cam, estimate)
    img = caption(img, f"{scene.spec.describe()}", row=1)
    return caption(img, f"{plan.kind} plan (red), other candidates (orange), true corners (green)")


def trial_config_dict(config: TrialConfig) -> dict:
    """The settings of a trial as a JSON-ready dict (for the report): arrays as lists, and
    numbers that are not finite (an unbounded workspace) as None."""

    def ready(value):
        if isinstance(value, dict):
            return {k: ready(v) for k, v in value.items()}
        if isinstance(value, np.ndarray):
            return ready(value.tolist())
        if isinstance(value, (list, tuple)):
            return [ready(v) for v in value]
        if isinstance(value, (float, np.floating)):
            return float(value) if math.isfinite(value) else None
        return value.item() if isinstance(value, np.generic) else value

    return ready(asdict(config))
