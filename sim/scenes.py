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

World frame: z up, the camera looks roughly along +y at the cloth, which faces -y.
The same seed gives the same frames; noise on or off does not change the scene.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from sim.camera import Lighting, VirtualCamera
from sim.camera_model import look_at
from sim.cloth_mesh import ClothMesh, TShirtShape, rectangle_mesh, tshirt_mesh
from sim.noise import DepthNoiseModel, add_colour_noise, add_depth_noise
from sim.physics import ClothMaterial, ClothPhysics
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
class SceneSpec:
    """Everything a scene needs, as data.

    cloth : ClothMesh; cloth_vertices_world : (V, 3) initial flat placement, metres
    texture_rgb : (H, W, 3) uint8 spanning the cloth's bounding box
    material : ClothMaterial
    boxes : scenery
    grasp_vertices : one cloth vertex id per gripper; each gripper starts there and pins
        the nodes within ``GRASP_RADIUS_M``
    gripper_poses : t (seconds after frame 0) -> one Pose per gripper; at t = 0 the
        positions are those of the grasp vertices
    camera : CameraInfo; T_world_cam : (4, 4) optical frame to world
    settle_s : simulated time before frame 0, grippers still, so the cloth hangs at rest
    timestep_s : physics step, a whole fraction of the 1/30 s frame period
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


def kinect_camera(width: int, height: int) -> CameraInfo:
    """Kinect-like intrinsics (f = 525 px at 640 wide, principal point at the image centre)."""
    if int(width) < 16 or int(height) < 16:
        raise ValueError(f"camera size: expected at least 16x16 pixels, got {width}x{height}")
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


def poster_bend_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A ~0.60 x 0.45 m poster held at its top corners, bent by moving them together and turning them.

    Over a 4 s cycle the corners come 35 % closer, 5 cm towards the camera and turn
    0.6 rad each so the poster curls away from the camera, peaking at t = 2 s (frame 60).
    """
    scale = rng.uniform(0.9, 1.1)
    mesh = rectangle_mesh(0.60 * scale, 0.45 * scale, spacing_m=0.025)
    verts = _hang_facing_camera(mesh, np.array([0.0, 0.0, 1.35]))
    width = mesh.size_m[0]
    grasps = (mesh.landmarks["top_left"], mesh.landmarks["top_right"])
    start = [verts[g] for g in grasps]

    def offsets(t: float) -> list:
        b = _ease(t, 4.0)
        inward, forward, yaw = 0.175 * width * b, -0.05 * b, 0.6 * b
        return [((inward, forward, 0.0), yaw), ((-inward, forward, 0.0), -yaw)]

    return SceneSpec(
        name="poster_bend",
        cloth=mesh,
        cloth_vertices_world=verts,
        texture_rgb=_texture_for(mesh, rng),
        material=ClothMaterial(mass_per_area_kg_m2=0.2),
        boxes=_room(rng, wall_y_m=0.8),
        grasp_vertices=grasps,
        gripper_poses=_two_hand_script(start, offsets),
        camera=camera,
        T_world_cam=_camera_pose(rng, eye=(0.1, -1.1, 1.3), target=(0.0, 0.0, 1.1)),
    )


def _shirt(rng: np.random.Generator) -> ClothMesh:
    return tshirt_mesh(TShirtShape().scaled(rng.uniform(0.9, 1.1)), spacing_m=0.03)


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
    verts = _hang_facing_camera(mesh, np.array([0.0, -0.08, shoulder_z + shoulder_v]))
    grasps = (mesh.landmarks["left_shoulder"], mesh.landmarks["right_shoulder"])
    start = [verts[g] for g in grasps]
    wood = (0.45, 0.3, 0.18, 1.0)
    chair = (
        Box((0.23, 0.02, 0.225), (0.0, 0.02, backrest_top - 0.225), wood),  # backrest, front face at y = 0
        Box((0.23, 0.22, 0.02), (0.0, 0.24, 0.45), wood),  # seat, behind the backrest
    ) + tuple(Box((0.02, 0.02, 0.215), (x, y, 0.215), wood) for x in (-0.21, 0.21) for y in (0.02, 0.44))

    def offsets(t: float) -> list:
        back = 0.28 * min(t / 1.0, 1.0)
        down = 0.60 * np.clip((t - 1.0) / 1.0, 0.0, 1.0)
        return [((0.0, back, -down), 0.0)] * 2

    return SceneSpec(
        name="shirt_chair",
        cloth=mesh,
        cloth_vertices_world=verts,
        texture_rgb=_texture_for(mesh, rng),
        material=ClothMaterial(mass_per_area_kg_m2=0.18),
        boxes=_room(rng, wall_y_m=1.2) + chair,
        grasp_vertices=grasps,
        gripper_poses=_two_hand_script(start, offsets),
        camera=camera,
        T_world_cam=_camera_pose(rng, eye=(0.0, -1.3, 1.35), target=(0.0, 0.0, 0.95)),
    )


def shirt_textureless_rotate_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A plain-coloured T-shirt held by the shoulders, turned out of the image plane.

    Both holders turn about the vertical line through the shirt's centre, up to 1 rad
    at t = 2 s (frame 60) and back by t = 4 s.
    """
    mesh = _shirt(rng)
    shoulder_v = mesh.uv_m[mesh.landmarks["left_shoulder"], 1]
    verts = _hang_facing_camera(mesh, np.array([0.0, 0.0, 1.45 + shoulder_v]))
    grasps = (mesh.landmarks["left_shoulder"], mesh.landmarks["right_shoulder"])
    start = [verts[g] for g in grasps]
    axis = 0.5 * (start[0] + start[1])

    def offsets(t: float) -> list:
        yaw = 1.0 * _ease(t, 4.0)
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return [(rot @ (p0 - axis) + axis - p0, yaw) for p0 in start]

    colour = random_plain_colour(rng)
    return SceneSpec(
        name="shirt_textureless_rotate",
        cloth=mesh,
        cloth_vertices_world=verts,
        texture_rgb=plain_texture(colour),
        material=ClothMaterial(mass_per_area_kg_m2=0.18),
        boxes=_room(rng, wall_y_m=0.7),
        grasp_vertices=grasps,
        gripper_poses=_two_hand_script(start, offsets),
        camera=camera,
        T_world_cam=_camera_pose(rng, eye=(0.0, -1.25, 1.3), target=(0.0, 0.0, 1.1)),
    )


def towel_sway_spec(rng: np.random.Generator, camera: CameraInfo) -> SceneSpec:
    """A ~0.6 m wide printed towel hanging from two grippers at its top corners, seen from ~1.3 m.

    The grippers sway sideways (0.12 m, 2 s period) and back and forth (4 cm, 1.5 s),
    and come up to 40 % closer over a 4 s cycle, so the towel swings and folds.
    """
    scale = rng.uniform(0.9, 1.1)
    mesh = rectangle_mesh(0.60 * scale, 0.50 * scale, spacing_m=0.025)
    verts = _hang_facing_camera(mesh, np.array([0.0, 0.0, 1.4]))
    width = mesh.size_m[0]
    grasps = (mesh.landmarks["top_left"], mesh.landmarks["top_right"])
    start = [verts[g] for g in grasps]

    def offsets(t: float) -> list:
        sway = 0.12 * np.sin(2.0 * np.pi * t / 2.0)
        depth = 0.04 * np.sin(2.0 * np.pi * t / 1.5)
        inward = 0.2 * width * _ease(t, 4.0)
        return [((sway + inward, depth, 0.0), 0.0), ((sway - inward, depth, 0.0), 0.0)]

    return SceneSpec(
        name="towel_sway",
        cloth=mesh,
        cloth_vertices_world=verts,
        texture_rgb=_texture_for(mesh, rng),
        material=ClothMaterial(mass_per_area_kg_m2=0.3),
        boxes=_room(rng, wall_y_m=None),
        grasp_vertices=grasps,
        gripper_poses=_two_hand_script(start, offsets),
        camera=camera,
        T_world_cam=_camera_pose(rng, eye=(0.0, -1.3, 1.25), target=(0.0, 0.0, 1.15)),
    )


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"ClothScene: expected a non-negative integer seed, got {seed!r}")
    return int(seed)


class ClothScene:
    """A scene running in PyBullet: physics, grippers following the script, camera, noise.

    name : key in ``SCENES``; build : (Generator, CameraInfo) -> SceneSpec
    seed : int; the scene (sizes, texture, camera jitter) and the noise draw from
        independent streams of it, so ``noise=False`` shows the same scene exactly
    noise : add sensor noise (``sim.noise``) to rendered frames
    width, height : image size in pixels (intrinsics scale with the width)

    After construction (and ``reset``) the world is at frame 0. ``step()`` advances one
    frame (1/30 s); ``render()`` returns the current frame as an RGBDFrame;
    ``cloth_vertices_cam()`` is the ground truth for it.
    """

    def __init__(self, name: str, build: Callable[[np.random.Generator, CameraInfo], SceneSpec], seed: int = 0,
                 noise: bool = True, width: int = 640, height: int = 480,
                 noise_model: DepthNoiseModel | None = None):
        self.name = name
        self._build = build
        self.noise = bool(noise)
        self.noise_model = noise_model or DepthNoiseModel()
        self.camera = kinect_camera(width, height)
        self.fps = FPS
        self.physics: ClothPhysics | None = None
        self.seed = _check_seed(seed)
        self.reset()

    def __enter__(self) -> ClothScene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.physics is not None:
            self.physics.close()
            self.physics = None

    def reset(self, seed: int | None = None) -> None:
        """Rebuild the world from ``seed`` (default: the last seed) and settle it to frame 0."""
        if seed is not None:
            self.seed = _check_seed(seed)
        scene_seq, noise_seq = np.random.SeedSequence(self.seed).spawn(2)
        self.spec = self._build(np.random.default_rng(scene_seq), self.camera)
        self._noise_rng = np.random.default_rng(noise_seq)
        self.close()
        spec = self.spec
        self.physics = ClothPhysics(timestep_s=spec.timestep_s)
        for box in spec.boxes:
            self.physics.add_box(box.half_extents_m, box.position, box.quat_xyzw, box.rgba)
        self.cloth_id = self.physics.add_cloth(spec.cloth, spec.cloth_vertices_world, spec.material)
        for vertex in spec.grasp_vertices:
            at = spec.cloth_vertices_world[vertex]
            gripper = self.physics.add_gripper(at)
            gripper.close_on(self.physics.nodes_near(at, GRASP_RADIUS_M))
        self.virtual_camera = VirtualCamera(self.camera, spec.T_world_cam, lighting=spec.lighting)
        self.physics.advance(spec.settle_s)
        self.frame_index = 0
        self._last_mask = None

    @property
    def time_s(self) -> float:
        """Time of the current frame, seconds after frame 0."""
        return self.frame_index / self.fps

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 cloth faces, counter-clockwise seen from the cloth's front."""
        return self.spec.cloth.faces

    @property
    def uv_m(self) -> np.ndarray:
        """(V, 2) float64 material coordinates of the cloth vertices, metres (``ClothMesh.uv_m``)."""
        return self.spec.cloth.uv_m

    def step(self) -> None:
        """Advance one frame period, grippers moving to the script's poses for the next frame."""
        t_next = (self.frame_index + 1) / self.fps
        for gripper, (position, quat) in zip(self.physics.grippers, self.spec.gripper_poses(t_next)):
            gripper.move_to(position, quat)
        self.physics.advance(1.0 / self.fps)
        self.frame_index += 1

    def cloth_vertices_world(self) -> np.ndarray:
        """(V, 3) float64 cloth vertices now, metres, world frame."""
        return self.physics.cloth_vertices()

    def cloth_vertices_cam(self) -> np.ndarray:
        """(V, 3) float64 cloth vertices now, metres, camera optical frame (the ground truth)."""
        return self.virtual_camera.world_to_camera(self.physics.cloth_vertices())

    def cloth_mask(self) -> np.ndarray:
        """(H, W) bool, where the last ``render()`` saw the cloth (exact, before noise)."""
        if self._last_mask is None:
            raise ValueError("cloth_mask: nothing rendered yet (call render first)")
        return self._last_mask

    def render(self) -> RGBDFrame:
        """The current frame as the sensor sees it (with noise if the scene has it)."""
        image = self.virtual_camera.render(self.physics, self.spec.texture_rgb)
        self._last_mask = image.body_ids == self.cloth_id
        rgb, depth = image.rgb, image.depth_m
        if self.noise:
            depth = add_depth_noise(depth, self.camera.K, self.noise_model, self._noise_rng)
            rgb = add_colour_noise(rgb, self.noise_model.colour_sigma, self._noise_rng)
        return RGBDFrame(rgb=rgb, depth_m=depth, camera=self.camera, timestamp_s=self.time_s, seq=self.frame_index)

    def frames(self, n: int):
        """Yield ``n`` frames from the current one on (render, then step between frames)."""
        for i in range(int(n)):
            if i:
                self.step()
            yield self.render()


def _factory(name: str, build: Callable[[np.random.Generator, CameraInfo], SceneSpec]):
    def make(seed: int = 0, noise: bool = True, width: int = 640, height: int = 480) -> ClothScene:
        return ClothScene(name, build, seed=seed, noise=noise, width=width, height=height)

    make.__name__ = name
    make.__doc__ = f"The ``{name}`` scene, reset to frame 0. {build.__doc__.splitlines()[0]}"
    return make


poster_bend = _factory("poster_bend", poster_bend_spec)
shirt_chair = _factory("shirt_chair", shirt_chair_spec)
shirt_textureless_rotate = _factory("shirt_textureless_rotate", shirt_textureless_rotate_spec)
towel_sway = _factory("towel_sway", towel_sway_spec)

SCENES: dict[str, Callable[..., ClothScene]] = {
    "poster_bend": poster_bend,
    "shirt_chair": shirt_chair,
    "shirt_textureless_rotate": shirt_textureless_rotate,
    "towel_sway": towel_sway,
}


def make_scene(name: str, seed: int = 0, noise: bool = True, width: int = 640, height: int = 480) -> ClothScene:
    """Build the registered scene ``name`` (see ``SCENES``), reset to frame 0."""
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; expected one of {', '.join(sorted(SCENES))}")
    return SCENES[name](seed=seed, noise=noise, width=width, height=height)
