"""The unfolding robot's motions: lift a cloth by one corner, take a second corner, stretch the edge.

The robot has two arms, mounted left and right of the table (``shoulders``), each ending
in a parallel gripper that the camera sees (``LaundryScene.add_robot_hand``). The task,
as ``launch_scripts.trial_runner`` runs it:

1. the first gripper grasps a corner of the cloth on the table and lifts it straight up
   at robot speed (``UnfoldConfig.lift_speed_m_s``) until the cloth hangs clear
   (``lift_target``: the robot reads the cloth's size from the tracked mesh);
2. it holds still while the cloth comes to rest (``UnfoldConfig.hang_s``);
3. the second gripper takes the corner the planner chose (``second_fingertip``); while the
   frame confirms none, the first gripper's wrist turns the hanging cloth a quarter turn at
   a time and the robot looks again (``UnfoldConfig.look_turns``, ``rolled``);
4. both move apart horizontally, sideways to the camera, until the points they hold are
   as far apart as along the cloth's tracked mesh (``stretch_targets``), then on, slowly,
   while the force sensors at their wrists feel the edge between them slack
   (``TautSensor``), and the cloth settles.

Everything here is geometry in the world frame (z up, metres); the scene and the services
stay with the caller.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from perception.geometry import check_points, check_positive, check_transform, check_vector
from perception.mesh import material_reach
from sim.laundry.spec import TABLE_HALF_XY_M

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class UnfoldConfig:
    """How the unfolding robot moves (metres, seconds).

    lift_speed_m_s : mean speed of the lift (the smooth profile of
        ``sim.grasp_execution.move_grippers`` peaks at 1.5 times it)
    hang_clearance_m : the lifted cloth's lowest point should hang this far above the table
    hang_s : the robot holds still this long, frames tracked, while the cloth comes to rest
    pinch_overtravel_m : the second gripper's fingertips go this far past the planned
        corner along the approach, so that the jaw closes over the cloth's edge. The cloth is
        held at the fingertips' centre, so every millimetre of it moves the held point inside
        the corner: 5 mm (15 before) brought the second grasps 1 cm nearer their corners with
        none closing on nothing (docs/results.md, "Unfolding")
    stretch_s : duration of the motion that brings both grippers level, ``pull_from`` times
        the planned material distance apart (``stretch_targets``)
    pull_speed_m_s : speed at which each gripper then moves outwards, frame by frame, while
        the edge is slack (slow enough that the springs' damping adds little to the pull)
    taut_pull, taut_stiffness_per_m, taut_frames : when the edge counts as taut
        (``TautSensor``): the cloth pulls the grippers together with at least ``taut_pull``
        times its weight, a pull growing by at least ``taut_stiffness_per_m`` times its weight
        per metre of separation over the last ``taut_frames`` frames. Measured in the sim,
        pulled at 0.1 m/s: a towel hung by its top corners (45 x 35 cm, mesh spacings 2-3
        cm) pulls with at most 0.7 times its weight while its edge sags, and is felt taut
        0.93-1.03 times the corners' distance apart (at 1.5 times its weight, 1.10-1.19:
        PyBullet's cloth is far softer than fabric). An edge carrying the rest of the cloth
        hanging from it sags like a chain and pulls hard long before it is straight: a towel
        held by a corner and a point of its side edge was felt taut at 0.85 of that edge's
        length, and at 0.82-0.95 with 1.5 times its weight. Hence the grippers first go as
        far apart as the tracked mesh says (``pull_from`` 1), and from there the pull alone
        decides (``taut_stiffness_per_m`` 0): on 50 held-out trials requiring 8 weights per
        metre as well left the edges stretched to 1.04-1.35 times their length
    pull_from : the grippers first move this fraction of the planned material distance
        apart (the tracked mesh's: too long when a grasp missed its corner, too short on a
        mesh laid on a folded cloth), wait ``pull_pause_s`` for the cloth to stop swinging,
        then move on while the edge is slack
    max_stretch : the grippers stop, taut or not, this many times the planned material
        distance apart (a mesh laid on a folded cloth underestimates an edge's length)
    settle_s : time after the stretch before the cloth is judged
    look_turns : how many more looks for the second corner while the frame confirms none
        (the corner the tracked mesh gives was seen too little, or the measured surface does
        not end where the mesh puts it): before each, the first gripper's wrist turns the
        hanging cloth a further ``look_turn_deg`` about the gripper's approach axis, at
        ``turn_speed_deg_s`` (mean), and holds still ``look_rest_s``, every frame tracked. A
        hanging cloth shows the camera one face, or an edge, and hides what lies behind its
        own layers; a corner out of sight at one look is in sight at another. 0: one look.
        Two, not more: each turn leaves the tracked mesh further off (its material slides as
        the cloth turns). On the latest unfold trial of each of 300 seeds run in the five
        sessions before, the second look (after one turn) grasped a right corner 21 times
        and a wrong one 15, the third 5 and 9, a fourth 1 and 12 (and declined 67)
    look_turn_deg, turn_speed_deg_s, look_rest_s : see ``look_turns``
    shoulder_height_m : the drawn arms' shoulders above the table top
    shoulder_out_m : the drawn arms' shoulders' distance beyond the table's left and right edges
    panda_shoulder_height_m, panda_shoulder_out_m : the same for Franka Pandas (``sim.panda``;
        out negative: over the table, the arm standing on it): where one reaches the table,
        the lifted cloth's height and the hanging cloth (``python benchmarks/panda_reach.py``:
        99 % of grasps on the near half of the table, 99 % of lifts' tops, 85 % of second
        grasps in the air, against 96, 20 and 66 % from the drawn arms' mounts)
    """

    lift_speed_m_s: float = 0.3
    hang_clearance_m: float = 0.15
    hang_s: float = 1.5
    pinch_overtravel_m: float = 0.005
    stretch_s: float = 1.0
    pull_speed_m_s: float = 0.1
    taut_pull: float = 0.5
    taut_stiffness_per_m: float = 0.0
    taut_frames: int = 3
    pull_from: float = 1.0
    pull_pause_s: float = 0.5
    max_stretch: float = 1.6
    settle_s: float = 1.0
    look_turns: int = 2
    look_turn_deg: float = 90.0
    turn_speed_deg_s: float = 30.0
    look_rest_s: float = 1.0
    shoulder_height_m: float = 0.45
    shoulder_out_m: float = 0.15
    panda_shoulder_height_m: float = 0.6
    panda_shoulder_out_m: float = -0.05

    def __post_init__(self):
        for name in ("lift_speed_m_s", "stretch_s", "pull_speed_m_s", "taut_pull", "pull_from", "max_stretch",
                     "turn_speed_deg_s"):
            check_positive(f"UnfoldConfig.{name}", getattr(self, name))
        if int(self.taut_frames) < 2:
            raise ValueError(f"UnfoldConfig.taut_frames: expected an integer >= 2, got {self.taut_frames!r}")
        if isinstance(self.look_turns, bool) or int(self.look_turns) != self.look_turns or self.look_turns < 0:
            raise ValueError(f"UnfoldConfig.look_turns: expected an integer >= 0, got {self.look_turns!r}")
        if not 0.0 < float(self.look_turn_deg) <= 120.0:  # a slerp between orientations takes the short way round
            raise ValueError(f"UnfoldConfig.look_turn_deg: expected a value in (0, 120], got {self.look_turn_deg!r}")
        for name in ("hang_clearance_m", "hang_s", "pinch_overtravel_m", "pull_pause_s", "taut_stiffness_per_m", "settle_s",
                     "look_rest_s", "shoulder_height_m", "shoulder_out_m", "panda_shoulder_height_m"):
            check_positive(f"UnfoldConfig.{name}", getattr(self, name), allow_zero=True)


def shoulders(table_top_m: float, config: UnfoldConfig, arm: str = "drawn") -> tuple[np.ndarray, np.ndarray]:
    """(left, right) (3,) float64 world metres: the two arms' shoulders, by the table's left
    (-x) and right (+x) edges, level with its middle; ``arm`` "drawn" or "panda"
    (``sim.laundry.scene.ARMS``) says whose mounts."""
    out, height = (config.panda_shoulder_out_m, config.panda_shoulder_height_m) if arm == "panda" \
        else (config.shoulder_out_m, config.shoulder_height_m)
    x = TABLE_HALF_XY_M[0] + out
    z = float(table_top_m) + height
    return np.array([-x, 0.0, z]), np.array([x, 0.0, z])


def arm_for(point_world: np.ndarray, table_top_m: float, config: UnfoldConfig, taken: np.ndarray | None = None,
            arm: str = "drawn") -> np.ndarray:
    """The shoulder of the arm that reaches ``point_world`` (3,): the one on its side of the
    table, or the other one when ``taken`` (the first arm's shoulder) is that one."""
    left, right = shoulders(table_top_m, config, arm)
    near, far = (left, right) if float(point_world[0]) < 0 else (right, left)
    if taken is not None and np.allclose(near, taken):
        return far
    return near


def lift_target(grasped_world: np.ndarray, canonical: np.ndarray, held_vertex: int, table_top_m: float,
                config: UnfoldConfig, over_x_m: float | None = None) -> np.ndarray:
    """(3,) float64 world metres: straight above the grasp, or above ``over_x_m`` (world x)
    level with it, high enough for the cloth to hang clear.

    The cloth hangs at most as far below the gripper as its farthest material point is from
    the held one; the robot reads that from the tracked mesh's canonical (rest) shape.
    grasped_world : (3,) where the first gripper closed
    canonical : (N, 3) float metres, the estimate's canonical mesh
    held_vertex : its vertex nearest the held point
    """
    p = check_vector("grasped_world", grasped_world)
    rest = check_points("canonical", canonical)
    reach = float(material_reach(rest, held_vertex)[0])
    return np.array([p[0] if over_x_m is None else float(over_x_m), p[1],
                     float(table_top_m) + reach + config.hang_clearance_m])


def rolled(quat_xyzw: np.ndarray, angle_deg: float) -> np.ndarray:
    """(4,) float64 unit quaternion (x, y, z, w): the gripper orientation ``quat_xyzw`` (4,)
    turned by ``angle_deg`` about its own approach (z) axis, as a robot's last wrist joint
    turns it: the wrist and the arm behind it stay where they are."""
    q = np.asarray(quat_xyzw, dtype=np.float64).reshape(4)
    if not np.all(np.isfinite(q)) or not abs(float(np.linalg.norm(q)) - 1.0) < 1e-6:
        raise ValueError(f"quat_xyzw: expected a unit quaternion (x, y, z, w), got {q.tolist()}")
    return (Rotation.from_quat(q) * Rotation.from_rotvec([0.0, 0.0, np.radians(float(angle_deg))])).as_quat()


def second_fingertip(position_world: np.ndarray, approach_world: np.ndarray, config: UnfoldConfig) -> np.ndarray:
    """(3,) float64 world metres: where the second gripper's fingertips close, a little past
    the planned corner along the approach (``UnfoldConfig.pinch_overtravel_m``)."""
    a = check_vector("approach_world", approach_world)
    return check_vector("position_world", position_world) + config.pinch_overtravel_m * a / np.linalg.norm(a)


def stretch_targets(first_world: np.ndarray, second_world: np.ndarray, material_distance_m: float,
                    T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the two grippers go to stretch the edge between the points they hold.

    Both end at the height of the higher one, ``material_distance_m`` apart along the
    horizontal direction across the camera's view (sideways in its image, so that the
    camera sees the stretched edge at its full length), about their midpoint, each
    keeping its side.
    first_world, second_world : (3,) float metres, the grippers now
    T_world_cam : (4, 4) float, camera optical frame to world
    returns (first target (3,), second target (3,)) float64 world metres
    """
    a, b = check_vector("first_world", first_world), check_vector("second_world", second_world)
    T = check_transform("T_world_cam", T_world_cam)
    across = T[:3, 0].copy()  # the camera's x axis: right in its image
    across[2] = 0.0
    norm = np.linalg.norm(across)
    across = across / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    if float(np.dot(b - a, across)) < 0:
        across = -across
    middle = 0.5 * (a + b)
    middle[2] = max(a[2], b[2])
    half = 0.5 * float(material_distance_m)
    return middle - half * across, middle + half * across


def inward_pull_n(first_force_n: np.ndarray, second_force_n: np.ndarray, first_world: np.ndarray,
                  second_world: np.ndarray) -> float:
    """How hard the cloth pulls two grippers towards each other, newtons: the mean of their wrist
    readings (3,) newtons, world frame, along the line between their positions (3,) world
    metres; 0 when they are at the same place."""
    axis = check_vector("second_world", second_world) - check_vector("first_world", first_world)
    apart = float(np.linalg.norm(axis))
    if apart < 1e-9:
        return 0.0
    axis = axis / apart
    return 0.5 * (float(np.dot(check_vector("first_force_n", first_force_n), axis))
                  - float(np.dot(check_vector("second_force_n", second_force_n), axis)))


class TautSensor:
    """Whether the edge between two grippers pulling apart is taut, from their wrist force
    sensors (``sim.physics.Gripper.cloth_force_n``), frame after frame.

    Taut: the cloth pulls the grippers towards each other (the mean of both readings along
    their separation) with at least ``taut_pull`` times its weight, and that pull grows with
    their separation at least ``taut_stiffness_per_m`` times the weight per metre, fitted over
    the last ``taut_frames`` readings. A cloth hanging between two grippers pulls them
    together with part of its weight however slack the edge is, more the farther apart they
    are, but slowly; only an edge pulled straight makes the pull grow steeply. The unfold
    trials ask the pull alone (``taut_stiffness_per_m`` 0: only that it does not fall), since
    their grippers start where the tracked mesh says the edge is straight.

    weight_n : the cloth's weight, as the first wrist read it while the cloth hung from it alone
    """

    def __init__(self, weight_n: float, config: UnfoldConfig):
        self.weight_n = check_positive("TautSensor.weight_n", weight_n)
        self.config = config
        self._readings: deque[tuple[float, float]] = deque(maxlen=config.taut_frames)

    def __call__(self, first_force_n: np.ndarray, second_force_n: np.ndarray, first_world: np.ndarray,
                 second_world: np.ndarray) -> bool:
        """Add one frame's readings (3,) newtons, world frame, with the grippers' positions (3,)
        world metres; True when the edge between them is taut (class docstring)."""
        apart = float(np.linalg.norm(check_vector("second_world", second_world) - check_vector("first_world", first_world)))
        if apart < 1e-9:
            return False
        inwards = inward_pull_n(first_force_n, second_force_n, first_world, second_world)
        self._readings.append((apart, inwards))
        if len(self._readings) < self._readings.maxlen:
            return False
        separations, pulls = np.array(self._readings).T
        if np.ptp(separations) < 1e-6:  # not moving apart: no stiffness to measure
            return False
        stiffness = float(np.polyfit(separations, pulls, 1)[0])
        cfg = self.config
        return inwards >= cfg.taut_pull * self.weight_n and stiffness >= cfg.taut_stiffness_per_m * self.weight_n
