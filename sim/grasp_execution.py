"""Executing a grasp plan in the simulation: approach, close, (hand over), lift, settle, judge.

The gripper is a two-finger abstraction built on ``sim.physics.Gripper`` (a kinematic
body without collision shape that anchors cloth nodes). Its frame follows the planner's
convention (``grasping``): z is the approach direction (palm to fingertips), x the
direction the fingers close along, y = z x x; the plan's ``position`` is where the
fingertips close. The jaw is the box between the open fingers, in the gripper frame::

    |x| <= opening_width_m / 2,   |y| <= finger_width_m / 2,
    -finger_length_m <= z <= fingertip_margin_m      (z = 0 at the fingertips)

and closing anchors the nodes of every cloth triangle whose surface passes through it
(``jaw_faces``).

Motion (``execute_grasp``): the gripper appears at the pre-grasp pose
``position - pregrasp_distance_m * approach``, moves along the approach to the grasp
pose, closes, and lifts straight up (world +z) by ``lift_height_m``; then the cloth
settles for ``settle_s``. An approach pointing down (within 60 degrees of -z) is a
guarded move, as a robot does on a table: the fingertips go on past the plan's position
until they touch the support surface, at most ``overtravel_m`` further, or stop short
at the surface if the position is below it. Any other approach stops at the position.

Outcome (``ExecutionResult``): the held nodes, the grasped material point (the point
of the held triangles nearest the fingertip centre at closing; ``uv`` in the cloth's
material coordinates, metres) and whether
the cloth is lifted clear: every node at least ``clear_margin_m`` above the surface
under it (table or floor) after settling.

For tasks that watch the motion (the unfold trials), ``move_grippers`` moves grippers one
camera frame at a time, calling back after each frame, and ``close_fingers`` closes one.

Frames: plans arrive in the camera frame; ``plan_to_world`` maps them with the scene's
``T_world_cam`` (4, 4), camera optical frame to world (z up).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ipc.messages import GraspPlan
from perception.geometry import check_transform
from sim.ground_truth import closest_point_barycentric
from sim.physics import slerp

log = logging.getLogger(__name__)

#: An approach within this angle of straight down is a guarded move onto the support.
_DOWNWARD_COS = math.cos(math.radians(60.0))


@dataclass(frozen=True)
class ExecutionConfig:
    """How the simulated gripper moves and what its jaw holds. Metres, seconds.

    pregrasp_distance_m : stand-off before the grasp, along the approach
    approach_speed_m_s : speed from the pre-grasp to the grasp pose
    finger_length_m : depth of the jaw along the approach, from the fingertips back
    finger_width_m : width of the finger pads (gripper y)
    fingertip_margin_m : the jaw reaches this far past the fingertips (pad thickness)
    overtravel_m : longest guarded move past the plan's position for a downward approach
    support_clearance_m : the fingertips stop this far above the support surface
    lift_height_m : straight up, after closing; must exceed the longest cloth's hanging
        length for a lifted cloth to hang clear of the table
    lift_speed_m_s : lifting speed
    settle_s : simulated time after the lift before the cloth is judged
    clear_margin_m : a node at least this high above the surface under it is clear
    samples_per_edge : surface samples per triangle edge when finding the cloth in the jaw
    """

    pregrasp_distance_m: float = 0.10
    approach_speed_m_s: float = 0.4
    finger_length_m: float = 0.03
    finger_width_m: float = 0.02
    fingertip_margin_m: float = 0.005
    overtravel_m: float = 0.02
    support_clearance_m: float = 0.002
    lift_height_m: float = 1.0
    lift_speed_m_s: float = 1.0
    settle_s: float = 1.0
    clear_margin_m: float = 0.02
    samples_per_edge: int = 8

    def __post_init__(self):
        for name in ("pregrasp_distance_m", "approach_speed_m_s", "finger_length_m", "finger_width_m",
                     "lift_speed_m_s"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ExecutionConfig.{name}: expected a positive number, got {value}")
        for name in ("fingertip_margin_m", "overtravel_m", "support_clearance_m", "lift_height_m", "settle_s",
                     "clear_margin_m"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"ExecutionConfig.{name}: expected a non-negative number, got {value}")
        if isinstance(self.samples_per_edge, bool) or int(self.samples_per_edge) != self.samples_per_edge \
                or self.samples_per_edge < 1:
            raise ValueError(f"ExecutionConfig.samples_per_edge: expected a positive integer, got {self.samples_per_edge}")


@dataclass(frozen=True)
class GraspPose:
    """A grasp in the world frame.

    position : (3,) float64 metres, where the fingertips close (the plan's position)
    R : (3, 3) float64, ``R_world_gripper``: columns are the gripper's x (closing),
        y and z (approach) axes in the world
    opening_width_m : finger opening before closing, metres
    """

    position: np.ndarray
    R: np.ndarray
    opening_width_m: float

    @property
    def approach(self) -> np.ndarray:
        """(3,) unit vector, world: the direction the gripper moves to reach the cloth."""
        return self.R[:, 2]

    @property
    def quat_xyzw(self) -> np.ndarray:
        """(4,) float64 unit quaternion (x, y, z, w) of ``R``."""
        return Rotation.from_matrix(self.R).as_quat()


def plan_to_world(plan: GraspPlan, T_world_cam: np.ndarray) -> GraspPose:
    """Map a camera-frame GraspPlan to the world frame.

    plan : GraspPlan, position (3,) metres and quat_xyzw = R_cam_gripper, camera frame
    T_world_cam : (4, 4) float, camera optical frame to world
    returns GraspPose with position = T_world_cam @ [position, 1] and
    R_world_gripper = R_world_cam @ R_cam_gripper
    """
    T = check_transform("T_world_cam", T_world_cam)
    R_cam_gripper = Rotation.from_quat(plan.quat_xyzw).as_matrix()
    return GraspPose(position=T[:3, :3] @ plan.position + T[:3, 3], R=T[:3, :3] @ R_cam_gripper,
                     opening_width_m=float(plan.opening_width_m))


def fingertip_target(pose: GraspPose, support_height_m: float, config: ExecutionConfig) -> np.ndarray:
    """(3,) world position the fingertips move to (see the module docstring: guarded move).

    support_height_m : height (world z) of the support surface under the grasp position
    """
    a = pose.approach
    if a[2] > -_DOWNWARD_COS:
        return pose.position.copy()
    stop_z = support_height_m + config.support_clearance_m
    # Distance along the approach from the position to the surface (negative: below it).
    to_surface = (pose.position[2] - stop_z) / -a[2]
    return pose.position + min(config.overtravel_m, to_surface) * a


def _barycentric_grid(n: int) -> np.ndarray:
    """(S, 3) float64 barycentric sample points of a triangle, n intervals per edge."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    return np.column_stack([i, j, n - i - j]).astype(np.float64) / n


def jaw_faces(points_world: np.ndarray, faces: np.ndarray, fingertip_world: np.ndarray, pose: GraspPose,
              config: ExecutionConfig) -> np.ndarray:
    """Cloth triangles whose surface passes between the open fingers.

    The jaw (the box of the module docstring) is smaller than the simulated cloth's
    grid, so testing the nodes alone would miss cloth lying between the fingers: each
    triangle is sampled ``config.samples_per_edge`` times along each edge, and a triangle
    with a sample inside the jaw is in it. Closing holds all their nodes (what the
    fingers pinch moves with them).

    points_world : (V, 3) float metres, cloth nodes now; faces : (F, 3) int
    fingertip_world : (3,) float metres, the fingertip centre
    returns (K,) int64 face ids, K may be 0
    """
    p = np.asarray(points_world, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    weights = _barycentric_grid(config.samples_per_edge)
    samples = np.einsum("sk,fkd->fsd", weights, p[f])  # (F, S, 3)
    local = (samples - fingertip_world) @ pose.R  # gripper-frame coordinates
    inside = ((np.abs(local[..., 0]) <= 0.5 * pose.opening_width_m) & (np.abs(local[..., 1]) <= 0.5 * config.finger_width_m)
              & (local[..., 2] >= -config.finger_length_m) & (local[..., 2] <= config.fingertip_margin_m))
    return np.flatnonzero(inside.any(axis=1)).astype(np.int64)


def grasped_material_point(points_world: np.ndarray, faces: np.ndarray, uv_m: np.ndarray,
                           fingertip_world: np.ndarray) -> tuple[np.ndarray, float]:
    """The held material point: the point of the held triangles nearest the fingertip centre.

    points_world : (V, 3) float metres, cloth nodes at closing
    faces : (K, 3) int, the held triangles (``jaw_faces``), K >= 1
    uv_m : (V, 2) float metres, material coordinates of the nodes
    fingertip_world : (3,) float metres
    returns (uv (2,) float64 metres, distance from the fingertip centre in metres)
    """
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0:
        raise ValueError("grasped_material_point: expected at least one held triangle, got none")
    p = np.asarray(points_world, dtype=np.float64)
    w = closest_point_barycentric(fingertip_world[None], p[f[:, 0]], p[f[:, 1]], p[f[:, 2]])  # (K, 3)
    closest = np.einsum("fk,fkd->fd", w, p[f])
    d = np.linalg.norm(closest - fingertip_world, axis=1)
    k = int(np.argmin(d))
    return np.einsum("k,kd->d", w[k], np.asarray(uv_m, dtype=np.float64)[f[k]]), float(d[k])


@dataclass(frozen=True)
class ExecutionResult:
    """What happened when a plan was executed.

    pose : GraspPose in the world
    fingertip_world : (3,) float64 metres, where the fingertips closed
    held_nodes : (K,) int64 cloth nodes anchored to the gripper (empty: missed)
    grasped_uv : (2,) float64 metres, material point held (see ``grasped_material_point``),
        None when nothing was held
    grasp_offset_m : distance from the fingertip centre to that point, metres
    lifted_clear : every node at least ``clear_margin_m`` above the surface under it
    lowest_clearance_m : the smallest height of a node above the surface under it, after settling
    failure : "" on a clean lift, else one line ("missed: ...", "not lifted clear: ...")
    """

    pose: GraspPose
    fingertip_world: np.ndarray
    held_nodes: np.ndarray
    grasped_uv: np.ndarray | None
    grasp_offset_m: float
    lifted_clear: bool
    lowest_clearance_m: float
    failure: str = ""


def move_grippers(scene, moves, duration_s: float, on_frame: Callable[[], None] | None = None) -> None:
    """Move grippers to their targets together, one camera frame at a time.

    scene : a scene with ``fps`` and ``step()`` (one frame period of physics)
    moves : [(gripper (``sim.physics.Gripper``), target position (3,) metres world,
        target quat_xyzw (4,) or None to keep the orientation)]
    duration_s : seconds the motion takes (rounded up to whole frames, at least one)
    on_frame : called after each frame's step, e.g. to render, publish and track it

    Each gripper moves along a straight line with a smooth start and stop (smoothstep:
    zero speed at both ends, a top speed of 1.5 times the mean, as a robot's controller
    ramps its speed), which a cloth hanging from it follows without being flung.
    """
    n = max(1, math.ceil(float(duration_s) * scene.fps - 1e-9))
    starts = [(g.position, g.quat_xyzw) for g, _, _ in moves]
    targets = [(np.asarray(p, dtype=np.float64), q0 if q is None else np.asarray(q, dtype=np.float64))
               for (_, p, q), (_, q0) in zip(moves, starts)]
    for k in range(1, n + 1):
        t = k / n
        s = t * t * (3.0 - 2.0 * t)
        for (gripper, _, _), (p0, q0), (p1, q1) in zip(moves, starts, targets):
            gripper.move_to(p0 + s * (p1 - p0), slerp(q0, q1, s))
        scene.step()
        if on_frame is not None:
            on_frame()


def pull_apart(scene, first, second, speed_m_s: float, max_apart_m: float, stop: Callable[[], bool],
               on_frame: Callable[[], None] | None = None) -> bool:
    """Move two grippers apart, one camera frame at a time, until ``stop()`` is True.

    scene : a scene with ``fps`` and ``step()``; first, second : ``sim.physics.Gripper``
    speed_m_s : each gripper moves outwards this fast, along the horizontal line through both
    max_apart_m : they stop there, horizontally apart, whatever ``stop`` says
    stop : asked before each frame's move, e.g. whether the force sensors feel the cloth taut
    on_frame : called after each frame's step
    returns True when ``stop`` ended the pull, False when the grippers reached ``max_apart_m``
    """
    axis = np.asarray(second.position, dtype=np.float64) - np.asarray(first.position, dtype=np.float64)
    axis[2] = 0.0
    norm = float(np.linalg.norm(axis))
    axis = axis / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    step = float(speed_m_s) / scene.fps
    while not stop():
        apart = float(np.dot(second.position - first.position, axis))
        if apart >= max_apart_m - 1e-9:
            return False
        grow = min(step, 0.5 * (max_apart_m - apart))
        first.move_to(first.position - grow * axis)
        second.move_to(second.position + grow * axis)
        scene.step()
        if on_frame is not None:
            on_frame()
    return True


@dataclass(frozen=True)
class Closing:
    """What a gripper's fingers closed on.

    held_nodes : (K,) int64 cloth nodes now anchored to the gripper (empty: missed)
    grasped_uv : (2,) float64 metres, material point held (``grasped_material_point``), None when missed
    grasp_offset_m : distance from the fingertip centre to that point, metres (inf when missed)
    """

    held_nodes: np.ndarray
    grasped_uv: np.ndarray | None
    grasp_offset_m: float


def close_fingers(scene, gripper, pose: GraspPose, fingertip: np.ndarray, config: ExecutionConfig) -> Closing:
    """Close ``gripper`` at ``fingertip`` (3,) world metres: anchor the cloth in its jaw (``jaw_faces``)."""
    points = scene.physics.cloth_vertices()
    faces = np.asarray(scene.faces, dtype=np.int64)
    held_faces = faces[jaw_faces(points, faces, fingertip, pose, config)]
    held = np.unique(held_faces)
    if held.size == 0:
        log.info("missed: no cloth node between the fingers at %s", np.round(fingertip, 3).tolist())
        return Closing(held, None, math.inf)
    uv, offset = grasped_material_point(points, held_faces, scene.uv_m, fingertip)
    gripper.close_on(held)
    return Closing(held, uv, offset)


def execute_grasp(scene, plan: GraspPlan, config: ExecutionConfig | None = None,
                  on_phase: Callable[[str], None] | None = None) -> ExecutionResult:
    """Execute ``plan`` in a running scene and report what the gripper holds.

    scene : a scene with ``physics`` (``sim.physics.ClothPhysics``), ``T_world_cam``
        (4, 4), ``faces`` (F, 3), ``uv_m`` (V, 2), ``support_height(xy (N, 2)) -> (N,)``,
        ``clearance_above_support() -> (V,)`` and ``release_holder()``, e.g.
        ``sim.laundry.LaundryScene``
    plan : GraspPlan in the camera frame of the scene
    config : ExecutionConfig, defaults when None
    on_phase : called with "closed" once the fingers have closed (before any holder lets
        go) and "lifted" after settling, e.g. to render pictures

    The scene's holder (a cloth held up by one corner) lets go once the gripper holds
    something: a hand-over, so that what is lifted hangs from the gripper alone.
    """
    config = config if config is not None else ExecutionConfig()
    physics = scene.physics
    pose = plan_to_world(plan, scene.T_world_cam)
    support = float(scene.support_height(pose.position[None, :2])[0])
    fingertip = fingertip_target(pose, support, config)
    quat = pose.quat_xyzw
    gripper = physics.add_gripper(fingertip - config.pregrasp_distance_m * pose.approach, quat)
    gripper.move_to(fingertip, quat)
    travel = float(np.linalg.norm(fingertip - gripper.position))
    physics.advance(travel / config.approach_speed_m_s)

    closing = close_fingers(scene, gripper, pose, fingertip, config)
    held, uv, offset = closing.held_nodes, closing.grasped_uv, closing.grasp_offset_m
    if held.size == 0:
        if on_phase is not None:
            on_phase("closed")
        return ExecutionResult(pose=pose, fingertip_world=fingertip, held_nodes=held, grasped_uv=None,
                               grasp_offset_m=math.inf, lifted_clear=False,
                               lowest_clearance_m=float(scene.clearance_above_support().min()),
                               failure="missed: no cloth between the fingers")
    if on_phase is not None:
        on_phase("closed")
    scene.release_holder()
    gripper.move_to(fingertip + np.array([0.0, 0.0, config.lift_height_m]), quat)
    physics.advance(config.lift_height_m / config.lift_speed_m_s)
    physics.advance(config.settle_s)
    clearance = scene.clearance_above_support()
    lowest = float(clearance.min())
    clear = lowest >= config.clear_margin_m
    if on_phase is not None:
        on_phase("lifted")
    failure = "" if clear else f"not lifted clear: lowest node {100 * lowest:.1f} cm above the support"
    log.info("held %d nodes at uv %s; lowest node %.3f m above the support", held.size, np.round(uv, 3).tolist(), lowest)
    return ExecutionResult(pose=pose, fingertip_world=fingertip, held_nodes=held, grasped_uv=uv,
                           grasp_offset_m=offset, lifted_clear=clear, lowest_clearance_m=lowest, failure=failure)
