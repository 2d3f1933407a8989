"""A Franka Emika Panda arm that carries a simulated gripper: inverse kinematics, reachability, and its links drawn.

The arm is PyBullet's bundled model (``pybullet_data/franka_panda/panda.urdf``), loaded in a
PyBullet client of its own: it is kinematic, posed by setting its joints, and never touches
the cloth. The cloth is held, as without an arm, by the simulated gripper
(``sim.physics.Gripper``); the arm puts its own hand where that gripper is, so the camera
sees the links that would carry it, and says when it cannot.

``PandaArm.reach(T_world_gripper)`` solves the inverse kinematics for a gripper pose (the
fingertip centre and ``R_world_gripper``, the convention of ``sim.grasp_execution``: +z from
the wrist towards the fingertips, the fingers closing along x) and returns how close the
arm's grasp point came: a pose is reachable when it is within ``POSITION_TOLERANCE_M`` and
``ANGLE_TOLERANCE_RAD``. The Panda's fingers close along its hand's y axis, so its grasp
frame is the gripper frame turned a quarter turn about z.

``PandaArm.mesh(opening_m)`` is the arm as posed, standing on a column (from the floor or a
table top), its links drawn from the model's collision meshes (about 3,500 triangles) in the world frame.
"""

from __future__ import annotations

import functools
import itertools
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from perception.geometry import check_transform, check_vector, rigid_transform, transform_points
from sim.solids import SolidMesh, cylinder, merge

#: the link whose frame lies between the fingertips (the URDF's grasp target)
GRASP_LINK = "panda_grasptarget"
#: a gripper pose is reachable when the arm's grasp point comes this close to it ...
POSITION_TOLERANCE_M = 0.01
#: ... and its grasp frame turns no more than this from it
ANGLE_TOLERANCE_RAD = np.radians(5.0)
#: Franka's "ready" pose, elbow up: where the solver's null space pulls the joints
READY = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
#: a solve afresh starts from each of these (the first joint turned towards the target) until
#: one converges: ready, reaching out and low, folded in close and low
STARTS = (READY, (0.0, 0.4, 0.0, -1.6, 0.0, 2.2, 0.785), (0.0, -0.2, 0.0, -2.8, 0.0, 2.8, 0.785))
#: the shoulder (joint 2) above the base: ``PandaArm.at_shoulder`` mounts the base this far below it
SHOULDER_HEIGHT_M = 0.333
#: the Panda's colours: white links, a dark grey hand and fingers
LINK_RGB = (232, 232, 235)
HAND_RGB = (70, 70, 76)
#: the column the arm stands on, from the floor or the table up to its base
PEDESTAL_RADIUS_M = 0.09
PEDESTAL_RGB = (150, 150, 156)
#: our grasp frame from the Panda's: fingers closing along x instead of y
_R_PANDA_GRIPPER = Rotation.from_euler("z", -90.0, degrees=True).as_matrix()


@dataclass(frozen=True)
class Reach:
    """How close the arm came to a gripper pose.

    joints : (7,) float64 radians, the arm's joints as solved
    position_error_m : distance from the arm's grasp point to the pose's position
    angle_error_rad : angle between the arm's grasp frame and the pose's
    """

    joints: np.ndarray
    position_error_m: float
    angle_error_rad: float

    @property
    def reachable(self) -> bool:
        return self.position_error_m <= POSITION_TOLERANCE_M and self.angle_error_rad <= ANGLE_TOLERANCE_RAD

    def describe(self) -> str:
        return f"{100 * self.position_error_m:.1f} cm and {np.degrees(self.angle_error_rad):.0f} degrees off"


def _pybullet():
    # imported when an arm is made, as in ``sim.physics``: importing the scenes needs no PyBullet
    import pybullet

    return pybullet


def urdf_path() -> Path:
    """The Panda model bundled with PyBullet (``pybullet_data``)."""
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"


def _better(reach: Reach, than: Reach | None) -> bool:
    """Whether ``reach`` comes nearer its pose than ``than`` (a centimetre weighs as much as 6 degrees)."""
    return than is None or reach.position_error_m + 0.1 * reach.angle_error_rad \
        < than.position_error_m + 0.1 * than.angle_error_rad


def _origin(element) -> np.ndarray:
    """(4, 4) the transform of a URDF ``<origin>`` child of ``element`` (identity without one)."""
    origin = element.find("origin")
    if origin is None:
        return np.eye(4)
    return rigid_transform(Rotation.from_euler("xyz", [float(v) for v in origin.get("rpy", "0 0 0").split()]).as_matrix(),
                           [float(v) for v in origin.get("xyz", "0 0 0").split()])


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (F, 3) of a Wavefront OBJ file (polygons split as fans)."""
    points, faces = [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            points.append([float(v) for v in parts[1:4]])
        elif parts[0] == "f":
            ids = [int(p.split("/")[0]) - 1 for p in parts[1:]]
            faces += [[ids[0], ids[k], ids[k + 1]] for k in range(1, len(ids) - 1)]
    return np.asarray(points, np.float64), np.asarray(faces, np.int64)


@functools.lru_cache(maxsize=1)
def _link_meshes() -> dict[str, SolidMesh]:
    """Each link's collision mesh in its link frame, coloured, by link name."""
    meshes = {}
    urdf = urdf_path()
    for link in ElementTree.parse(urdf).getroot().iter("link"):
        collision = link.find("collision")
        if collision is None:
            continue
        mesh = collision.find("geometry/mesh")
        if mesh is None:
            continue
        points, faces = _read_obj(urdf.parent / mesh.get("filename").replace("package://", ""))
        name = link.get("name")
        colour = HAND_RGB if name in ("panda_hand", "panda_leftfinger", "panda_rightfinger") else LINK_RGB
        meshes[name] = SolidMesh(points, faces, np.tile(np.array(colour, np.uint8), (len(points), 1))) \
            .transformed(_origin(collision))
    return meshes


class PandaArm:
    """One Panda mounted at ``T_world_base`` (4, 4), on a column down to height
    ``stands_on_z`` (none when that is not below the base); see the module docstring.

    Holds a PyBullet client (DIRECT) of its own until ``close``.
    """

    def __init__(self, T_world_base: np.ndarray, stands_on_z: float = 0.0):
        self.T_world_base = check_transform("T_world_base", T_world_base)
        self.stands_on_z = float(stands_on_z)
        pybullet = self._p = _pybullet()
        self._client = pybullet.connect(pybullet.DIRECT)
        quat = Rotation.from_matrix(self.T_world_base[:3, :3]).as_quat()
        self._body = pybullet.loadURDF(str(urdf_path()), self.T_world_base[:3, 3].tolist(), quat.tolist(),
                                       useFixedBase=True, physicsClientId=self._client)
        self._links: dict[str, int] = {}
        self._arm_joints: list[int] = []
        self._finger_joints: list[int] = []
        lower, upper = [], []
        for j in range(pybullet.getNumJoints(self._body, physicsClientId=self._client)):
            info = pybullet.getJointInfo(self._body, j, physicsClientId=self._client)
            self._links[info[12].decode()] = j
            if info[2] == pybullet.JOINT_REVOLUTE:
                self._arm_joints.append(j)
                lower.append(info[8])
                upper.append(info[9])
            elif info[2] == pybullet.JOINT_PRISMATIC:
                self._finger_joints.append(j)
        self._lower, self._upper = np.array(lower), np.array(upper)
        self._grasp = self._links[GRASP_LINK]
        self.joints = np.array(READY)
        self._set(self.joints)

    @classmethod
    def at_shoulder(cls, shoulder_world, facing_world, stands_on_z: float = 0.0) -> PandaArm:
        """A Panda whose shoulder (joint 2) is at ``shoulder_world`` (3,), upright, its base
        turned to face ``facing_world`` (3,) (the middle of the table it works at), on a
        column standing at height ``stands_on_z`` (the floor, or a table top)."""
        shoulder = check_vector("shoulder_world", shoulder_world)
        towards = check_vector("facing_world", facing_world) - shoulder
        return cls(rigid_transform(Rotation.from_euler("z", float(np.arctan2(towards[1], towards[0]))).as_matrix(),
                                   shoulder - [0.0, 0.0, SHOULDER_HEIGHT_M]), stands_on_z)

    def close(self) -> None:
        """Disconnect the arm's PyBullet client (idempotent)."""
        if self._client is not None:
            self._p.disconnect(self._client)
            self._client = None

    def __enter__(self) -> PandaArm:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _set(self, joints: np.ndarray) -> None:
        for j, q in zip(self._arm_joints, joints):
            self._p.resetJointState(self._body, j, float(q), physicsClientId=self._client)

    def _link_pose(self, link: int) -> np.ndarray:
        state = self._p.getLinkState(self._body, link, computeForwardKinematics=True, physicsClientId=self._client)
        return rigid_transform(Rotation.from_quat(state[5]).as_matrix(), state[4])

    def grasp_pose(self) -> np.ndarray:
        """(4, 4) where the arm's grasp frame is now, in the gripper convention (module docstring)."""
        T = self._link_pose(self._grasp)
        T[:3, :3] = T[:3, :3] @ _R_PANDA_GRIPPER
        return T

    def _error(self, T_target: np.ndarray) -> tuple[float, float]:
        T = self.grasp_pose()
        position = float(np.linalg.norm(T[:3, 3] - T_target[:3, 3]))
        angle = float(Rotation.from_matrix(T[:3, :3].T @ T_target[:3, :3]).magnitude())
        return position, angle

    def _solve_from(self, T: np.ndarray, joints: np.ndarray) -> Reach:
        """PyBullet's damped least squares from ``joints`` towards the grasp pose ``T``."""
        target = Rotation.from_matrix(T[:3, :3] @ _R_PANDA_GRIPPER.T).as_quat()
        best = None
        # The solver takes one damped step per call from the arm's state: a few rounds from
        # the returned joints converge where one call stops short.
        for _ in range(6):
            self._set(joints)
            solution = self._p.calculateInverseKinematics(
                self._body, self._grasp, T[:3, 3].tolist(), target.tolist(),
                lowerLimits=self._lower.tolist(), upperLimits=self._upper.tolist(),
                jointRanges=(self._upper - self._lower).tolist(), restPoses=list(READY),
                maxNumIterations=100, residualThreshold=1e-5, physicsClientId=self._client)
            joints = np.clip(np.asarray(solution[:len(self._arm_joints)]), self._lower, self._upper)
            self._set(joints)
            reach = Reach(joints, *self._error(T))
            if _better(reach, best):
                best = reach
            if reach.position_error_m < 1e-3 and reach.angle_error_rad < 1e-2:
                break
        return best

    def solve(self, T_world_gripper: np.ndarray, start: np.ndarray | None = None) -> Reach:
        """The joints that bring the arm's grasp frame nearest the gripper pose
        ``T_world_gripper`` (4, 4), and how near that is; the arm is left there.

        From ``start`` (7,) if given, else from the ready pose turned towards the target (the
        solver is local). A parallel gripper holds the same grasp turned half a turn about
        its approach, so that pose is tried too, as the arm's wrist may reach only one."""
        T = check_transform("T_world_gripper", T_world_gripper)
        flipped = T.copy()
        flipped[:3, :2] *= -1.0
        if start is not None:
            starts = [np.asarray(start, np.float64)]
        else:
            towards = transform_points(np.linalg.inv(self.T_world_base), T[:3, 3][None])[0]
            turn = np.clip(np.arctan2(towards[1], towards[0]), self._lower[0], self._upper[0])
            starts = [np.array([turn, *pose[1:]]) for pose in STARTS]
        best = None
        for joints, pose in itertools.product(starts, (T, flipped)):
            reach = self._solve_from(pose, joints)
            if _better(reach, best):
                best = reach
            if best.position_error_m < 2e-3 and best.angle_error_rad < 2e-2:
                break
        self._set(best.joints)
        self.joints = best.joints
        return best

    def reach(self, T_world_gripper: np.ndarray) -> Reach:
        """``solve`` from the arm's present joints (a motion's next pose is near its last),
        else afresh when that comes nearer."""
        reach = self.solve(T_world_gripper, self.joints)
        if not reach.reachable:  # a far start can leave the solver on a poor branch
            fresh = self.solve(T_world_gripper)
            if _better(reach, fresh):
                self._set(reach.joints)
                self.joints = reach.joints
                return reach
            reach = fresh
        return reach

    def can_reach(self, T_world_gripper: np.ndarray) -> Reach:
        """``reach`` without moving the arm: whether it could bring its gripper to that pose."""
        joints = self.joints
        try:
            return self.reach(T_world_gripper)
        finally:
            self._set(joints)
            self.joints = joints

    def mesh(self, opening_m: float) -> SolidMesh:
        """The arm as posed, its fingers ``opening_m`` apart (0 to 0.08), in the world frame."""
        half = float(np.clip(opening_m, 0.0, 0.08)) / 2.0
        for j in self._finger_joints:
            self._p.resetJointState(self._body, j, half, physicsClientId=self._client)
        base = self.T_world_base[:3, 3]
        parts = [cylinder(base, [base[0], base[1], self.stands_on_z], PEDESTAL_RADIUS_M, PEDESTAL_RGB)] \
            if base[2] > self.stands_on_z else []
        for name, mesh in _link_meshes().items():
            T = self.T_world_base if name not in self._links else self._link_pose(self._links[name])
            parts.append(SolidMesh(transform_points(T, mesh.points), mesh.faces, mesh.colours))
        return merge(parts)
