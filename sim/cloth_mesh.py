"""Flat cloth meshes in their rest layout, generated in code (pure NumPy).

A cloth is a triangle mesh described by its material coordinates ``uv_m``: where each
vertex lies on the flat, unstretched cloth, in metres, with u to the right and v down
from the top-left corner of the cloth's bounding box as seen from its front side. The
same convention as an image seen by a camera facing the cloth (x right, y down), so a
cloth hung flat in front of the camera has camera x ~ u and camera y ~ v.

Faces are ordered counter-clockwise as seen from the front (on screen, v down): their
right-hand normal points towards a viewer of the front side.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import Delaunay

from perception.geometry import check_ids, check_points, unique_edges

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClothMesh:
    """A cloth in its flat rest layout.

    uv_m : (V, 2) float64, metres, material coordinates (u right, v down, origin at the
        top-left of the bounding box, seen from the front)
    faces : (F, 3) int64 vertex ids, counter-clockwise seen from the front
    landmarks : name -> vertex id of named points derived from the geometry
        (``top_left``, ``left_shoulder``, ...); "left" is the smaller u, i.e. the left
        as seen from the front
    name : short description, e.g. ``"rectangle 0.60x0.45 m"``
    """

    uv_m: np.ndarray
    faces: np.ndarray
    landmarks: dict = field(default_factory=dict)
    name: str = ""

    def __post_init__(self):
        uv = check_points("ClothMesh.uv_m", self.uv_m, dim=2)
        faces = check_ids("ClothMesh.faces", self.faces, len(uv), ndim=2, allow_empty=True)
        object.__setattr__(self, "uv_m", uv)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "landmarks", {str(k): int(v) for k, v in dict(self.landmarks).items()})

    @property
    def n_vertices(self) -> int:
        return len(self.uv_m)

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the bounding box in metres."""
        extent = self.uv_m.max(axis=0) - self.uv_m.min(axis=0)
        return float(extent[0]), float(extent[1])

    def edges(self) -> np.ndarray:
        """(E, 2) int64 unique undirected edges, smaller id first."""
        return unique_edges(self.faces)

    def rest_lengths(self) -> np.ndarray:
        """(E,) float64 metres, length of each of ``edges()`` on the flat cloth."""
        e = self.edges()
        return np.linalg.norm(self.uv_m[e[:, 0]] - self.uv_m[e[:, 1]], axis=1)

    def texture_coords(self) -> np.ndarray:
        """(V, 2) float64 in [0, 1], OBJ ``vt`` convention (s right, t up).

        The texture image spans the bounding box: image row 0 is the cloth's top edge.
        """
        width, height = self.size_m
        return np.stack([self.uv_m[:, 0] / width, 1.0 - self.uv_m[:, 1] / height], axis=1)

    def layout_points(self, origin: np.ndarray, right: np.ndarray, down: np.ndarray) -> np.ndarray:
        """Place the flat cloth in 3D: ``origin + u * right + v * down``.

        origin : (3,) float, metres, where the top-left of the bounding box goes
        right, down : (3,) float unit vectors, orthogonal; the front faces ``down x right``
        returns (V, 3) float64, metres
        """
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        right = np.asarray(right, dtype=np.float64).reshape(3)
        down = np.asarray(down, dtype=np.float64).reshape(3)
        if abs(np.linalg.norm(right) - 1) > 1e-9 or abs(np.linalg.norm(down) - 1) > 1e-9 or abs(right @ down) > 1e-9:
            raise ValueError(f"layout_points: right and down must be orthonormal, got {right.tolist()} and {down.tolist()}")
        return origin + self.uv_m[:, :1] * right + self.uv_m[:, 1:] * down


def edge_strain(vertices: np.ndarray, edges: np.ndarray, rest_lengths: np.ndarray) -> np.ndarray:
    """Engineering strain of each edge: current length / rest length - 1.

    vertices : (V, 3) float, metres, any frame
    edges : (E, 2) int vertex ids
    rest_lengths : (E,) float, metres, > 0
    returns (E,) float64, dimensionless (0.02 = stretched by 2 %, negative = compressed)
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"edge_strain: expected vertices of shape (V, 3), got {v.shape}")
    e = np.asarray(edges)
    if e.ndim != 2 or e.shape[1] != 2:
        raise ValueError(f"edge_strain: expected edges of shape (E, 2), got {e.shape}")
    rest = np.asarray(rest_lengths, dtype=np.float64)
    if rest.shape != (len(e),) or np.any(rest <= 0):
        raise ValueError(f"edge_strain: expected {len(e)} positive rest lengths, got shape {rest.shape}")
    return np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1) / rest - 1.0


def _grid_faces(cells_ij: np.ndarray, vertex_id: np.ndarray) -> np.ndarray:
    """Two triangles per grid cell, diagonals alternating in a checkerboard.

    Alternating diagonals keep the mesh free of a preferred shear direction, so the
    cloth folds alike along both diagonals. Triangles are counter-clockwise seen from
    the front (negative 2D cross product in u-right, v-down coordinates).
    """
    i, j = cells_ij[:, 0], cells_ij[:, 1]  # row (v), column (u)
    tl, tr = vertex_id[i, j], vertex_id[i, j + 1]
    bl, br = vertex_id[i + 1, j], vertex_id[i + 1, j + 1]
    even = (i + j) % 2 == 0
    # even cells split along tl-br, odd cells along tr-bl
    t1 = np.where(even[:, None], np.stack([tl, br, tr], 1), np.stack([tl, bl, tr], 1))
    t2 = np.where(even[:, None], np.stack([tl, bl, br], 1), np.stack([tr, bl, br], 1))
    return np.concatenate([t1, t2])


def _grid_mesh(rows: int, cols: int, spacing_u: float, spacing_v: float) -> tuple[np.ndarray, np.ndarray]:
    """(uv_m (V, 2), faces (F, 3)) of a rows x cols grid of cells, vertices row by row from the top-left."""
    grid_id = np.arange((rows + 1) * (cols + 1)).reshape(rows + 1, cols + 1)
    faces = _grid_faces(np.argwhere(np.ones((rows, cols), bool)), grid_id)
    vi, vj = np.divmod(np.arange((rows + 1) * (cols + 1)), cols + 1)
    return np.stack([vj * spacing_u, vi * spacing_v], axis=1).astype(np.float64), faces


def _check_size(name: str, value: float, minimum: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value < minimum:
        raise ValueError(f"{name}: expected a finite value >= {minimum}, got {value}")
    return value


def rectangle_cloth(width_m: float, height_m: float, spacing_m: float = 0.025) -> ClothMesh:
    """A rectangular cloth (poster, towel) as a regular grid.

    width_m, height_m : size in metres
    spacing_m : target edge length in metres; the grid spacing is adjusted so the
        corners fall exactly on the rectangle's corners
    returns ClothMesh with landmarks ``top_left, top_right, bottom_left, bottom_right``
    """
    spacing_m = _check_size("rectangle_cloth: spacing_m", spacing_m, 1e-3)
    width_m = _check_size("rectangle_cloth: width_m", width_m, 2 * spacing_m)
    height_m = _check_size("rectangle_cloth: height_m", height_m, 2 * spacing_m)
    cols = max(1, round(width_m / spacing_m))
    rows = max(1, round(height_m / spacing_m))
    uv, faces = _grid_mesh(rows, cols, width_m / cols, height_m / rows)
    landmarks = {
        "top_left": _nearest(uv, (0.0, 0.0)),
        "top_right": _nearest(uv, (width_m, 0.0)),
        "bottom_left": _nearest(uv, (0.0, height_m)),
        "bottom_right": _nearest(uv, (width_m, height_m)),
    }
    return ClothMesh(uv, faces, landmarks, name=f"rectangle {width_m:.2f}x{height_m:.2f} m")


@dataclass(frozen=True)
class TShirtShape:
    """Outline of a T-shirt front seen flat, in metres.

    body_width_m, body_length_m : chest width and shoulder-to-hem length
    sleeve_length_m, sleeve_opening_m : along the sleeve's top edge, and across its end
    sleeve_angle_rad : how far the sleeves point below horizontal
    neck_width_m, neck_depth_m : the neck opening cut into the top edge
    shoulder_drop_m : how much lower the shoulder tip is than the neck
    """

    body_width_m: float = 0.50
    body_length_m: float = 0.70
    sleeve_length_m: float = 0.20
    sleeve_opening_m: float = 0.17
    sleeve_angle_rad: float = np.radians(30.0)
    neck_width_m: float = 0.18
    neck_depth_m: float = 0.07
    shoulder_drop_m: float = 0.04

    def scaled(self, factor: float) -> TShirtShape:
        """The same shape with every length multiplied by ``factor``."""
        return TShirtShape(
            body_width_m=self.body_width_m * factor,
            body_length_m=self.body_length_m * factor,
            sleeve_length_m=self.sleeve_length_m * factor,
            sleeve_opening_m=self.sleeve_opening_m * factor,
            sleeve_angle_rad=self.sleeve_angle_rad,
            neck_width_m=self.neck_width_m * factor,
            neck_depth_m=self.neck_depth_m * factor,
            shoulder_drop_m=self.shoulder_drop_m * factor,
        )

    def outline(self, n_neck: int = 9) -> np.ndarray:
        """(n_neck + 10, 2) float64 closed polygon (last point not repeated), metres, (u, v)
        with the neck centre's top at u = 0, v = 0, clockwise on screen (v down): the
        neck's ``n_neck`` points left to right, then right shoulder, right cuff (top,
        bottom), right armpit, right hem, left hem, left armpit, left cuff (bottom, top),
        left shoulder."""
        half_w = 0.5 * self.body_width_m
        a = self.sleeve_angle_rad
        along = np.array([np.cos(a), np.sin(a)])  # right sleeve direction (out, down)
        across = np.array([-np.sin(a), np.cos(a)])  # from the sleeve's top edge to its bottom edge
        shoulder = np.array([half_w, self.shoulder_drop_m])
        cuff_top = shoulder + self.sleeve_length_m * along
        cuff_bottom = cuff_top + self.sleeve_opening_m * across
        # the underside of the sleeve runs parallel to its top edge back to the body side
        t = (cuff_bottom[0] - half_w) / along[0]
        armpit = cuff_bottom - t * along
        if armpit[1] >= self.body_length_m:
            raise ValueError("TShirtShape: the sleeves reach below the hem; shorten or raise them")
        right = [shoulder, cuff_top, cuff_bottom, armpit, np.array([half_w, self.body_length_m])]
        left = [p * np.array([-1.0, 1.0]) for p in reversed(right)]
        # neck: half-ellipse from the left neck point down through (0, depth) to the right
        angles = np.linspace(np.pi, 0.0, n_neck)
        neck = np.stack([0.5 * self.neck_width_m * np.cos(angles), self.neck_depth_m * np.sin(angles)], axis=1)
        return np.concatenate([neck, np.array(right), np.array(left)])


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd test of each point against a closed polygon.

    points : (N, 2) float; polygon : (P, 2) float, closing edge implied
    returns (N,) bool, True inside
    """
    pts = check_points("points", points, dim=2)
    poly = check_points("polygon", polygon, dim=2)
    a = poly
    b = np.roll(poly, -1, axis=0)
    x, y = pts[:, :1], pts[:, 1:]
    # does the horizontal ray to +x from each point cross edge a-b?
    straddles = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    crossings = straddles & (x < x_cross)
    return (crossings.sum(axis=1) % 2) == 1


def _signed_areas(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) signed area in the (u, v) plane; negative = counter-clockwise seen from the front."""
    p0, p1, p2 = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    d1, d2 = p1 - p0, p2 - p0
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def _resample_outline(polygon: np.ndarray, spacing_m: float) -> np.ndarray:
    """Points along the closed polygon, every polygon corner kept, edges split into
    equal pieces no longer than ``spacing_m``; (P', 2) float64."""
    out = []
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing_m)))
        t = np.arange(n)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def _distance_to_outline(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(N,) float64 distance of each point to the closed polygon's outline."""
    a = polygon[None, :, :]
    ab = np.roll(polygon, -1, axis=0)[None] - a
    ap = points[:, None, :] - a
    t = np.clip(np.sum(ap * ab, axis=2) / np.sum(ab * ab, axis=2), 0.0, 1.0)
    return np.min(np.linalg.norm(ap - t[..., None] * ab, axis=2), axis=1)


def tshirt_cloth(shape: TShirtShape | None = None, spacing_m: float = 0.03) -> ClothMesh:
    """A T-shirt outline (body and sleeves, one layer: the front) as a triangle mesh.

    Points on a hexagonal lattice inside the outline (kept at least half a spacing away
    from it) and points along the outline are Delaunay-triangulated; triangles whose
    centroid falls outside the outline are dropped. The interior is then made of
    near-equilateral triangles and the outline is followed exactly.

    shape : TShirtShape, default a medium adult shirt (0.50 m wide, 0.70 m long)
    spacing_m : target edge length in metres
    returns ClothMesh with landmarks ``left_shoulder, right_shoulder, neck,
    left_hem, right_hem, left_cuff, right_cuff``
    """
    shape = shape or TShirtShape()
    spacing_m = _check_size("tshirt_cloth: spacing_m", spacing_m, 1e-3)
    outline = shape.outline()
    outline = outline - outline.min(axis=0)
    extent = outline.max(axis=0)
    if np.any(extent < 4 * spacing_m):
        raise ValueError(f"tshirt_cloth: spacing_m={spacing_m} is too coarse for a {extent[0]:.2f}x{extent[1]:.2f} m shirt")

    row_step = spacing_m * np.sqrt(3.0) / 2.0
    rows = np.arange(0.0, extent[1] + row_step, row_step)
    cols = np.arange(0.0, extent[0] + spacing_m, spacing_m)
    jj, ii = np.meshgrid(cols, np.arange(len(rows)))
    lattice = np.stack([(jj + 0.5 * spacing_m * (ii % 2)).ravel(), rows[ii].ravel()], axis=1)
    # centre the lattice on the shirt so left and right are cut alike
    lattice[:, 0] += 0.5 * (extent[0] - (lattice[:, 0].max() + lattice[:, 0].min()))
    keep = points_in_polygon(lattice, outline) & (_distance_to_outline(lattice, outline) >= 0.5 * spacing_m)
    border = _resample_outline(outline, spacing_m)
    uv = np.concatenate([border, lattice[keep]])

    tri = Delaunay(uv).simplices
    # Delaunay leaves slivers of no area between collinear outline points; a sliver's
    # centroid lies on the outline, so the inside test keeps some of them. They hold no
    # cloth and make a fold in the outline (PyBullet's loadSoftBody can hang on them):
    # drop them. A true triangle of this lattice has an area of about 0.43 spacing^2.
    signed = _signed_areas(uv, tri)
    centroids = uv[tri].mean(axis=1)
    keep = points_in_polygon(centroids, outline) & (np.abs(signed) > 1e-6 * spacing_m**2)
    faces, flip = tri[keep].astype(np.int64), signed[keep] > 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    used, faces = np.unique(faces, return_inverse=True)
    faces = faces.reshape(-1, 3)
    uv = uv[used]

    # key points of the outline, in the order TShirtShape.outline lists them
    n_neck = len(outline) - 10
    key = outline[n_neck:]
    landmarks = {
        "neck": _nearest(uv, outline[n_neck // 2]),
        "right_shoulder": _nearest(uv, key[0]),
        "right_cuff": _nearest(uv, 0.5 * (key[1] + key[2])),
        "right_hem": _nearest(uv, key[4]),
        "left_hem": _nearest(uv, key[5]),
        "left_cuff": _nearest(uv, 0.5 * (key[7] + key[8])),
        "left_shoulder": _nearest(uv, key[9]),
    }
    log.debug("tshirt_cloth: %d vertices, %d faces", len(uv), len(faces))
    return ClothMesh(uv, faces, landmarks, name=f"T-shirt {shape.body_width_m:.2f}x{shape.body_length_m:.2f} m")


def _nearest(uv: np.ndarray, point) -> int:
    return int(np.argmin(np.linalg.norm(uv - np.asarray(point, dtype=np.float64), axis=1)))


def write_obj(path, vertices: np.ndarray, faces: np.ndarray, texture_coords: np.ndarray) -> None:
    """Write a triangle mesh as Wavefront OBJ with one ``vt`` per vertex.

    vertices : (V, 3) float, metres; faces : (F, 3) int; texture_coords : (V, 2) float
    Vertex i of the file is vertex i of the arrays (PyBullet keeps this order for
    soft-body nodes), so node ids and mesh ids agree.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(texture_coords, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64) + 1
    if v.ndim != 2 or v.shape[1] != 3 or t.shape != (len(v), 2):
        raise ValueError(f"write_obj: expected vertices (V, 3) and texture_coords (V, 2), got {v.shape} and {t.shape}")
    lines = ["# cloth mesh written by sim.cloth_mesh"]
    lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in v]
    lines += [f"vt {s:.7f} {q:.7f}" for s, q in t]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in f]
    with open(path, "w", encoding="ascii") as fh:
        fh.write("\n".join(lines) + "\n")
