"""What a laundry trial's seed draws (pure data): the cloth, its initial state, the table and the camera.

``laundry_spec(seed)`` draws a ``LaundrySpec`` (see the ``sim.laundry`` package docstring
for what is drawn and why); ``sim.laundry.scene.LaundryScene`` builds the PyBullet world from it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ipc.messages import CameraInfo
from perception.geometry import boundary_edges, look_at, rotation_about_axis
from sim.camera import Lighting
from sim.cloth_mesh import ClothMesh, TShirtShape, rectangle_cloth, tshirt_cloth
from sim.laundry.truth import rectangle_corners_uv, tshirt_corners_uv
from sim.physics import ClothMaterial
from sim.scene import check_seed
from sim.scenes import Box, kinect_camera
from sim.textures import plain_texture, poster_texture, random_plain_colour

log = logging.getLogger(__name__)

CLOTH_KINDS = ("towel", "tshirt")
#: Where the camera stands: "table" looks down at the cloth from close by (the corner
#: task); "room" stands farther back and lower, seeing the table and the space above it,
#: where a lifted cloth hangs (the unfold task).
VIEWS = ("table", "room")
INITIAL_STATES = ("flat", "crumpled", "folded", "held")
#: The initial states with the cloth lying on the table: where the unfold task starts.
TABLE_STATES = ("flat", "crumpled", "folded")
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


def _room_camera_pose(rng: np.random.Generator, table_top_m: float) -> np.ndarray:
    """T_world_cam seeing the table and up to ~1 m above it: 1.55-1.75 m from a point 0.35 m
    over the table's centre, 18-28 deg elevation, azimuth within 15 deg of the front (-y).

    With the Kinect-like intrinsics (vertical field of view about 49 deg) that covers a
    cloth lying on the table and the same cloth hanging from a gripper up to ~0.9 m above it.
    """
    target = np.array([0.0, 0.0, table_top_m + 0.35])
    distance = rng.uniform(1.55, 1.75)
    elevation = np.radians(rng.uniform(18.0, 28.0))
    azimuth = np.radians(-90.0 + rng.uniform(-15.0, 15.0))
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
                 cloth_kind: str | None = None, view: str = "table",
                 states: tuple[str, ...] = INITIAL_STATES) -> LaundrySpec:
    """Draw a laundry scene from ``seed`` (see the module docstring).

    camera : CameraInfo, default Kinect-like 640x480
    state, cloth_kind : force the initial state or cloth kind (tests, demonstrations);
        everything else is still drawn from the seed
    view : where the camera stands (``VIEWS``); the cloth, the table and everything else
        drawn from the seed are the same in every view
    states : the initial states to draw among (a task's own, e.g. ``TABLE_STATES``). A state
        drawn outside them is drawn again among them, by their ``STATE_PROBABILITIES``, from
        a stream of its own: a seed whose state is among them draws the same scene as with
        all states. A forced ``state`` need not be among them.
    """
    seed = check_seed(seed)
    if view not in VIEWS:
        raise ValueError(f"unknown view {view!r}; expected one of {', '.join(VIEWS)}")
    if state is not None and state not in INITIAL_STATES:
        raise ValueError(f"unknown initial state {state!r}; expected one of {', '.join(INITIAL_STATES)}")
    if cloth_kind is not None and cloth_kind not in CLOTH_KINDS:
        raise ValueError(f"unknown cloth kind {cloth_kind!r}; expected one of {', '.join(CLOTH_KINDS)}")
    if not states or len(set(states)) != len(states) or any(s not in INITIAL_STATES for s in states):
        raise ValueError(f"states: expected some of {', '.join(INITIAL_STATES)}, each once, got {states!r}")
    camera = camera if camera is not None else kinect_camera(640, 480)
    # the third stream redraws a state outside ``states``; the first two are as they always were
    scene_seq, _, redraw_seq = np.random.SeedSequence(seed).spawn(3)
    rng = np.random.default_rng(scene_seq)

    drawn_kind = CLOTH_KINDS[int(rng.integers(0, len(CLOTH_KINDS)))]
    drawn_state = INITIAL_STATES[int(rng.choice(len(INITIAL_STATES), p=STATE_PROBABILITIES))]
    if drawn_state not in states:
        p = np.array([STATE_PROBABILITIES[INITIAL_STATES.index(s)] for s in states])
        redraw = np.random.default_rng(redraw_seq)
        drawn_state = states[int(redraw.choice(len(states), p=p / p.sum()))]
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
    # The camera is drawn last, so a view changes nothing else the seed draws.
    T_world_cam = _camera_pose(rng, target) if view == "table" else _room_camera_pose(rng, float(table_top))
    return LaundrySpec(
        seed=seed, cloth_kind=kind, cloth=mesh, printed=printed, texture_rgb=texture, material=material,
        corners_uv=corners_uv, corner_names=names, outline_edges=boundary_edges(mesh.faces), state=state,
        cloth_vertices_world=verts, holder_vertex=holder_vertex, holder_position=holder_position,
        table_top_z=float(table_top), boxes=boxes, camera=camera, T_world_cam=T_world_cam, settle_s=settle_s,
        rest_s=rest_s,
    )
