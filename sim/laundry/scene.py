"""A laundry scene running in PyBullet: the settled cloth on its table, a noisy RGB-D camera, ground truth."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ipc.messages import RGBDFrame
from perception.geometry import boundary_vertices, rotation_about_axis, transform_points
from sim.camera import SOLID_ID, VirtualCamera
from sim.laundry.spec import HOLDER_HALF_EXTENTS_M, HOLDER_RADIUS_M, TABLE_HALF_XY_M, LaundrySpec, laundry_spec
from sim.noise import DepthNoiseModel
from sim.panda import PandaArm, Reach
from sim.physics import ClothPhysics, Gripper
from sim.robot_drawing import GripperLook
from sim.scene import PhysicsScene
from sim.solids import SolidMesh, merge

log = logging.getLogger(__name__)

#: how the robot's arms look (``LaundryScene(arm=...)``)
ARMS = ("drawn", "panda")


@dataclass
class RobotHand:
    """One of the robot's grippers as the simulation moves it and the camera sees it.

    gripper : the kinematic ``sim.physics.Gripper`` (its pose is the fingertip centre and
        ``R_world_gripper``, the convention of ``sim.grasp_execution``)
    look : GripperLook, how its fingers, wrist and arm are drawn
    shoulder_world : (3,) float64 metres, where its arm is mounted, or None for a forearm
        straight back from the wrist
    opening_m : distance between the fingers' inner faces as drawn (0 once closed)
    arm : the Franka Panda that carries it (``sim.panda``), or None for the drawn arm
    """

    gripper: Gripper
    look: GripperLook
    shoulder_world: np.ndarray | None
    opening_m: float
    arm: PandaArm | None = None

    def drawn(self) -> SolidMesh:
        """The gripper with its wrist and arm as the camera sees them now (world frame): a
        Panda posed by its inverse kinematics to where the gripper is, or the drawn arm."""
        T = self.T_world_gripper()
        if self.arm is None:
            return self.look.mesh(T, self.opening_m, self.shoulder_world)
        self.arm.reach(T)
        return self.arm.mesh(self.opening_m)

    def T_world_gripper(self) -> np.ndarray:
        """(4, 4) float64, the gripper frame to world, now."""
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(self.gripper.quat_xyzw).as_matrix()
        T[:3, 3] = self.gripper.position
        return T


class LaundryScene(PhysicsScene):
    """A laundry scene running in PyBullet: settled cloth, table, camera with noise.

    spec : LaundrySpec (``laundry_spec(seed)``)
    noise : add sensor noise to rendered frames (its random stream comes from the seed)
    noise_model : DepthNoiseModel, Kinect-like by default
    known_occluders : frames carry the mask of the robot's hands and arms as drawn
        (``RGBDFrame.occluder_mask``), as a robot that knows where its own arms are sends it
    arm : "drawn" (a gripper, wrist and two links to its shoulder, ``sim.robot_drawing``) or
        "panda" (a Franka Panda mounted at the shoulder, ``sim.panda``), for every hand
        added with a shoulder

    A ``sim.scene.Scene``. After construction (and ``reset``) the cloth has settled for
    ``spec.settle_s`` (and been brought to rest for ``spec.rest_s``): frame 0. ``step()``
    advances one frame, ``render()`` returns what the sensor sees now, ``render_empty()``
    the same view without the cloth (a reference picture of the empty table), and the
    accessors below give the ground truth. Use as a context manager or call ``close()``.
    ``add_robot_hand`` adds a gripper that the camera sees with its wrist and arm.
    """

    def __init__(self, spec: LaundrySpec, noise: bool = True, noise_model: DepthNoiseModel | None = None,
                 known_occluders: bool = False, arm: str = "drawn"):
        if arm not in ARMS:
            raise ValueError(f"LaundryScene: expected arm in {ARMS}, got {arm!r}")
        self.arm = arm
        self.spec = spec
        self.known_occluders = bool(known_occluders)
        self.name = f"laundry:{spec.seed}"
        self.noise = bool(noise)
        self.noise_model = noise_model or DepthNoiseModel()
        self.camera = spec.camera
        self.T_world_cam = np.asarray(spec.T_world_cam, dtype=np.float64)
        if isinstance(spec.substeps, bool) or int(spec.substeps) != spec.substeps or spec.substeps < 1:
            raise ValueError(f"LaundryScene: expected spec.substeps a positive integer, got {spec.substeps!r}")
        self.physics: ClothPhysics | None = None
        self.hands: list[RobotHand] = []
        self._reach_arms: dict[tuple, PandaArm] = {}  # arms that only check reach, by shoulder
        self.reset()
        log.info("laundry scene %s", spec.describe())

    def reset(self) -> None:
        """Build the world from the spec again and let the cloth settle: frame 0, and the same
        frames (noise included) after it as the first time."""
        self.close()
        spec = self.spec
        _, noise_seq = np.random.SeedSequence(spec.seed).spawn(2)
        self._noise_rng = np.random.default_rng(noise_seq)
        self.physics = ClothPhysics(timestep_s=spec.timestep_s)
        try:
            for box in spec.boxes:
                self.physics.add_box(box.half_extents_m, box.position, box.quat_xyzw, box.rgba)
            self.cloth_id = self.physics.add_cloth(spec.cloth, spec.cloth_vertices_world, spec.material)
            self.physics.set_timestep(spec.timestep_s / spec.substeps)
            self.holder: Gripper | None = None
            if spec.holder_vertex is not None:
                # Visible, so that it hides the corner it holds as a hand or gripper would.
                self.holder = self.physics.add_gripper(spec.holder_position, visual_half_extents_m=HOLDER_HALF_EXTENTS_M,
                                                       rgba=(0.25, 0.25, 0.28, 1.0))
                self.holder.close_on(self.physics.nodes_near(spec.holder_position, HOLDER_RADIUS_M))
            self.virtual_camera = VirtualCamera(self.camera, self.T_world_cam, lighting=spec.lighting)
            self.physics.advance(spec.settle_s)
            if spec.rest_s > 0:
                self.physics.settle_to_rest(spec.rest_s)
        except Exception:
            self.close()
            raise
        self.frame_index = 0
        self._last_mask: np.ndarray | None = None

    @classmethod
    def from_seed(cls, seed: int, noise: bool = True, **spec_options) -> LaundryScene:
        """``LaundryScene(laundry_spec(seed, **spec_options), noise)``."""
        return cls(laundry_spec(seed, **spec_options), noise=noise)

    # -- time ---------------------------------------------------------------------------------

    def step(self) -> None:
        """Advance one frame period (1/30 s)."""
        self.physics.advance(1.0 / self.fps)
        self.frame_index += 1

    def add_robot_hand(self, position, quat_xyzw, shoulder_world=None, look: GripperLook | None = None,
                       opening_m: float | None = None) -> RobotHand:
        """A robot gripper at a world pose (fingertip centre, ``R_world_gripper`` as a quaternion),
        open, drawn with its wrist and its arm reaching to ``shoulder_world`` (3,) metres (with
        ``arm="panda"``, carried by a Panda whose shoulder is there)."""
        look = look if look is not None else GripperLook()
        shoulder = None if shoulder_world is None else np.asarray(shoulder_world, dtype=np.float64)
        arm = None
        if self.arm == "panda" and shoulder is not None:
            arm = self._panda_at(shoulder)
        gripper = self.physics.add_gripper(position, quat_xyzw)
        hand = RobotHand(gripper, look, shoulder, look.max_opening_m if opening_m is None else float(opening_m), arm)
        self.hands.append(hand)
        return hand

    def can_reach(self, shoulder_world, T_world_gripper: np.ndarray) -> Reach | None:
        """How near the arm mounted at ``shoulder_world`` (3,) would bring a gripper to the pose
        ``T_world_gripper`` (4, 4), without moving any arm: a ``sim.panda.Reach``, or None with
        drawn arms, which reach anywhere."""
        if self.arm != "panda":
            return None
        shoulder = np.asarray(shoulder_world, dtype=np.float64)
        key = tuple(np.round(shoulder, 6))
        if key not in self._reach_arms:
            self._reach_arms[key] = self._panda_at(shoulder)
        return self._reach_arms[key].can_reach(T_world_gripper)

    def _panda_at(self, shoulder: np.ndarray) -> PandaArm:
        """A Panda with its shoulder at ``shoulder`` (3,), facing the table's middle, on a column
        from the table top when it stands over the table, else from the floor."""
        over_table = bool(np.all(np.abs(shoulder[:2]) < TABLE_HALF_XY_M))
        return PandaArm.at_shoulder(shoulder, [0.0, 0.0, self.spec.table_top_z],
                                    self.spec.table_top_z if over_table else 0.0)

    def close(self) -> None:
        """Disconnect PyBullet and the arms' own clients (idempotent)."""
        arms = [h.arm for h in getattr(self, "hands", []) if h.arm is not None]
        for arm in arms + list(getattr(self, "_reach_arms", {}).values()):
            arm.close()
        self.hands, self._reach_arms = [], {}
        super().close()

    def step_coming_to_rest(self) -> None:
        """Advance one frame period while the cloth comes to rest as air drag would bring it
        (``ClothPhysics.settle_to_rest``; PyBullet's cloth has no drag and would swing on for
        tens of seconds). For a robot waiting, grippers still, for a hanging cloth to calm."""
        self.physics.settle_to_rest(1.0 / self.fps)
        self.frame_index += 1

    def release_holder(self) -> None:
        """The holder of a ``held`` cloth lets go (nothing happens for other states)."""
        if self.holder is not None:
            self.holder.open()

    # -- sensor -------------------------------------------------------------------------------

    def _frame(self, rgb: np.ndarray, depth: np.ndarray, occluder_mask: np.ndarray | None = None) -> RGBDFrame:
        rgb, depth = self._sensed(rgb, depth)
        return RGBDFrame(rgb=rgb, depth_m=depth, camera=self.camera, timestamp_s=self.time_s, seq=self.frame_index,
                         occluder_mask=occluder_mask)

    def _hands_drawn(self):
        """The robot's hands and arms as one world-frame SolidMesh, or None without hands."""
        if not self.hands:
            return None
        return merge([h.drawn() for h in self.hands])

    def render(self) -> RGBDFrame:
        """The current frame as the sensor sees it (with noise if the scene has it), the
        robot's hands and arms drawn in it (their mask in ``occluder_mask`` when the scene
        has ``known_occluders``)."""
        image = self.virtual_camera.render(self.physics, self.spec.texture_rgb, solids=self._hands_drawn())
        self._last_mask = image.body_ids == self.cloth_id
        occluders = None
        if self.known_occluders and self.hands:
            occluders = image.body_ids == SOLID_ID
        return self._frame(image.rgb, image.depth_m, occluders)

    def render_empty(self) -> RGBDFrame:
        """The same view without the cloth: what the sensor saw of the empty table."""
        image = self.virtual_camera.render_rigid(self.physics)
        return self._frame(image.rgb, image.depth_m)

    def render_turned(self, angle_rad: float) -> tuple[RGBDFrame, RGBDFrame, np.ndarray]:
        """What the sensor sees once the holder has turned a held cloth by ``angle_rad``
        about the vertical through the holder: (frame, the same view without the cloth,
        T_world_cam of that view).

        A cloth at rest that hangs from one point keeps its shape when the point turns it
        about the vertical, so turning the cloth is rendered as turning the camera the
        other way about that axis; the cloth's points seen in the frame are then where the
        cloth hangs now, through the returned T_world_cam. Noise as in ``render``.
        Raises ValueError for a scene whose cloth is not held.
        """
        if self.holder is None:
            raise ValueError("render_turned: the cloth is not held (state 'held' only)")
        turn = np.eye(4)
        turn[:3, :3] = rotation_about_axis(np.array([0.0, 0.0, 1.0]), -float(angle_rad))
        axis = np.array([*self.spec.holder_position[:2], 0.0])
        turn[:3, 3] = axis - turn[:3, :3] @ axis
        T_world_cam = turn @ self.T_world_cam
        camera = VirtualCamera(self.camera, T_world_cam, lighting=self.spec.lighting)
        seen, empty = camera.render(self.physics, self.spec.texture_rgb), camera.render_rigid(self.physics)
        frame, reference = self._frame(seen.rgb, seen.depth_m), self._frame(empty.rgb, empty.depth_m)
        return frame, reference, T_world_cam

    def cloth_mask(self) -> np.ndarray:
        """(H, W) bool, where the last ``render()`` saw the cloth (exact, before noise)."""
        if self._last_mask is None:
            raise ValueError("cloth_mask: nothing rendered yet (call render first)")
        return self._last_mask

    # -- ground truth -------------------------------------------------------------------------

    def corner_vertices(self) -> np.ndarray:
        """(C,) int64 cloth vertex at each true corner (the corners are mesh vertices)."""
        uv = self.uv_m
        ids = np.array([np.argmin(np.linalg.norm(uv - c, axis=1)) for c in self.spec.corners_uv], dtype=np.int64)
        return ids

    def corners_world(self) -> np.ndarray:
        """(C, 3) float64 metres, world frame: where the true corners are now."""
        return self.cloth_vertices_world()[self.corner_vertices()]

    def support_height(self, xy_world: np.ndarray) -> np.ndarray:
        """Height of the surface under world points: the table top over the table, else the floor.

        xy_world : (N, 2) float metres; returns (N,) float64 metres
        """
        xy = np.asarray(xy_world, dtype=np.float64).reshape(-1, 2)
        hx, hy = TABLE_HALF_XY_M
        over = (np.abs(xy[:, 0]) <= hx) & (np.abs(xy[:, 1]) <= hy)
        return np.where(over, self.spec.table_top_z, 0.0)

    def clearance_above_support(self) -> np.ndarray:
        """(V,) float64 metres: height of each cloth node above the surface under it."""
        v = self.cloth_vertices_world()
        return v[:, 2] - self.support_height(v[:, :2])

    def boundary_vertices(self) -> np.ndarray:
        """(B,) int64 sorted ids of the cloth's boundary vertices."""
        return boundary_vertices(self.faces)

    def to_world(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points, metres, to (N, 3) world points."""
        return transform_points(self.T_world_cam, points_cam)
