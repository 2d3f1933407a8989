"""Laundry-grasping trial scenes: a towel or T-shirt on a table (or held up by a corner).

A scene has two halves, as ``sim.scenes``: ``LaundrySpec`` (pure data drawn from a seed
by ``laundry_spec``) and ``LaundryScene``, which builds the PyBullet world from it,
drops and settles the cloth, renders noisy RGB-D frames and answers ground-truth
questions (where the true corners and the outline of the cloth are).

What a seed draws (``laundry_spec``):

- cloth: a towel (rectangle 0.35-0.60 m by 0.30-0.50 m) or a T-shirt (the default
  ``TShirtShape`` scaled by 0.60-0.85), printed (poster texture) or plain coloured;
- initial state (``INITIAL_STATES``): ``flat`` (laid flat at a random yaw and dropped
  from a few centimetres), ``crumpled`` (dropped edge first from 10-25 cm in a pose
  tilted by 35-75 degrees; it lands shifted and creased, mostly spread: PyBullet's
  cloth has little bending stiffness), ``folded`` (a straight fold: the part of the
  cloth beyond a random row or column of its vertices is turned over before the
  drop), or ``held`` (hanging from a holder that clamps one true
  corner, its lowest point above the table; the holder is a visible box around that
  corner, which it hides as a hand would; the cloth falls into its folds for 5 s and is
  then brought to rest, as air drag, which PyBullet lacks, would do);
- the cloth's layers collide with each other (``ClothMaterial.self_collision``): a fold
  or a crumple stacks its layers, each 12 mm (twice the collision margin) above the one
  below, rather than letting them pass into one plane, so a fold stands thicker than
  one layer as a real one does;
- table: top 0.70-0.78 m above the floor, 1.2 m x 0.8 m, neutral grey;
- camera: 1.0-1.3 m from the cloth, 50-70 degrees above the horizontal, azimuth within
  20 degrees of the table's front (-y), aim jittered by a few centimetres; Kinect-like
  intrinsics, sensor noise on by default (``sim.noise``).

Ground truth (material coordinates ``uv_m`` of ``sim.cloth_mesh``, metres on the flat
cloth): the true corners (a towel's four corners; a T-shirt's hem corners and the two
corners of each sleeve end, taken from the ``TShirtShape`` construction, not from mesh
indices) and the material outline (the mesh's boundary edges).

World frame: z up, floor top at z = 0, the table centred on the origin. Camera frame:
OpenCV optical; ``T_world_cam`` (4, 4) maps camera points to the world.
The same seed gives the same scene and the same frames; noise on or off does not
change the scene (independent random streams, as ``sim.scenes``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.geometry import (
    boundary_edges,
    boundary_vertices,
    look_at,
    rotation_about_axis,
    transform_points,
)
from sim.camera import Lighting, VirtualCamera
from sim.cloth_mesh import ClothMesh, TShirtShape, rectangle_cloth, tshirt_cloth
from sim.noise import DepthNoiseModel
from sim.physics import ClothMaterial, ClothPhysics, Gripper
from sim.scene import PhysicsScene, check_seed
from sim.scenes import Box, kinect_camera
from sim.textures import plain_texture, poster_texture, random_plain_colour

log = logging.getLogger(__name__)

CLOTH_KINDS = ("towel", "tshirt")
INITIAL_STATES = ("flat", "crumpled", "folded", "held")
#: How often each initial state is drawn, in the order of ``INITIAL_STATES``.
STATE_PROBABILITIES = (0.35, 0.25, 0.15, 0.25)
#: Spacing of the simulated cloth's grid, metres. Corners are mesh vertices whatever it is.
CLOTH_SPACING_M = 0.03
#: Half extents of the table top (x, y), metres, and its thickness.
TABLE_HALF_XY_M = (0.60, 0.40)
TABLE_THICKNESS_M = 0.04
#: The holder of a ``held`` cloth clamps the nodes within this radius of its corner (the
#: corner node and its grid neighbours): pinned by one node, the cloth spins about it.
HOLDER_RADIUS_M = 0.045
#: Half extents of the holder's visible body (a closed gripper's fingers around the corner), metres.
HOLDER_HALF_EXTENTS_M = (0.025, 0.025, 0.04)


# ----------------------------------------------------------------------------- ground truth (pure)


def rectangle_corners_uv(width_m: float, height_m: float) -> tuple[np.ndarray, tuple]:
    """The four corners of a ``rectangle_cloth`` in material coordinates.

    returns corners (4, 2) float64 metres (u right, v down from the top-left) and their
    names ``("top_left", "top_right", "bottom_right", "bottom_left")``
    """
    w, h = float(width_m), float(height_m)
    corners = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    return corners, ("top_left", "top_right", "bottom_right", "bottom_left")


def tshirt_corners_uv(shape: TShirtShape) -> tuple[np.ndarray, tuple]:
    """Hem corners and sleeve-end corners of a ``tshirt_cloth(shape)`` in material coordinates.

    The points come from the outline's construction (``TShirtShape.outline`` lists the
    neck, then the right shoulder, cuff top, cuff bottom, armpit and hem, then the same
    on the left in reverse), shifted as ``tshirt_cloth`` shifts the outline so that its
    bounding box starts at (0, 0). The neck's corners are left out: a neck opening is
    not what a laundry robot calls a corner of a shirt.

    returns corners (6, 2) float64 metres and their names
    """
    outline = shape.outline()
    n_neck = len(outline) - 10
    key = outline[n_neck:] - outline.min(axis=0)
    # key rows: 0 right shoulder, 1 right cuff top, 2 right cuff bottom, 3 right armpit,
    # 4 right hem, 5 left hem, 6 left armpit, 7 left cuff bottom, 8 left cuff top, 9 left shoulder
    rows = (1, 2, 4, 5, 7, 8)
    names = ("right_cuff_top", "right_cuff_bottom", "right_hem", "left_hem", "left_cuff_bottom", "left_cuff_top")
    return key[list(rows)].astype(np.float64), names


def distance_to_segments(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distance of 2D points to the nearest of a set of segments (an outline).

    points : (N, 2) float, metres; segments : (E, 2, 2) float, metres, (start, end) each
    returns (N,) float64 metres
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    a, ab = seg[:, 0], seg[:, 1] - seg[:, 0]
    ap = pts[:, None, :] - a[None]
    t = np.clip(np.sum(ap * ab[None], axis=2) / np.maximum(np.sum(ab * ab, axis=1), 1e-300)[None], 0.0, 1.0)
    return np.min(np.linalg.norm(ap - t[..., None] * ab[None], axis=2), axis=1)


def nearest_corner(uv: np.ndarray, corners_uv: np.ndarray) -> tuple[int, float]:
    """Index of the corner nearest to a material point and the distance to it.

    uv : (2,) float metres; corners_uv : (C, 2) float metres, C >= 1
    returns (index, distance in metres)
    """
    d = np.linalg.norm(np.asarray(corners_uv, dtype=np.float64) - np.asarray(uv, dtype=np.float64).reshape(1, 2), axis=1)
    k = int(np.argmin(d))
    return k, float(d[k])


# ----------------------------------------------------------------------------- spec (pure data)


@dataclass(frozen=True)
class LaundrySpec:
    """Everything a laundry scene needs, as data (see the module docstring).

    seed : the seed it was drawn from
    cloth_kind : "towel" or "tshirt"; cloth : ClothMesh; printed : texture is a print
    texture_rgb : (Ht, Wt, 3) uint8 spanning the cloth's bounding box
    material : ClothMaterial
    corners_uv : (C, 2) float64 metres, the true corners; corner_names : C names
    outline_edges : (E, 2) int64 vertex ids of the edges of the material outline
    state : one of ``INITIAL_STATES``
    cloth_vertices_world : (V, 3) float64 metres, where the cloth starts before settling
    holder_vertex : cloth vertex pinned by the holder (``held`` only), else None
    holder_position : (3,) float64 metres, world, where the holder stays (``held`` only)
    table_top_z : float metres; boxes : the floor and the table (``sim.scenes.Box``)
    camera : CameraInfo; T_world_cam : (4, 4) float64, optical camera frame to world
    settle_s : simulated seconds the cloth falls and settles before frame 0
    rest_s : simulated seconds after ``settle_s`` in which the cloth is brought to rest
        (``ClothPhysics.settle_to_rest``): a hanging cloth, which PyBullet would leave
        swinging (no air drag); 0 for a cloth on the table, which friction stops
    timestep_s : the step the cloth's springs are made for (``ClothMaterial``)
    substeps : physics steps per ``timestep_s``: the same cloth, integrated more finely.
        At 1/240 s, with layers that collide, a cloth dropped onto the table passed
        partly through it in 2 of 17 crumpled scenes (even seeds 0-30 and seed 235; none
        at 1/480 s, nor in 16 folded scenes), and a held cloth let go by its holder blew
        apart falling onto itself in 1 of 32 hand-overs (even seeds 0-62; none with the
        hand-over at 1/480 s). The price, besides time: at 1/480 s a held T-shirt whose
        layers touch does not come fully to rest; its lower part creeps on at up to
        ~5 cm/s (a towel stays still).
    """

    seed: int
    cloth_kind: str
    cloth: ClothMesh
    printed: bool
    texture_rgb: np.ndarray
    material: ClothMaterial
    corners_uv: np.ndarray
    corner_names: tuple
    outline_edges: np.ndarray
    state: str
    cloth_vertices_world: np.ndarray
    holder_vertex: int | None
    holder_position: np.ndarray | None
    table_top_z: float
    boxes: tuple
    camera: CameraInfo
    T_world_cam: np.ndarray
    settle_s: float
    rest_s: float = 0.0
    timestep_s: float = 1.0 / 240.0
    substeps: int = 2
    lighting: Lighting = field(default_factory=Lighting)

    @property
    def outline_uv(self) -> np.ndarray:
        """(E, 2, 2) float64 metres: the material outline as segments (start, end)."""
        return self.cloth.uv_m[self.outline_edges]

    @property
    def table_half_xy(self) -> tuple[float, float]:
        return TABLE_HALF_XY_M

    def describe(self) -> str:
        """One line: what the seed drew."""
        w, h = self.cloth.size_m
        texture = "printed" if self.printed else "plain"
        return f"seed {self.seed}: {texture} {self.cloth_kind} {w:.2f}x{h:.2f} m, {self.state}"


def _flat_on_table(mesh: ClothMesh, yaw_rad: float, height_m: float) -> np.ndarray:
    """(V, 3) the flat cloth, front up, centred over the origin at ``height_m``, turned by ``yaw_rad``."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    right, down = np.array([c, s, 0.0]), np.array([s, -c, 0.0])  # front faces down x right = +z
    centre_uv = 0.5 * (mesh.uv_m.min(axis=0) + mesh.uv_m.max(axis=0))
    return mesh.layout_points(np.array([0.0, 0.0, height_m]) - centre_uv[0] * right - centre_uv[1] * down, right, down)


def _fold(mesh: ClothMesh, points: np.ndarray, rng: np.random.Generator, layer_m: float) -> np.ndarray:
    """Turn the part of a flat, front-up cloth beyond a straight line over onto the rest.

    PyBullet takes the springs' rest lengths from the initial shape, and an edge that
    crosses the fold line comes out shorter, down to nothing (a collapsed spring stalls
    its solver). So the line runs through a row or column of the mesh's vertices (u or
    v constant): on a towel's grid no edge crosses it and the fold keeps every length;
    on a T-shirt's lattice a few outline edges change, and lines that change any edge
    by more than -40 % / +40 % are rejected. Among the lines leaving 15-45 % of the
    vertices beyond, one is drawn at random; the vertices beyond it are mirrored about
    it in the cloth's plane and lifted by ``layer_m`` so the flap starts above the rest.
    points : (V, 3) flat placement (z constant), ``mesh.layout_points`` of a rotation;
    returns (V, 3)
    """
    uv = mesh.uv_m
    candidates = []
    for axis in (0, 1):
        values, counts = np.unique(uv[:, axis], return_counts=True)
        for value in values[counts >= 4]:  # a line through a whole row (column) of vertices
            for side in (1.0, -1.0):
                beyond = side * (uv[:, axis] - value) > 1e-9
                if 0.15 <= beyond.mean() <= 0.45:
                    candidates.append((axis, value, beyond))
    edges, rest = mesh.edges(), mesh.rest_lengths()
    # The flat placement is an affine image of uv (a rotation and a shift): map mirrored uv alike.
    affine = np.linalg.lstsq(np.column_stack([uv, np.ones(len(uv))]), points, rcond=None)[0]
    for k in rng.permutation(len(candidates)):
        axis, value, beyond = candidates[k]
        folded_uv = uv.copy()
        folded_uv[beyond, axis] = 2.0 * value - uv[beyond, axis]
        out = np.column_stack([folded_uv, np.ones(len(uv))]) @ affine
        out[beyond, 2] += layer_m
        stretch = np.linalg.norm(out[edges[:, 0]] - out[edges[:, 1]], axis=1) / rest
        if stretch.min() > 0.6 and stretch.max() < 1.4:  # a little pucker at the fold, no collapsed spring
            return out
    raise ValueError(f"no fold line of {mesh.name} keeps its edges' lengths")


def _camera_pose(rng: np.random.Generator, target: np.ndarray) -> np.ndarray:
    """T_world_cam looking down at ``target`` from 1.0-1.3 m, 50-70 deg elevation, front side, jittered."""
    distance = rng.uniform(1.0, 1.3)
    elevation = np.radians(rng.uniform(50.0, 70.0))
    azimuth = np.radians(-90.0 + rng.uniform(-20.0, 20.0))  # -90 deg: the camera on the -y side
    eye = target + distance * np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                        np.sin(elevation)])
    return look_at(eye, target + rng.uniform(-0.03, 0.03, 3))


def _texture(mesh: ClothMesh, rng: np.random.Generator, printed: bool, px_per_m: float = 900.0) -> np.ndarray:
    if not printed:
        return plain_texture(random_plain_colour(rng))
    width, height = mesh.size_m
    area = width * height
    return poster_texture(rng, round(width * px_per_m), round(height * px_per_m),
                          n_shapes=max(20, int(120 * area / 0.27)), n_words=max(3, int(10 * area / 0.27)))


def laundry_spec(seed: int, camera: CameraInfo | None = None, state: str | None = None,
                 cloth_kind: str | None = None) -> LaundrySpec:
    """Draw a laundry scene from ``seed`` (see the module docstring).

    camera : CameraInfo, default Kinect-like 640x480
    state, cloth_kind : force the initial state or cloth kind (tests, demonstrations);
        everything else is still drawn from the seed
    """
    seed = check_seed(seed)
    if state is not None and state not in INITIAL_STATES:
        raise ValueError(f"unknown initial state {state!r}; expected one of {', '.join(INITIAL_STATES)}")
    if cloth_kind is not None and cloth_kind not in CLOTH_KINDS:
        raise ValueError(f"unknown cloth kind {cloth_kind!r}; expected one of {', '.join(CLOTH_KINDS)}")
    camera = camera if camera is not None else kinect_camera(640, 480)
    scene_seq, _ = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(scene_seq)

    drawn_kind = CLOTH_KINDS[int(rng.integers(0, len(CLOTH_KINDS)))]
    drawn_state = INITIAL_STATES[int(rng.choice(len(INITIAL_STATES), p=STATE_PROBABILITIES))]
    kind = cloth_kind or drawn_kind
    state = state or drawn_state
    printed = bool(rng.random() < 0.5)
    size_draw = rng.uniform(0.0, 1.0, 2)
    if kind == "towel":
        width, height = 0.35 + 0.25 * size_draw[0], 0.30 + 0.20 * size_draw[1]
        mesh = rectangle_cloth(width, height, spacing_m=CLOTH_SPACING_M)
        corners_uv, names = rectangle_corners_uv(width, height)
        material = ClothMaterial(mass_per_area_kg_m2=0.3, self_collision=True)
    else:
        shape = TShirtShape().scaled(0.60 + 0.25 * size_draw[0])
        mesh = tshirt_cloth(shape, spacing_m=CLOTH_SPACING_M)
        corners_uv, names = tshirt_corners_uv(shape)
        material = ClothMaterial(mass_per_area_kg_m2=0.18, self_collision=True)
    texture = _texture(mesh, rng, printed)
    table_top = rng.uniform(0.70, 0.78)
    grey = rng.uniform(0.55, 0.70)
    boxes = (
        Box((3.0, 3.0, 0.01), (0.0, 0.0, -0.01), (0.42, 0.40, 0.37, 1.0)),
        Box((TABLE_HALF_XY_M[0], TABLE_HALF_XY_M[1], 0.5 * TABLE_THICKNESS_M),
            (0.0, 0.0, table_top - 0.5 * TABLE_THICKNESS_M), (grey, grey, grey + 0.02, 1.0)),
    )

    yaw = rng.uniform(0.0, 2.0 * np.pi)
    holder_vertex, holder_position, rest_s = None, None, 0.0
    target = np.array([0.0, 0.0, table_top])
    if state == "flat":
        tilt = rotation_about_axis(np.array([np.cos(yaw), np.sin(yaw), 0.0]), np.radians(rng.uniform(-4.0, 4.0)))
        flat = _flat_on_table(mesh, yaw, 0.0)
        verts = flat @ tilt.T + [0.0, 0.0, table_top + 0.03 + rng.uniform(0.0, 0.03)]
        settle_s = 1.0
    elif state == "crumpled":
        flat = _flat_on_table(mesh, yaw, 0.0)
        axis_angle = rng.uniform(0.0, np.pi)
        tilt = rotation_about_axis(np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0]),
                                   np.radians(rng.uniform(35.0, 75.0)))
        verts = flat @ tilt.T
        verts[:, 2] += table_top + rng.uniform(0.10, 0.25) - verts[:, 2].min()
        settle_s = 2.0
    elif state == "folded":
        flat = _flat_on_table(mesh, yaw, 0.0)
        verts = _fold(mesh, flat, rng, layer_m=0.012) + [0.0, 0.0, table_top + 0.02]
        settle_s = 1.2
    else:  # held: hanging from one true corner over the table
        k = int(rng.integers(0, len(corners_uv)))
        holder_vertex = int(np.argmin(np.linalg.norm(mesh.uv_m - corners_uv[k], axis=1)))
        # Lay the cloth in a vertical plane facing the camera's side, turned so that the
        # held corner is on top and the cloth's centre straight below it.
        facing = np.radians(-90.0 + rng.uniform(-40.0, 40.0))
        normal = np.array([np.cos(facing), np.sin(facing), 0.0])
        side = np.cross([0.0, 0.0, 1.0], normal)
        centre_uv = mesh.uv_m.mean(axis=0)
        d = centre_uv - mesh.uv_m[holder_vertex]
        d /= np.linalg.norm(d)
        rot = np.array([[d[1], -d[0]], [d[0], d[1]]])  # turns d onto (0, 1), "down" in uv
        uv = (mesh.uv_m - mesh.uv_m[holder_vertex]) @ rot.T
        hang = uv[:, 1].max()
        top = table_top + hang + rng.uniform(0.05, 0.15)
        verts = np.array([0.0, 0.0, top]) + uv[:, :1] * side[None] - uv[:, 1:2] * np.array([[0.0, 0.0, 1.0]])
        holder_position = verts[holder_vertex].copy()
        target = np.array([0.0, 0.0, top - 0.5 * hang])
        # PyBullet cloth has no air drag: a hanging cloth still swings at 0.1-0.4 m/s after
        # 5 s. It falls into its folds freely, then is brought to rest as air would do.
        settle_s, rest_s = 5.0, 2.0
    T_world_cam = _camera_pose(rng, target)
    return LaundrySpec(
        seed=seed, cloth_kind=kind, cloth=mesh, printed=printed, texture_rgb=texture, material=material,
        corners_uv=corners_uv, corner_names=names, outline_edges=boundary_edges(mesh.faces), state=state,
        cloth_vertices_world=verts, holder_vertex=holder_vertex, holder_position=holder_position,
        table_top_z=float(table_top), boxes=boxes, camera=camera, T_world_cam=T_world_cam, settle_s=settle_s,
        rest_s=rest_s,
    )


# ----------------------------------------------------------------------------- scene (PyBullet)


class LaundryScene(PhysicsScene):
    """A laundry scene running in PyBullet: settled cloth, table, camera with noise.

    spec : LaundrySpec (``laundry_spec(seed)``)
    noise : add sensor noise to rendered frames (its random stream comes from the seed)
    noise_model : DepthNoiseModel, Kinect-like by default

    A ``sim.scene.Scene``. After construction (and ``reset``) the cloth has settled for
    ``spec.settle_s`` (and been brought to rest for ``spec.rest_s``): frame 0. ``step()``
    advances one frame, ``render()`` returns what the sensor sees now, ``render_empty()``
    the same view without the cloth (a reference picture of the empty table), and the
    accessors below give the ground truth. Use as a context manager or call ``close()``.
    """

    def __init__(self, spec: LaundrySpec, noise: bool = True, noise_model: DepthNoiseModel | None = None):
        self.spec = spec
        self.name = f"laundry:{spec.seed}"
        self.noise = bool(noise)
        self.noise_model = noise_model or DepthNoiseModel()
        self.camera = spec.camera
        self.T_world_cam = np.asarray(spec.T_world_cam, dtype=np.float64)
        if isinstance(spec.substeps, bool) or int(spec.substeps) != spec.substeps or spec.substeps < 1:
            raise ValueError(f"LaundryScene: expected spec.substeps a positive integer, got {spec.substeps!r}")
        self.physics: ClothPhysics | None = None
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

    def release_holder(self) -> None:
        """The holder of a ``held`` cloth lets go (nothing happens for other states)."""
        if self.holder is not None:
            self.holder.open()

    # -- sensor -------------------------------------------------------------------------------

    def _frame(self, rgb: np.ndarray, depth: np.ndarray) -> RGBDFrame:
        rgb, depth = self._sensed(rgb, depth)
        return RGBDFrame(rgb=rgb, depth_m=depth, camera=self.camera, timestamp_s=self.time_s, seq=self.frame_index)

    def render(self) -> RGBDFrame:
        """The current frame as the sensor sees it (with noise if the scene has it)."""
        image = self.virtual_camera.render(self.physics, self.spec.texture_rgb)
        self._last_mask = image.body_ids == self.cloth_id
        return self._frame(image.rgb, image.depth_m)

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
