"""Scripted cloth scenes that mirror the paper's experiments, in a registry.

A scene has two halves, as in dm_control: a ``SceneSpec`` (pure data: cloth, texture,
rigid boxes, camera pose, and the grippers' poses as a function of time), built by a
small factory from a seeded Generator, and ``ClothScene``, which builds the PyBullet
world from a spec (``sim.physics``), runs the script and renders RGB-D frames.

Scenes (``SCENES``, ``make_scene(name, seed=..., noise=...)``):

- ``poster_bend``: a printed poster held at its top corners; the corners move towards
  each other and turn so it bends (paper Figs. 4 and 5).
- ``shirt_chair``: a printed T-shirt held by the shoulders is carried over a chair's
  backrest and lowered: its lower third hangs over the front, the rest goes down behind
  the backrest (self-occlusion, Fig. 6).
- ``shirt_textureless_rotate``: a plain T-shirt held by the shoulders turns out of the
  image plane (Fig. 7).
- ``towel_sway``: a printed towel hanging from two grippers that sway and come closer,
  so it swings and folds.

Scenes of a cloth being handled (``HANDLED_SCENES``), each with a drawn occluder:

- ``occluder_sweep``: an arm- or hand-sized bar or capsule sweeps across in front of a
  hanging printed cloth.
- ``gripper_corner_move``: a robot's parallel gripper, with its wrist and arm, grasps a
  hanging cloth's free bottom corner, lifts it and carries it sideways.
- ``table_lift``: a robot's gripper lifts a printed cloth lying flat on a table by one
  corner, at robot speed, until it hangs.

Beside them, not in the table by default (``MORE_HANDLED_SCENES``):

- ``occluder_close``: ``occluder_sweep`` with the occluder just in front of the cloth, its
  back 1-8 cm before it, as a hand on the cloth or a tool passing close: nearer than the
  tracker's occlusion margin.
- ``occluder_plain``: ``occluder_close`` on a cloth of one plain colour.
- ``occluder_near_camera``: a hand-sized ball passes a few tens of centimetres in front of
  the camera, inside the sensor's minimum range (no depth), and stops over the cloth.

Their occluders are drawn (``sim.solids``), never simulated: a scene made with
``occluders=False`` is their twin, the same cloth moving the same way with nothing drawn
in front of it. With ``known_occluders=True`` the frames carry the exact mask of the
occluders as rendered (``RGBDFrame.occluder_mask``), as a robot that knows where its own
gripper and arm are would send it.

World frame: z up, the camera looks roughly along +y at the cloth, which faces -y.
The same seed gives the same frames; noise on or off does not change the scene.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ipc.messages import CameraInfo, RGBDFrame
from perception.geometry import frames_from_z_and_x, invert_transform, look_at, transform_points
from sim.camera import SOLID_ID, Lighting, VirtualCamera
from sim.cloth_mesh import ClothMesh, TShirtShape, rectangle_cloth, tshirt_cloth
from sim.noise import DepthNoiseModel
from sim.physics import ClothMaterial, ClothPhysics
from sim.robot_drawing import GripperLook
from sim.scene import PhysicsScene, check_seed
from sim.solids import SolidMesh, box, capsule, sphere
from sim.textures import plain_texture, poster_texture, random_plain_colour

log = logging.getLogger(__name__)

FPS = 30.0
DEFAULT_FRAMES = 60
# radius around a grasp point whose nodes a gripper pins: a finger pad's size
GRASP_RADIUS_M = 0.03


@dataclass(frozen=True)
class Box:
    """A static box of the scenery. half_extents_m, position : (3,) metres, world frame."""

    half_extents_m: tuple
    position: tuple
    rgba: tuple = (0.6, 0.6, 0.6, 1.0)
    quat_xyzw: tuple = (0.0, 0.0, 0.0, 1.0)


Pose = tuple  # (position (3,) metres, quat_xyzw (4,)) in the world frame


@dataclass(frozen=True)
class GraspEvent:
    """At ``time_s`` (seconds after frame 0, taken at the nearest frame), gripper number
    ``gripper`` closes on the cloth nodes within ``GRASP_RADIUS_M`` of vertex ``vertex``."""

    time_s: float
    gripper: int
    vertex: int


@dataclass(frozen=True)
class SceneSpec:
    """Everything a scene needs, as data.

    cloth : ClothMesh; cloth_vertices_world : (V, 3) initial flat placement, metres
    texture_rgb : (H, W, 3) uint8 spanning the cloth's bounding box
    material : ClothMaterial
    boxes : scenery
    grasp_vertices : one cloth vertex id for each of the first grippers (the holders);
        each of them starts there and pins the nodes within ``GRASP_RADIUS_M``
    gripper_poses : t (seconds after frame 0) -> one Pose per gripper; at t = 0 the
        holders' positions are those of their grasp vertices, and any further gripper
        (a robot's) starts free at its pose
    camera : CameraInfo; T_world_cam : (4, 4) optical frame to world
    settle_s : simulated time before frame 0, grippers still, so the cloth hangs at rest
    timestep_s : the step the cloth's springs are made for, a whole fraction of the 1/30 s
        frame period
    substeps : physics steps per ``timestep_s`` (the same cloth integrated more finely,
        for contact with a table)
    n_frames : frames the script is written for
    grasp_events : GraspEvent, grippers closing on the cloth after frame 0
    occluders : t -> SolidMesh (world frame) of the rigid bodies drawn in front of the
        camera at time t (None: nothing then); None for a scene without occluders
    """

    name: str
    cloth: ClothMesh
    cloth_vertices_world: np.ndarray
    texture_rgb: np.ndarray
    material: ClothMaterial
    boxes: tuple
    grasp_vertices: tuple
    gripper_poses: Callable[[float], list[Pose]]
    camera: CameraInfo
    T_world_cam: np.ndarray
    settle_s: float = 1.0
    timestep_s: float = 1.0 / 240.0
    lighting: Lighting = field(default_factory=Lighting)
    substeps: int = 1
    n_frames: int = DEFAULT_FRAMES
    grasp_events: tuple = ()
    occluders: Callable[[float], SolidMesh | None] | None = None


#: Largest simulated image side, pixels (a 4K camera's width). PyBullet's software renderer
#: allocates several buffers of the image's size and aborts the whole process when it cannot
#: (a 100000-pixel side), so the size is checked before it is asked.
MAX_CAMERA_SIDE_PX = 4096


def kinect_camera(width: int, height: int) -> CameraInfo:
    """Kinect-like intrinsics (f = 525 px at 640 wide, principal point at the image centre)."""
    if int(width) < 16 or int(height) < 16:
        raise ValueError(f"camera size: expected at least 16x16 pixels, got {width}x{height}")
    if int(width) > MAX_CAMERA_SIDE_PX or int(height) > MAX_CAMERA_SIDE_PX:
        raise ValueError(f"camera size: expected at most {MAX_CAMERA_SIDE_PX}x{MAX_CAMERA_SIDE_PX} pixels, "
                         f"got {width}x{height}")
    f = 525.0 * int(width) / 640.0
    K = np.array([[f, 0.0, (int(width) - 1) / 2.0], [0.0, f, (int(height) - 1) / 2.0], [0.0, 0.0, 1.0]])
    return CameraInfo(width=int(width), height=int(height), K=K)


def _yaw_quat(yaw_rad: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(0.5 * yaw_rad), np.cos(0.5 * yaw_rad)])


def _ease(t: float, period_s: float) -> float:
    """0 at t = 0, 1 at half a period, back to 0 after a full one (smooth cosine)."""
    return 0.5 * (1.0 - np.cos(2.0 * np.pi * t / period_s))


def _hang_facing_camera(mesh: ClothMesh, top_centre: np.ndarray) -> np.ndarray:
    """Vertices of the flat cloth in the x-z plane, front towards -y, top edge centred at top_centre."""
    width, _ = mesh.size_m
    origin = np.asarray(top_centre, dtype=np.float64) - np.array([0.5 * width, 0.0, 0.0])
    return mesh.layout_points(origin, right=np.array([1.0, 0.0, 0.0]), down=np.array([0.0, 0.0, -1.0]))


#: The landmarks a rectangle is held by when it hangs, and those of a T-shirt.
TOP_CORNERS = ("top_left", "top_right")
SHOULDERS = ("left_shoulder", "right_shoulder")


def _hung(mesh: ClothMesh, top_centre, held: tuple) -> tuple[np.ndarray, tuple, list]:
    """The flat cloth hung facing the camera (``_hang_facing_camera``) from its landmarks
    ``held``: (vertices (V, 3) metres world, the held vertex ids, the held vertices' positions)."""
    verts = _hang_facing_camera(mesh, np.asarray(top_centre, dtype=np.float64))
    grasps = tuple(mesh.landmarks[name] for name in held)
    return verts, grasps, [verts[g] for g in grasps]


def _room(rng: np.random.Generator, wall_y_m: float | None) -> tuple:
    """Floor (top at z = 0) and optionally a wall facing the camera at y = wall_y_m."""
    grey = rng.uniform(0.45, 0.6)
    boxes = [Box((4.0, 4.0, 0.01), (0.0, 0.0, -0.01), (grey + 0.08, grey, grey - 0.08, 1.0))]
    if wall_y_m is not None:
        tone = rng.uniform(0.7, 0.85)
        boxes.append(Box((4.0, 0.02, 1.5), (0.0, wall_y_m + 0.02, 1.5), (tone, tone - 0.03, tone - 0.1, 1.0)))
    return tuple(boxes)


def _camera_pose(rng: np.random.Generator, eye, target) -> np.ndarray:
    """look_at with the pose jittered by a few centimetres, so no test is tuned to one view."""
    eye = np.asarray(eye, dtype=np.float64) + rng.uniform(-0.05, 0.05, 3)
    target = np.asarray(target, dtype=np.float64) + rng.uniform(-0.03, 0.03, 3)
    return look_at(eye, target)


def _texture_for(mesh: ClothMesh, rng: np.random.Generator, px_per_m: float = 900.0) -> np.ndarray:
    """A poster texture with the cloth's aspect ratio, ~2 texels per image pixel at ~1.2 m."""
    width, height = mesh.size_m
    return poster_texture(rng, round(width * px_per_m), round(height * px_per_m),
                          n_shapes=int(120 * width * height / 0.27), n_words=int(10 * width * height / 0.27))


def _two_hand_script(start: list[np.ndarray], offsets: Callable[[float], list[tuple]]) -> Callable[[float], list[Pose]]:
    """gripper_poses(t) from start positions and a function t -> [(offset (3,), yaw)] per gripper."""
    def poses(t: float) -> list[Pose]:
        return [(p0 + np.asarray(off, dtype=np.float64), _yaw_quat(yaw)) for p0, (off, yaw) in zip(start, offsets(t))]
    return poses


def _two_hand_spec(name: str, rng: np.random.Generator, camera: CameraInfo, mesh: ClothMesh, hung: tuple,
                   offsets: Callable[[float], list[tuple]], texture_rgb: np.ndarray, mass_per_area_kg_m2: float,
                   boxes: tuple, eye, target) -> SceneSpec:
    """A paper scene's spec: ``mesh`` hung as ``hung`` (``_hung``'s result) from two hands that
    follow ``offsets``, seen from about ``eye`` (jittered by ``_camera_pose``, drawn last)."""
    verts, grasps, start = hung
    return SceneSpec(name=name, cloth=mesh, cloth_vertices_world=verts, texture_rgb=texture_rgb,
                     material=ClothMaterial(mass_per_area_kg_m2=mass_per_area_kg_m2), boxes=boxes,
                     grasp_vertices=grasps, gripper_poses=_two_hand_script(start, offsets), camera=camera,
                     T_world_cam=_camera_pose(rng, eye=eye, target=target))


def poster_bend_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A ~0.60 x 0.45 m poster held at its top corners, bent by moving them together and turning them.

    Over a 4 s cycle the corners come 35 % closer, 5 cm towards the camera and turn
    0.6 rad each so the poster curls away from the camera, peaking at t = 2 s (frame 60).
    """
    scale = rng.uniform(0.9, 1.1)
    mesh = rectangle_cloth(0.60 * scale, 0.45 * scale, spacing_m=0.025)
    verts, grasps, start = _hung(mesh, (0.0, 0.0, 1.35), TOP_CORNERS)
    width = mesh.size_m[0]

    def offsets(t: float) -> list:
        b = _ease(t, 4.0)
        inward, forward, yaw = 0.175 * width * b, -0.05 * b, 0.6 * b
        return [((inward, forward, 0.0), yaw), ((-inward, forward, 0.0), -yaw)]

    return _two_hand_spec("poster_bend", rng, camera, mesh, (verts, grasps, start), offsets,
                          _texture_for(mesh, rng), 0.2, _room(rng, wall_y_m=0.8), eye=(0.1, -1.1, 1.3),
                          target=(0.0, 0.0, 1.1))


def _shirt(rng: np.random.Generator) -> ClothMesh:
    return tshirt_cloth(TShirtShape().scaled(rng.uniform(0.9, 1.1)), spacing_m=0.03)


def shirt_chair_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A printed T-shirt held by the shoulders, carried over a chair's backrest and lowered.

    The shirt starts hanging in front of the backrest with its lower third below the
    backrest's top. The holders move 0.28 m back over the backrest (0 to 1 s), then
    down 0.6 m (1 to 2 s), the shoulders ending ~15 cm below the backrest's top: the
    lower third lies over the front of the backrest and the rest goes down behind it,
    hidden by the backrest and by the shirt's own front.
    """
    mesh = _shirt(rng)
    backrest_top = 0.90
    shoulder_to_hem = mesh.uv_m[:, 1].max() - mesh.uv_m[mesh.landmarks["left_shoulder"], 1]
    hem_below_top = shoulder_to_hem / 3.0
    shoulder_z = backrest_top - hem_below_top + shoulder_to_hem
    shoulder_v = mesh.uv_m[mesh.landmarks["left_shoulder"], 1]
    verts, grasps, start = _hung(mesh, (0.0, -0.08, shoulder_z + shoulder_v), SHOULDERS)
    wood = (0.45, 0.3, 0.18, 1.0)
    chair = (
        Box((0.23, 0.02, 0.225), (0.0, 0.02, backrest_top - 0.225), wood),  # backrest, front face at y = 0
        Box((0.23, 0.22, 0.02), (0.0, 0.24, 0.45), wood),  # seat, behind the backrest
    ) + tuple(Box((0.02, 0.02, 0.215), (x, y, 0.215), wood) for x in (-0.21, 0.21) for y in (0.02, 0.44))

    def offsets(t: float) -> list:
        back = 0.28 * min(t / 1.0, 1.0)
        down = 0.60 * np.clip((t - 1.0) / 1.0, 0.0, 1.0)
        return [((0.0, back, -down), 0.0)] * 2

    return _two_hand_spec("shirt_chair", rng, camera, mesh, (verts, grasps, start), offsets,
                          _texture_for(mesh, rng), 0.18, _room(rng, wall_y_m=1.2) + chair, eye=(0.0, -1.3, 1.35),
                          target=(0.0, 0.0, 0.95))


def shirt_textureless_rotate_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A plain-coloured T-shirt held by the shoulders, turned out of the image plane.

    Both holders turn about the vertical line through the shirt's centre, up to 1 rad
    at t = 2 s (frame 60) and back by t = 4 s.
    """
    mesh = _shirt(rng)
    shoulder_v = mesh.uv_m[mesh.landmarks["left_shoulder"], 1]
    verts, grasps, start = _hung(mesh, (0.0, 0.0, 1.45 + shoulder_v), SHOULDERS)
    axis = 0.5 * (start[0] + start[1])

    def offsets(t: float) -> list:
        yaw = 1.0 * _ease(t, 4.0)
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return [(rot @ (p0 - axis) + axis - p0, yaw) for p0 in start]

    colour = random_plain_colour(rng)
    return _two_hand_spec("shirt_textureless_rotate", rng, camera, mesh, (verts, grasps, start), offsets,
                          plain_texture(colour), 0.18, _room(rng, wall_y_m=0.7), eye=(0.0, -1.25, 1.3), target=(0.0, 0.0, 1.1))


def towel_sway_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A ~0.6 m wide printed towel hanging from two grippers at its top corners, seen from ~1.3 m.

    The grippers sway sideways (0.12 m, 2 s period) and back and forth (4 cm, 1.5 s),
    and come up to 40 % closer over a 4 s cycle, so the towel swings and folds.
    """
    scale = rng.uniform(0.9, 1.1)
    mesh = rectangle_cloth(0.60 * scale, 0.50 * scale, spacing_m=0.025)
    verts, grasps, start = _hung(mesh, (0.0, 0.0, 1.4), TOP_CORNERS)
    width = mesh.size_m[0]

    def offsets(t: float) -> list:
        sway = 0.12 * np.sin(2.0 * np.pi * t / 2.0)
        depth = 0.04 * np.sin(2.0 * np.pi * t / 1.5)
        inward = 0.2 * width * _ease(t, 4.0)
        return [((sway + inward, depth, 0.0), 0.0), ((sway - inward, depth, 0.0), 0.0)]

    return _two_hand_spec("towel_sway", rng, camera, mesh, (verts, grasps, start), offsets,
                          _texture_for(mesh, rng), 0.3, _room(rng, wall_y_m=None), eye=(0.0, -1.3, 1.25), target=(0.0, 0.0, 1.15))


# ----------------------------------------------------------------------------- handled scenes

#: Frames of a handled scene's script: its motion, then a short still end, clipped to this range.
HANDLED_FRAMES = (60, 90)
#: Seconds each handled script runs on after its motion, so recovery can be seen.
_AFTER_S = 0.5
#: Half extents (x, y) of the table of ``table_lift``, metres.
TABLE_HALF_XY_M = (0.6, 0.4)


def _frames_for(duration_s: float) -> int:
    return int(np.clip(np.ceil(duration_s * FPS), *HANDLED_FRAMES))


def _printed(mesh: ClothMesh, rng: np.random.Generator, px_per_m: float = 900.0) -> np.ndarray:
    """A poster texture for ``mesh`` whose density of shapes and words varies by a factor 0.5-1.5."""
    width, height = mesh.size_m
    density = rng.uniform(0.5, 1.5) * width * height / 0.27
    return poster_texture(rng, round(width * px_per_m), round(height * px_per_m),
                          n_shapes=max(20, int(120 * density)), n_words=max(3, int(10 * density)))


def _printed_in_a_room(rng: np.random.Generator, mesh: ClothMesh) -> dict:
    """A hanging handled cloth's print, material and room (drawn in this order), as ``SceneSpec`` fields."""
    return {"texture_rgb": _printed(mesh, rng), "material": ClothMaterial(mass_per_area_kg_m2=rng.uniform(0.18, 0.3)),
            "boxes": _room(rng, wall_y_m=rng.uniform(0.6, 1.0))}


def _gripper_rotation(approach, closing_hint) -> np.ndarray:
    """(3, 3) R_world_gripper: z along ``approach``, x along ``closing_hint`` made perpendicular to it."""
    z = np.asarray(approach, dtype=np.float64)
    return frames_from_z_and_x((z / np.linalg.norm(z))[None], np.asarray(closing_hint, dtype=np.float64)[None])[0]


def _trapezoid(tau_s: float, distance_m: float, speed_m_s: float, ramp_s: float) -> tuple[float, float]:
    """(fraction of ``distance_m`` covered after ``tau_s``, total duration) of a move that speeds up
    over ``ramp_s`` to ``speed_m_s``, cruises, and slows down over ``ramp_s`` (or less, if short)."""
    accel = speed_m_s / ramp_s
    if distance_m <= 0:
        return 1.0, 0.0
    if distance_m < speed_m_s * ramp_s:  # never reaches the cruising speed
        peak = np.sqrt(accel * distance_m)
        ramp, cruise = peak / accel, 0.0
    else:
        peak, ramp = speed_m_s, ramp_s
        cruise = (distance_m - speed_m_s * ramp_s) / speed_m_s
    total = 2.0 * ramp + cruise
    tau = float(np.clip(tau_s, 0.0, total))
    if tau < ramp:
        covered = 0.5 * accel * tau * tau
    elif tau < ramp + cruise:
        covered = 0.5 * accel * ramp * ramp + peak * (tau - ramp)
    else:
        covered = distance_m - 0.5 * accel * (total - tau) ** 2
    return covered / distance_m, total


@dataclass(frozen=True)
class PickAndMove:
    """A robot gripper's script: approach along its z to a grasp point, close, then move by an offset.

    grasp_m : (3,) world point where the fingertips close; R : (3, 3) R_world_gripper,
    constant (``sim.robot_drawing`` frame: z approach, x closing)
    pregrasp_m : the approach starts this far back along -z, at t = 0
    approach_speed_m_s, move_speed_m_s : cruising speeds (ramps of ``ramp_s``)
    move_m : (3,) world offset of the move after the grasp
    look : GripperLook; shoulder_m : (3,) world point the arm is mounted at
    close_s : the fingers close over this time once the grasp point is reached; the grasp
        (``grasp_time_s``) is on the first frame after
    closed_opening_m : the fingers' opening once closed on the cloth
    """

    grasp_m: np.ndarray
    R: np.ndarray
    pregrasp_m: float
    approach_speed_m_s: float
    move_m: np.ndarray
    move_speed_m_s: float
    look: GripperLook
    shoulder_m: np.ndarray
    close_s: float = 0.1
    closed_opening_m: float = 0.006
    ramp_s: float = 0.15

    @property
    def reached_s(self) -> float:
        return _trapezoid(0.0, self.pregrasp_m, self.approach_speed_m_s, self.ramp_s)[1]

    @property
    def grasp_time_s(self) -> float:
        """Time of the frame at which the fingers have closed and hold the cloth."""
        return float(np.ceil((self.reached_s + self.close_s) * FPS - 1e-9) / FPS)

    @property
    def move_start_s(self) -> float:
        return self.grasp_time_s + 1.0 / FPS

    @property
    def end_s(self) -> float:
        """When the move ends."""
        return self.move_start_s + _trapezoid(0.0, float(np.linalg.norm(self.move_m)), self.move_speed_m_s,
                                              self.ramp_s)[1]

    def position(self, t: float) -> np.ndarray:
        """(3,) fingertip centre at time t, metres, world."""
        if t < self.move_start_s:
            done, _ = _trapezoid(t, self.pregrasp_m, self.approach_speed_m_s, self.ramp_s)
            return self.grasp_m - (1.0 - done) * self.pregrasp_m * self.R[:, 2]
        done, _ = _trapezoid(t - self.move_start_s, float(np.linalg.norm(self.move_m)), self.move_speed_m_s,
                             self.ramp_s)
        return self.grasp_m + done * self.move_m

    def pose(self, t: float) -> Pose:
        return self.position(t), Rotation.from_matrix(self.R).as_quat()

    def opening(self, t: float) -> float:
        """Distance between the fingers at time t, metres."""
        closing = np.clip((t - self.reached_s) / (self.grasp_time_s - self.reached_s), 0.0, 1.0)
        return float(self.look.max_opening_m + closing * (self.closed_opening_m - self.look.max_opening_m))

    def mesh(self, t: float) -> SolidMesh:
        """The drawn gripper, wrist and arm at time t (world frame)."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.position(t)
        return self.look.mesh(T, self.opening(t), self.shoulder_m)


def _occluder_colour(rng: np.random.Generator) -> tuple:
    """A skin tone, a sleeve's colour or a robot's grey."""
    kind = rng.integers(0, 3)
    if kind == 0:
        tones = np.array([(236, 188, 150), (205, 150, 110), (160, 110, 75), (110, 72, 50)], dtype=float)
        return tuple(np.clip(tones[rng.integers(0, len(tones))] + rng.uniform(-10, 10, 3), 0, 255))
    if kind == 1:
        return random_plain_colour(rng)
    grey = rng.uniform(60, 200)
    return (grey, grey, grey + rng.uniform(0, 10))


def occluder_sweep_spec(rng: np.random.Generator, camera: CameraInfo, close: bool = False) -> SceneSpec:
    """An arm- or hand-sized bar or capsule sweeps across in front of a hanging printed cloth.

    The cloth (0.45-0.75 m by 0.35-0.60 m) hangs from its top corners, which sway 2-8 cm
    sideways and up to 3 cm back and forth, so that the hidden part moves too. The
    occluder, 6-12 cm wide and 0.5-0.8 m long (a box or a capsule), lies 20-40 cm in
    front of the cloth with its long axis up or down (within 20 degrees of square to its
    path) and moves at a constant 0.35-1.0 m/s (faster when a slow pass would
    not fit in 90 frames), left to right or right to left, up to 25 degrees off the
    horizontal, from wholly beside the cloth to wholly beyond its other side as the camera
    sees them. The camera stands 1.1-1.35 m in front of the cloth.

    close : the occluder's back lies 1-8 cm in front of the cloth as it comes nearest the
        camera instead (the same draws, so the same cloth and motion as without)
    """
    width, height = rng.uniform(0.45, 0.75), rng.uniform(0.35, 0.60)
    mesh = rectangle_cloth(width, height, spacing_m=0.025)
    top_z = rng.uniform(1.30, 1.50)
    verts, grasps, start = _hung(mesh, (0.0, 0.0, top_z), TOP_CORNERS)
    sway_m, sway_period_s = rng.uniform(0.02, 0.08), rng.uniform(2.0, 4.0)
    fore_m, fore_period_s = rng.uniform(0.0, 0.03), rng.uniform(1.5, 3.0)

    def offsets(t: float) -> list:
        x = sway_m * np.sin(2.0 * np.pi * t / sway_period_s)
        y = fore_m * np.sin(2.0 * np.pi * t / fore_period_s)
        return [((x, y, 0.0), 0.0)] * 2

    camera_distance = rng.uniform(1.10, 1.35)
    bottom_z = top_z - height
    T_world_cam = _camera_pose(rng, eye=(0.0, -camera_distance, top_z - 0.05), target=(0.0, 0.0, top_z - 0.5 * height))

    capsule_shaped = bool(rng.random() < 0.5)
    thickness = rng.uniform(0.06, 0.12)
    depth = rng.uniform(0.04, 0.08)
    length = rng.uniform(0.5, 0.8)
    gap = rng.uniform(0.20, 0.40)
    if close:
        back = 0.5 * (thickness if capsule_shaped else depth)  # from its centre line to its back
        gap = back + fore_m + 0.01 + (gap - 0.20) / 0.20 * 0.07
    speed = rng.uniform(0.35, 1.0)
    heading, tilt = rng.choice([-1.0, 1.0]), np.radians(rng.uniform(-25.0, 25.0))
    direction = np.array([heading * np.cos(tilt), 0.0, np.sin(tilt)])
    from_above = bool(rng.random() < 0.6)
    lean = np.radians(rng.uniform(-20.0, 20.0))
    square = np.array([-direction[2], 0.0, direction[0]])  # direction turned 90 degrees in the x-z plane
    square *= 1.0 if (square[2] > 0) == from_above else -1.0
    axis = np.cos(lean) * square + np.sin(lean) * direction
    fraction = rng.uniform(0.15, 0.55) if from_above else rng.uniform(0.45, 0.85)
    through = np.array([rng.uniform(-0.15, 0.15) * width, -gap, bottom_z + fraction * height])
    lead_in_s = rng.uniform(0.1, 0.3)
    colour = _occluder_colour(rng)
    across = direction - (direction @ axis) * axis
    across /= np.linalg.norm(across)
    R_box = np.column_stack([across, np.cross(axis, across), axis])

    def shape(along_m: float) -> SolidMesh:
        """The occluder with its end ``along_m`` from ``through`` along its path."""
        end = through + along_m * direction
        if capsule_shaped:
            return capsule(end, end + length * axis, 0.5 * thickness, colour)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_box, end + 0.5 * length * axis
        return box((0.5 * thickness, 0.5 * depth, 0.5 * length), colour, T)

    # the path runs from where the camera sees the occluder wholly beside the swaying cloth
    # to where it sees it wholly beyond the other side
    T_cam_world = invert_transform(T_world_cam)
    cloth_cam = transform_points(T_cam_world, verts)
    reach = (sway_m + 0.03) / camera_distance
    cloth_x = (cloth_cam[:, 0] / cloth_cam[:, 2]).min() - reach, (cloth_cam[:, 0] / cloth_cam[:, 2]).max() + reach

    def beside(along_m: float) -> bool:
        p = transform_points(T_cam_world, shape(along_m).points)
        x = p[:, 0] / p[:, 2]
        return x.max() < cloth_x[0] or x.min() > cloth_x[1]

    path = [0.0, 0.0]
    for k, sign in enumerate((-1.0, 1.0)):
        while not beside(path[k]) and abs(path[k]) < 3.0:
            path[k] += 0.01 * sign
    # a slow pass over a long path would not fit in the frames: it goes faster
    speed = max(speed, (path[1] - path[0]) / (HANDLED_FRAMES[1] / FPS - lead_in_s - _AFTER_S))

    def occluders(t: float) -> SolidMesh:
        return shape(path[0] + speed * (t - lead_in_s))

    return SceneSpec(
        name="occluder_sweep",
        cloth=mesh,
        cloth_vertices_world=verts,
        **_printed_in_a_room(rng, mesh),
        grasp_vertices=grasps,
        gripper_poses=_two_hand_script(start, offsets),
        camera=camera,
        T_world_cam=T_world_cam,
        n_frames=_frames_for(lead_in_s + (path[1] - path[0]) / speed + _AFTER_S),
        occluders=occluders,
    )


def occluder_close_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """An arm- or hand-sized bar or capsule sweeps across just in front of a hanging printed
    cloth, its back 1-8 cm before it (``occluder_sweep_spec`` with ``close``)."""
    return replace(occluder_sweep_spec(rng, camera, close=True), name="occluder_close")


def occluder_plain_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """``occluder_close`` on a cloth of one plain colour (drawn after everything else, so the
    same cloth, motion and occluder as ``occluder_close``): there the occluder's edges are the
    image's only contrast, and its motion the only one an image comparison sees. The occluder's
    colour may come out near the cloth's (both can be a random plain colour): then nothing
    tells it from the cloth that close, as with a grey arm over a grey cloth."""
    spec = occluder_close_spec(rng, camera)
    return replace(spec, name="occluder_plain", texture_rgb=plain_texture(random_plain_colour(rng)))


def occluder_near_camera_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A hand-sized ball passes just in front of the camera, stops over the hanging cloth and
    goes on: inside the sensor's minimum range (``sim.noise.DepthNoiseModel.min_range_m``), so
    it has no depth at all.

    The cloth, its motion, camera and room are ``occluder_sweep``'s (the same draws); the cloth
    is printed or, on half the seeds, of one plain colour. The ball (radius 4-7 cm, its centre
    22 cm or more from the camera and its far side within 38 cm, on the line of sight to the
    cloth's middle; a skin tone, a sleeve's colour or a robot's grey) comes in from beside the
    cloth as the camera sees it, from the left or the right, in 0.4-0.6 s, stops over the
    cloth's middle (off it by up to a fifth of the cloth's width) for 0.5-1.0 s, and goes on
    out of the other side as fast.
    """
    spec = occluder_sweep_spec(rng, camera)
    if rng.random() < 0.5:
        spec = replace(spec, texture_rgb=plain_texture(random_plain_colour(rng)))
    radius = rng.uniform(0.04, 0.07)
    distance = rng.uniform(0.22, 0.38 - radius)  # the ball's far side within 38 cm of the camera
    colour = _occluder_colour(rng)
    eye = spec.T_world_cam[:3, 3]
    right = spec.T_world_cam[:3, 0]  # the camera's x axis, in the world
    cloth = spec.cloth_vertices_world
    centre = 0.5 * (cloth.min(axis=0) + cloth.max(axis=0))
    ahead = (centre - eye) / np.linalg.norm(centre - eye)
    # lateral offsets (metres at the ball's distance) from wholly beside the cloth in view to where it stops
    half_view = 0.5 * np.ptp(cloth @ right) * distance / np.linalg.norm(centre - eye)
    side = rng.choice([-1.0, 1.0])
    beside = side * (half_view + radius + 0.03)
    stop = rng.uniform(-0.2, 0.2) * half_view
    lead_in, move_s, stay_s = 0.3, rng.uniform(0.4, 0.6), rng.uniform(0.5, 1.0)

    def occluders(t: float) -> SolidMesh | None:
        if t < lead_in or t > lead_in + 2 * move_s + stay_s:
            return None
        phase = t - lead_in
        if phase < move_s:
            x = beside + (stop - beside) * phase / move_s
        elif phase < move_s + stay_s:
            x = stop
        else:
            x = stop + (-beside - stop) * (phase - move_s - stay_s) / move_s
        return sphere(eye + distance * ahead + x * right, radius, colour)

    return replace(spec, name="occluder_near_camera", occluders=occluders,
                   n_frames=_frames_for(lead_in + 2 * move_s + stay_s + _AFTER_S))


def gripper_corner_move_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A robot's gripper, wrist and arm grasp a hanging cloth's free bottom corner, lift it and carry it sideways.

    The printed cloth (0.40-0.65 m by 0.35-0.55 m) hangs from its top corners. The
    gripper (``GripperLook.random``) comes from outside the cloth's left or right edge,
    20-70 degrees towards the camera and 10-40 degrees from above, approaching 10-16 cm at
    0.3-0.5 m/s; it closes on the bottom corner and moves it 15-30 cm sideways (in or
    out), 10-25 cm up and up to 10 cm towards the camera at 0.3-0.6 m/s. Its arm reaches
    back to a shoulder 35-55 cm in front of the cloth, up to 35 cm from the corner towards
    the cloth's middle and 25-55 cm above it, so the arm crosses in front of the cloth.
    """
    width, height = rng.uniform(0.40, 0.65), rng.uniform(0.35, 0.55)
    mesh = rectangle_cloth(width, height, spacing_m=0.025)
    top_z = rng.uniform(1.40, 1.55)
    verts, holders, start = _hung(mesh, (0.0, 0.0, top_z), TOP_CORNERS)
    side = float(rng.choice([-1.0, 1.0]))
    corner = mesh.landmarks["bottom_right" if side > 0 else "bottom_left"]
    corner_at = verts[corner]
    look = GripperLook.random(rng)
    yaw, pitch = np.radians(rng.uniform(20.0, 70.0)), np.radians(rng.uniform(10.0, 40.0))
    back = np.array([side * np.cos(yaw) * np.cos(pitch), -np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
    in_plane = np.array([-back[0], 0.0, -back[2]])
    script = PickAndMove(
        grasp_m=corner_at + 0.012 * in_plane / np.linalg.norm(in_plane),
        R=_gripper_rotation(-back, closing_hint=(0.0, 1.0, 0.0)),
        pregrasp_m=rng.uniform(0.10, 0.16),
        approach_speed_m_s=rng.uniform(0.3, 0.5),
        move_m=np.array([rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.30), -rng.uniform(0.0, 0.10),
                         rng.uniform(0.10, 0.25)]),
        move_speed_m_s=rng.uniform(0.3, 0.6),
        look=look,
        # the robot stands in front of the cloth: its arm reaches across the cloth's front to the corner
        shoulder_m=corner_at + np.array([-side * rng.uniform(0.0, 0.35), -rng.uniform(0.35, 0.55),
                                         rng.uniform(0.25, 0.55)]),
    )

    def poses(t: float) -> list:
        return [(p, _yaw_quat(0.0)) for p in start] + [script.pose(t)]

    eye = (side * rng.uniform(0.0, 0.15), -rng.uniform(1.25, 1.45), top_z - 0.1)
    target = (0.25 * script.move_m[0], 0.0, top_z - 0.55 * height)
    return SceneSpec(
        name="gripper_corner_move",
        cloth=mesh,
        cloth_vertices_world=verts,
        **_printed_in_a_room(rng, mesh),
        grasp_vertices=holders,
        gripper_poses=poses,
        camera=camera,
        T_world_cam=_camera_pose(rng, eye=eye, target=target),
        n_frames=_frames_for(script.end_s + _AFTER_S),
        grasp_events=(GraspEvent(script.grasp_time_s, 2, corner),),
        occluders=script.mesh,
    )


def table_lift_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A printed cloth lying flat on a table is lifted by one corner at robot speed until it hangs.

    The cloth (0.30-0.42 m by 0.25-0.34 m) lies turned by up to 35 degrees near the
    middle of a table 0.72-0.78 m high. A robot's gripper approaches one of its corners
    from 10-13 cm above (up to 20 degrees off the vertical) at 0.3-0.5 m/s, closes on it
    and lifts it by the cloth's diagonal plus 8 cm at 0.3-0.5 m/s, drifting up to 12 cm
    sideways, so that the cloth ends hanging from that corner. Its arm reaches to a
    shoulder 0.5-0.8 m above the table, on any side but straight in front. The camera looks
    down at 30-45 degrees from 1.0-1.2 m in front of the table.
    """
    table_top = rng.uniform(0.72, 0.78)
    grey = rng.uniform(0.5, 0.65)
    boxes = (
        Box((4.0, 4.0, 0.01), (0.0, 0.0, -0.01), (0.42, 0.40, 0.37, 1.0)),
        Box((*TABLE_HALF_XY_M, 0.02), (0.0, 0.0, table_top - 0.02), (grey, grey, grey + 0.03, 1.0)),
    )
    width, height = rng.uniform(0.30, 0.42), rng.uniform(0.25, 0.34)
    mesh = rectangle_cloth(width, height, spacing_m=0.025)
    yaw = rng.uniform(-0.6, 0.6)
    right, down = np.array([np.cos(yaw), np.sin(yaw), 0.0]), np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    centre = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), table_top + 0.008])
    verts = mesh.layout_points(centre - 0.5 * width * right - 0.5 * height * down, right, down)  # front up
    corner = mesh.landmarks[("top_left", "top_right", "bottom_left", "bottom_right")[int(rng.integers(0, 4))]]
    corner_at = verts[corner]
    inward = centre - corner_at
    inward[2] = 0.0
    inward /= np.linalg.norm(inward)
    look = GripperLook.random(rng)
    tilt, tilt_dir = np.radians(rng.uniform(0.0, 20.0)), rng.uniform(0.0, 2.0 * np.pi)
    approach = np.array([np.sin(tilt) * np.cos(tilt_dir), np.sin(tilt) * np.sin(tilt_dir), -np.cos(tilt)])
    drift, drift_dir = rng.uniform(0.0, 0.12), rng.uniform(0.0, 2.0 * np.pi)
    shoulder_dir = np.radians(rng.uniform(-30.0, 210.0))
    reach = rng.uniform(0.35, 0.5)
    script = PickAndMove(
        grasp_m=corner_at + 0.015 * inward + np.array([0.0, 0.0, 0.004]),
        R=_gripper_rotation(approach, closing_hint=inward),
        pregrasp_m=rng.uniform(0.10, 0.13),
        approach_speed_m_s=rng.uniform(0.3, 0.5),
        move_m=np.array([drift * np.cos(drift_dir), drift * np.sin(drift_dir), np.hypot(width, height) + 0.08]),
        move_speed_m_s=rng.uniform(0.3, 0.5),
        look=look,
        shoulder_m=np.array([corner_at[0] + reach * np.cos(shoulder_dir), corner_at[1] + reach * np.sin(shoulder_dir),
                             table_top + rng.uniform(0.5, 0.8)]),
    )
    distance, elevation = rng.uniform(1.0, 1.2), np.radians(rng.uniform(30.0, 45.0))
    azimuth = np.radians(-90.0 + rng.uniform(-20.0, 20.0))
    target = np.array([*(0.5 * (centre[:2] + corner_at[:2]) + 0.5 * script.move_m[:2]), table_top + 0.3])
    eye = target + distance * np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                        np.sin(elevation)])
    return SceneSpec(
        name="table_lift",
        cloth=mesh,
        cloth_vertices_world=verts,
        texture_rgb=_printed(mesh, rng),
        material=ClothMaterial(mass_per_area_kg_m2=rng.uniform(0.25, 0.35)),
        boxes=boxes,
        grasp_vertices=(),
        gripper_poses=lambda t: [script.pose(t)],
        camera=camera,
        T_world_cam=_camera_pose(rng, eye=eye, target=target),
        settle_s=0.6,
        substeps=2,
        n_frames=_frames_for(script.end_s + _AFTER_S),
        grasp_events=(GraspEvent(script.grasp_time_s, 0, corner),),
        occluders=script.mesh,
    )


class ClothScene(PhysicsScene):
    """A scene running in PyBullet: physics, grippers following the script, camera, noise.

    name : key in ``SCENES``; build : (Generator, CameraInfo) -> SceneSpec
    seed : int; the scene (sizes, texture, camera jitter) and the noise draw from
        independent streams of it, so ``noise=False`` shows the same scene exactly
    noise : add sensor noise (``sim.noise``) to rendered frames
    width, height : image size in pixels (intrinsics scale with the width)
    occluders : draw the script's occluders (False: the twin scene, the same physics and
        noise draws with nothing drawn in front of the cloth)
    known_occluders : rendered frames carry ``occluder_mask``, the exact mask of the drawn
        occluders (all False where none is seen)

    A ``sim.scene.Scene``. After construction (and ``reset``) the world is at frame 0.
    ``step()`` advances one frame (1/30 s); ``render()`` returns the current frame as an
    RGBDFrame; ``cloth_vertices_cam()`` is the ground truth for it.
    """

    def __init__(self, name: str, build: Callable[[np.random.Generator, CameraInfo], SceneSpec], seed: int = 0,
                 noise: bool = True, width: int = 640, height: int = 480,
                 noise_model: DepthNoiseModel | None = None, occluders: bool = True, known_occluders: bool = False):
        self.name = name
        self._build = build
        self.noise = bool(noise)
        self.noise_model = noise_model or DepthNoiseModel()
        self.draw_occluders = bool(occluders)
        self.known_occluders = bool(known_occluders)
        self.camera = kinect_camera(width, height)
        self.fps = FPS
        self.physics: ClothPhysics | None = None
        self.seed = check_seed(seed)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Rebuild the world from ``seed`` (default: the last seed) and settle it to frame 0."""
        if seed is not None:
            self.seed = check_seed(seed)
        # the background has its own noise stream: taking it leaves the frames' noise draws as they are
        scene_seq, noise_seq, background_seq = np.random.SeedSequence(self.seed).spawn(3)
        self.spec = self._build(np.random.default_rng(scene_seq), self.camera)
        self._noise_rng = np.random.default_rng(noise_seq)
        self._background_noise_rng = np.random.default_rng(background_seq)
        self.close()
        spec = self.spec
        n_grippers = len(spec.gripper_poses(0.0))
        for event in spec.grasp_events:
            if round(event.time_s * self.fps) < 1 or not 0 <= event.gripper < n_grippers:
                raise ValueError(f"{self.name}: a grasp must come after frame 0 and name one of the {n_grippers} "
                                 f"grippers, got {event}")
        self.physics = ClothPhysics(timestep_s=spec.timestep_s)
        for scenery in spec.boxes:
            self.physics.add_box(scenery.half_extents_m, scenery.position, scenery.quat_xyzw, scenery.rgba)
        self.cloth_id = self.physics.add_cloth(spec.cloth, spec.cloth_vertices_world, spec.material)
        if spec.substeps != 1:
            self.physics.set_timestep(spec.timestep_s / spec.substeps)
        for i, (position, quat) in enumerate(spec.gripper_poses(0.0)):
            if i < len(spec.grasp_vertices):
                at = spec.cloth_vertices_world[spec.grasp_vertices[i]]
                gripper = self.physics.add_gripper(at)
                gripper.close_on(self.physics.nodes_near(at, GRASP_RADIUS_M))
            else:
                self.physics.add_gripper(position, quat)
        self.virtual_camera = VirtualCamera(self.camera, spec.T_world_cam, lighting=spec.lighting)
        self.physics.advance(spec.settle_s)
        self.frame_index = 0
        self._last_render = None

    @property
    def n_frames(self) -> int:
        """Frames the scene's script is written for (60 for the paper's scenes)."""
        return self.spec.n_frames

    @property
    def has_occluders(self) -> bool:
        """Whether the script has occluders (drawn or, in a twin, left out)."""
        return self.spec.occluders is not None

    def step(self) -> None:
        """Advance one frame period, grippers moving to the script's poses for the next frame;
        grippers whose grasp falls on the next frame close on the cloth there."""
        t_next = (self.frame_index + 1) / self.fps
        for gripper, (position, quat) in zip(self.physics.grippers, self.spec.gripper_poses(t_next)):
            gripper.move_to(position, quat)
        self.physics.advance(1.0 / self.fps)
        self.frame_index += 1
        for event in self.spec.grasp_events:
            if round(event.time_s * self.fps) == self.frame_index:
                at = self.physics.cloth_vertices()[event.vertex]
                self.physics.grippers[event.gripper].close_on(self.physics.nodes_near(at, GRASP_RADIUS_M))

    def robot_grips(self) -> dict[int, np.ndarray]:
        """Where the robot's closed grippers hold the cloth now: gripper number -> (3,) fingertip
        centre, metres, camera optical frame (the holders a cloth hangs from are not the robot's)."""
        held = {}
        for i, gripper in enumerate(self.physics.grippers):
            if i >= len(self.spec.grasp_vertices) and gripper.is_closed:
                held[i] = self.virtual_camera.world_to_camera(gripper.position[None])[0]
        return held

    def render_empty(self) -> RGBDFrame:
        """The same view without the cloth and the occluders: the empty workspace, as a robot
        would capture it before the cloth is put there (with noise if the scene has it)."""
        image = self.virtual_camera.render_rigid(self.physics)
        rgb, depth = self._sensed(image.rgb, image.depth_m, self._background_noise_rng)
        return RGBDFrame(rgb=rgb, depth_m=depth, camera=self.camera, timestamp_s=self.time_s, seq=self.frame_index)

    def occluder_mesh_world(self) -> SolidMesh | None:
        """The occluders the script places now (world frame), drawn or not; None when there are none."""
        return None if self.spec.occluders is None else self.spec.occluders(self.time_s)

    def _rendered(self):
        if self._last_render is None:
            raise ValueError("nothing rendered yet (call render first)")
        return self._last_render

    def cloth_mask(self) -> np.ndarray:
        """(H, W) bool, where the last ``render()`` saw the cloth (exact, before noise)."""
        return self._rendered().body_ids == self.cloth_id

    def occluder_mask(self) -> np.ndarray:
        """(H, W) bool, where the last ``render()`` saw a drawn occluder (exact, before noise)."""
        return self._rendered().body_ids == SOLID_ID

    def exact_depth_m(self) -> np.ndarray:
        """(H, W) float32 metres, the depth of the last ``render()`` before noise, 0 where nothing is seen."""
        return self._rendered().depth_m

    def render(self) -> RGBDFrame:
        """The current frame as the sensor sees it (with noise if the scene has it)."""
        solids = self.occluder_mesh_world() if self.draw_occluders else None
        image = self.virtual_camera.render(self.physics, self.spec.texture_rgb, solids=solids)
        self._last_render = image
        rgb, depth = self._sensed(image.rgb, image.depth_m)
        occluder_mask = self.occluder_mask() if self.known_occluders else None
        return RGBDFrame(rgb=rgb, depth_m=depth, camera=self.camera, timestamp_s=self.time_s, seq=self.frame_index,
                         occluder_mask=occluder_mask)

    def frames(self, n: int | None = None):
        """Yield ``n`` frames (default: the script's ``n_frames``) from the current one on
        (render, then step between frames)."""
        for i in range(self.n_frames if n is None else int(n)):
            if i:
                self.step()
            yield self.render()


def _factory(name: str, build: Callable[[np.random.Generator, CameraInfo], SceneSpec]):
    def make(seed: int = 0, noise: bool = True, width: int = 640, height: int = 480, occluders: bool = True,
             known_occluders: bool = False) -> ClothScene:
        return ClothScene(name, build, seed=seed, noise=noise, width=width, height=height, occluders=occluders,
                          known_occluders=known_occluders)

    make.__name__ = name
    make.__doc__ = f"The ``{name}`` scene, reset to frame 0. {build.__doc__.splitlines()[0]}"
    return make


poster_bend = _factory("poster_bend", poster_bend_spec)
shirt_chair = _factory("shirt_chair", shirt_chair_spec)
shirt_textureless_rotate = _factory("shirt_textureless_rotate", shirt_textureless_rotate_spec)
towel_sway = _factory("towel_sway", towel_sway_spec)
occluder_sweep = _factory("occluder_sweep", occluder_sweep_spec)
occluder_close = _factory("occluder_close", occluder_close_spec)
occluder_plain = _factory("occluder_plain", occluder_plain_spec)
occluder_near_camera = _factory("occluder_near_camera", occluder_near_camera_spec)
gripper_corner_move = _factory("gripper_corner_move", gripper_corner_move_spec)
table_lift = _factory("table_lift", table_lift_spec)

SCENES: dict[str, Callable[..., ClothScene]] = {
    "poster_bend": poster_bend,
    "shirt_chair": shirt_chair,
    "shirt_textureless_rotate": shirt_textureless_rotate,
    "towel_sway": towel_sway,
    "occluder_sweep": occluder_sweep,
    "occluder_close": occluder_close,
    "occluder_plain": occluder_plain,
    "occluder_near_camera": occluder_near_camera,
    "gripper_corner_move": gripper_corner_move,
    "table_lift": table_lift,
}
#: The paper's experiments (``launch_scripts.evaluate``'s first table).
PAPER_SCENES = ("poster_bend", "shirt_chair", "shirt_textureless_rotate", "towel_sway")
#: A cloth handled, with an occluder drawn in front of it (the "Tracking while handled" table).
HANDLED_SCENES = ("occluder_sweep", "gripper_corner_move", "table_lift")
#: More handled scenes, run when named (``launch_scripts.evaluate --handled --scenes NAME``).
MORE_HANDLED_SCENES = ("occluder_close", "occluder_plain", "occluder_near_camera")


def make_scene(name: str, seed: int = 0, noise: bool = True, width: int = 640, height: int = 480,
               occluders: bool = True, known_occluders: bool = False) -> ClothScene:
    """Build the registered scene ``name`` (see ``SCENES``), reset to frame 0.

    occluders : draw the scene's occluders (False: its twin without them)
    known_occluders : frames carry the exact occluder mask (``RGBDFrame.occluder_mask``)
    """
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; expected one of {', '.join(sorted(SCENES))}")
    return SCENES[name](seed=seed, noise=noise, width=width, height=height, occluders=occluders,
                        known_occluders=known_occluders)
