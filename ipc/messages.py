"""Message dataclasses shared by every package.

Each message is a plain dataclass holding NumPy arrays and scalars. The numerical
core (tracker, grasp selection) takes and returns these; the codec in
``ipc.codec`` turns them into msgpack bytes and back. Each field declares the wire type
it travels as (``ipc.wire.field``): the codec's schemas are derived from these classes.
Arrays use the toolkit's conventions: metres, seconds, radians, OpenCV optical camera
frame.

Constructors validate shapes, dtypes and values and raise ``ValueError`` with a
one-line message naming the field, so a bad frame is caught where it enters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ipc import wire

SCHEMA_VERSION = 7

# Wire types shared by several fields.
_REQUEST_ID = wire.Int(lo=0)  # echoed in the reply
_COUNT = wire.Int(lo=0)
_DURATION_OR_NIL = wire.Optional(wire.Float(lo=0.0))  # nil while nothing was measured


def _check_mask(name: str, value, shape: tuple) -> np.ndarray:
    """Return ``value`` as a bool array of ``shape``: bool as is, integers as non-zero."""
    arr = np.asarray(value)
    if arr.dtype != np.bool_:
        if arr.dtype.kind not in "iu":
            raise ValueError(f"{name}: expected dtype bool or an integer type, got {arr.dtype}")
        arr = arr != 0
    return _check_array(name, arr, shape)


def _check_array(name: str, value, shape: tuple, dtype=None, finite: bool = False) -> np.ndarray:
    """Return ``value`` as an array of ``shape`` (None = any length) and ``dtype``.

    Raises ValueError naming ``name`` and the shape or dtype received.
    """
    arr = np.asarray(value)
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        dims = ["N" if s is None else str(s) for s in shape]
        want = f"({dims[0]},)" if len(dims) == 1 else "(" + ", ".join(dims) + ")"  # as numpy prints a shape
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if dtype is not None and arr.dtype != dtype:
        if np.dtype(dtype).kind == "f" and arr.dtype.kind in "fiu":
            arr = arr.astype(dtype)
        elif np.dtype(dtype).kind in "iu" and arr.dtype.kind in "iu":
            limits = np.iinfo(dtype)
            if arr.size and (arr.min() < limits.min or arr.max() > limits.max):
                raise ValueError(f"{name}: values from {arr.min()} to {arr.max()} do not fit {np.dtype(dtype)} "
                                 f"([{limits.min}, {limits.max}])")
            arr = arr.astype(dtype)
        else:
            raise ValueError(f"{name}: expected dtype {np.dtype(dtype)}, got {arr.dtype}")
    if finite and arr.size and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return arr


@dataclass(frozen=True)
class CameraInfo:
    """Pinhole intrinsics, as ROS CameraInfo.

    width, height : int, pixels
    K : (3, 3) float64, ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels
    D : (5,) float64 plumb_bob distortion ``k1 k2 t1 t2 k3``, or (0,) for none
    frame_id : name of the optical frame the camera looks along (+z)
    """

    width: int = wire.field(wire.Int(1, 65535))
    height: int = wire.field(wire.Int(1, 65535))
    K: np.ndarray = wire.field(wire.Array(("float64",), 2))
    D: np.ndarray = wire.field(wire.Array(("float64",), 1), default_factory=lambda: np.zeros(0))
    frame_id: str = wire.field(wire.Str(), default="camera_color_optical_frame")

    def __post_init__(self):
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"CameraInfo: width and height must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        K = _check_array("CameraInfo.K", self.K, (3, 3), np.float64, finite=True)
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] != 1.0 or K[0, 1] != 0 or np.any(K[2, :2] != 0):
            raise ValueError(f"CameraInfo.K: expected [[fx,0,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0, got {K.tolist()}")
        D = _check_array("CameraInfo.D", self.D, (None,), np.float64, finite=True)
        if D.size not in (0, 4, 5, 8):
            raise ValueError(f"CameraInfo.D: expected 0, 4, 5 or 8 coefficients, got {D.size}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @classmethod
    def from_fov(cls, width: int, height: int, fov_y_rad: float, **kw) -> CameraInfo:
        """Square-pixel camera with the principal point at the image centre."""
        f = 0.5 * height / math.tan(0.5 * fov_y_rad)
        K = np.array([[f, 0.0, 0.5 * width], [0.0, f, 0.5 * height], [0.0, 0.0, 1.0]])
        return cls(width=width, height=height, K=K, **kw)


@dataclass(frozen=True)
class RGBDFrame:
    """One registered colour and depth image.

    rgb : (H, W, 3) uint8, RGB channel order
    depth_m : (H, W) float32, metres along the optical axis; 0 or NaN = no measurement (other
        float types are converted; integer depth is refused: its scale is not known here)
    camera : CameraInfo of both images (depth is registered to colour)
    timestamp_s : float, seconds
    seq : int, frame counter of the source
    occluder_mask : (H, W) bool, True where a known occluder (the robot's gripper or arm,
        a hand) covers the image, or None when nothing is known; integers are taken as
        non-zero. The tracker never binds the object to these pixels.
    held_vertices : (K,) int32, ids of the tracked mesh's vertices (of ``MeshEstimate.canonical``)
        that the robot holds in its grippers (e.g. the ``vertex_id`` of the grasp plan it
        executed) or whose place it knows as surely (e.g. the material point a cloth hanging
        from one gripper has lowest: ``perception.hanging``), or None when it holds nothing
    held_points_m : (K, 3) float64 metres, in this frame's camera frame: where the robot's
        grippers hold them at this frame's time, from its own kinematics, or where it knows
        them to be; given with
        ``held_vertices`` (both or neither). The tracker keeps those vertices there.
    held_quats_xyzw : (K, 4) float64 unit quaternions (x, y, z, w), in this frame's camera
        frame: the orientation of the gripper holding each of ``held_vertices``, from the
        robot's own kinematics, a row of NaN for a point no gripper holds (e.g. the lowest
        point ``perception.hanging`` finds); or None when not known (only with
        ``held_vertices``). When one gripper's orientation is given in this frame and the
        last, for the same vertex, the tracker predicts the cloth turned with it about the
        held point, as a robot's wrist turns a cloth hanging from it
    """

    rgb: np.ndarray = wire.field(wire.Array(("uint8",), 3))
    depth_m: np.ndarray = wire.field(wire.Array(("float32", "uint16"), 2))
    camera: CameraInfo = wire.field(wire.Nested(CameraInfo))
    timestamp_s: float = wire.field(wire.Float(), default=0.0)
    seq: int = wire.field(wire.Int(), default=0)
    occluder_mask: np.ndarray | None = wire.field(wire.Optional(wire.Array(("uint8",), 2)), default=None)
    held_vertices: np.ndarray | None = wire.field(wire.Optional(wire.Array(("int32",), 1)), default=None)
    held_points_m: np.ndarray | None = wire.field(wire.Optional(wire.Array(("float64", "float32"), 2)), default=None)
    held_quats_xyzw: np.ndarray | None = wire.field(wire.Optional(wire.Array(("float64", "float32"), 2)), default=None)

    def __post_init__(self):
        cam = self.camera
        if not isinstance(cam, CameraInfo):
            raise ValueError(f"RGBDFrame.camera: expected CameraInfo, got {type(cam).__name__}")
        rgb = _check_array("RGBDFrame.rgb", self.rgb, (cam.height, cam.width, 3), np.uint8)
        if np.asarray(self.depth_m).dtype.kind in "iu":
            raise ValueError(f"RGBDFrame.depth_m: expected float metres, got {np.asarray(self.depth_m).dtype} "
                             f"(integer depth comes with its scale: divide by it, e.g. 1000 for millimetres)")
        depth = _check_array("RGBDFrame.depth_m", self.depth_m, (cam.height, cam.width), np.float32)
        # fmin/fmax skip NaN (missing) and are one fast pass each; this runs on every
        # frame a service receives. A -inf shows as negative, as it did with depth < 0.
        if np.fmin.reduce(depth, axis=None) < 0:
            raise ValueError("RGBDFrame.depth_m: negative depth values")
        if np.isinf(np.fmax.reduce(depth, axis=None)):
            raise ValueError("RGBDFrame.depth_m: infinite depth values (use 0 or NaN for missing)")
        if not math.isfinite(float(self.timestamp_s)):
            raise ValueError(f"RGBDFrame.timestamp_s: expected a finite number, got {self.timestamp_s}")
        if self.occluder_mask is not None:
            mask = _check_mask("RGBDFrame.occluder_mask", self.occluder_mask, (cam.height, cam.width))
            object.__setattr__(self, "occluder_mask", mask)
        if (self.held_vertices is None) != (self.held_points_m is None):
            raise ValueError("RGBDFrame.held_vertices and held_points_m: expected both or neither")
        if self.held_vertices is not None:
            ids = np.asarray(self.held_vertices)
            points = np.asarray(self.held_points_m)
            if ids.ndim != 1 or ids.dtype.kind not in "iu":
                raise ValueError(f"RGBDFrame.held_vertices: expected (K,) integer vertex ids, got shape "
                                 f"{ids.shape} dtype {ids.dtype}")
            if ids.size and (ids.min() < 0 or ids.max() > np.iinfo(np.int32).max):
                raise ValueError(f"RGBDFrame.held_vertices: vertex ids from {ids.min()} to {ids.max()}, expected "
                                 f"0 to {np.iinfo(np.int32).max}")
            if points.shape != (ids.size, 3):
                raise ValueError(f"RGBDFrame.held_points_m: expected ({ids.size}, 3) metres like held_vertices, "
                                 f"got shape {points.shape}")
            if points.dtype.kind not in "fiu" or not np.all(np.isfinite(points)):
                raise ValueError("RGBDFrame.held_points_m: expected finite metres, got NaN, infinite or "
                                 "non-numeric values")
            object.__setattr__(self, "held_vertices", ids.astype(np.int32))
            object.__setattr__(self, "held_points_m", points.astype(np.float64))
        if self.held_quats_xyzw is not None:
            object.__setattr__(self, "held_quats_xyzw", self._held_quats())
        object.__setattr__(self, "rgb", rgb)
        object.__setattr__(self, "depth_m", depth)
        object.__setattr__(self, "timestamp_s", float(self.timestamp_s))
        object.__setattr__(self, "seq", int(self.seq))

    def _held_quats(self) -> np.ndarray:
        """``held_quats_xyzw`` checked: (K, 4) float64, each row a unit quaternion or all NaN."""
        if self.held_vertices is None:
            raise ValueError("RGBDFrame.held_quats_xyzw: expected only with held_vertices")
        quats = np.asarray(self.held_quats_xyzw)
        if quats.shape != (self.held_vertices.size, 4) or quats.dtype.kind != "f":
            raise ValueError(f"RGBDFrame.held_quats_xyzw: expected ({self.held_vertices.size}, 4) float quaternions "
                             f"like held_vertices, got shape {quats.shape} dtype {quats.dtype}")
        quats = quats.astype(np.float64)
        unknown = np.all(np.isnan(quats), axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            norms = np.linalg.norm(quats[~unknown], axis=1)
        if not np.all(np.abs(norms - 1.0) <= 1e-3):  # also catches a row partly NaN, or infinite
            raise ValueError("RGBDFrame.held_quats_xyzw: expected unit quaternions (x, y, z, w), or a row of NaN "
                             "for a point no gripper holds")
        quats[~unknown] /= norms[:, None]
        return quats

    def valid_depth(self) -> np.ndarray:
        """(H, W) bool: where depth was measured (finite and > 0)."""
        d = self.depth_m
        return np.isfinite(d) & (d > 0)


@dataclass(frozen=True)
class MeshEstimate:
    """The tracker's estimate of the object's configuration in one frame.

    vertices : (N, 3) float64, metres, camera frame (``frame_id``)
    faces : (M, 3) int32 vertex ids, counter-clockwise seen from the camera at frame 0
    boundary : (B,) int32 ids of boundary vertices (fewer than six neighbours)
    canonical : (N, 3) float64, metres, the canonical (rest) mesh in its own flat frame
        (z = 0 plane); material coordinates of each vertex
    energies : per-term energies at the solution, keys among
        ``smoothness, correspondence, depth, boundary, total``
    iterations : solver iterations used for this frame
    confidence : in [0, 1], how well the data supports the estimate (depth agreement of
        the visible vertices, coverage of the segmented object, fit of the correspondences)
    lost : True when the data no longer explains the mesh
    timing_ms : tracking time of this frame, milliseconds
    visible : (N,) bool, True for the vertices the camera saw in this frame (not hidden
        behind something nearer, not out of view, with depth), or None when not known
    """

    vertices: np.ndarray = wire.field(wire.Array(("float64",), 2))
    faces: np.ndarray = wire.field(wire.Array(("int32",), 2))
    boundary: np.ndarray = wire.field(wire.Array(("int32",), 1))
    canonical: np.ndarray = wire.field(wire.Array(("float64",), 2))
    timestamp_s: float = wire.field(wire.Float(), default=0.0)
    seq: int = wire.field(wire.Int(), default=0)
    energies: dict = wire.field(wire.Map(wire.Float()), default_factory=dict)
    iterations: int = wire.field(wire.Int(lo=0), default=0)
    confidence: float = wire.field(wire.Float(), default=1.0)
    lost: bool = wire.field(wire.Bool(), default=False)
    timing_ms: float = wire.field(wire.Float(lo=0.0), default=0.0)
    frame_id: str = wire.field(wire.Str(), default="camera_color_optical_frame")
    visible: np.ndarray | None = wire.field(wire.Optional(wire.Array(("uint8",), 1)), default=None)

    def __post_init__(self):
        v = _check_array("MeshEstimate.vertices", self.vertices, (None, 3), np.float64, finite=True)
        n = v.shape[0]
        f = _check_array("MeshEstimate.faces", self.faces, (None, 3), np.int32)
        b = _check_array("MeshEstimate.boundary", self.boundary, (None,), np.int32)
        c = _check_array("MeshEstimate.canonical", self.canonical, (n, 3), np.float64, finite=True)
        for name, ids in (("faces", f), ("boundary", b)):
            if ids.size and (ids.min() < 0 or ids.max() >= n):
                raise ValueError(f"MeshEstimate.{name}: vertex ids outside [0, {n})")
        if not 0.0 <= float(self.confidence) <= 1.0:
            raise ValueError(f"MeshEstimate.confidence: expected a value in [0, 1], got {self.confidence}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "boundary", b)
        if self.visible is not None:
            object.__setattr__(self, "visible", _check_mask("MeshEstimate.visible", self.visible, (n,)))
        object.__setattr__(self, "canonical", c)
        object.__setattr__(self, "energies", {str(k): float(x) for k, x in dict(self.energies).items()})
        object.__setattr__(self, "lost", bool(self.lost))


@dataclass(frozen=True)
class GraspPlan:
    """One grasp for a parallel gripper, in the camera frame unless ``frame_id`` says otherwise.

    position : (3,) float64, metres, where the fingertips close
    approach : (3,) float64, unit vector, direction the gripper moves in to reach ``position``
    quat_xyzw : (4,) float64, gripper orientation (x, y, z, w)
    opening_width_m : finger opening before closing, metres
    score : higher is better, in [0, 1]
    vertex_id : mesh vertex the grasp is attached to
    kind : "corner", "boundary" or "highest"
    """

    position: np.ndarray = wire.field(wire.Array(("float64",), 1))
    approach: np.ndarray = wire.field(wire.Array(("float64",), 1))
    quat_xyzw: np.ndarray = wire.field(wire.Array(("float64",), 1))
    opening_width_m: float = wire.field(wire.Float())
    score: float = wire.field(wire.Float())
    vertex_id: int = wire.field(wire.Int(lo=0))
    kind: str = wire.field(wire.Str())
    frame_id: str = wire.field(wire.Str(), default="camera_color_optical_frame")
    timestamp_s: float = wire.field(wire.Float(), default=0.0)

    KINDS = ("corner", "boundary", "highest")

    def __post_init__(self):
        object.__setattr__(self, "position", _check_array("GraspPlan.position", self.position, (3,), np.float64, finite=True))
        a = _check_array("GraspPlan.approach", self.approach, (3,), np.float64, finite=True)
        q = _check_array("GraspPlan.quat_xyzw", self.quat_xyzw, (4,), np.float64, finite=True)
        with np.errstate(over="ignore"):  # a huge component (a corrupt message) is reported as norm inf
            norm_a, norm_q = float(np.linalg.norm(a)), float(np.linalg.norm(q))
        if abs(norm_a - 1.0) > 1e-6:
            raise ValueError(f"GraspPlan.approach: expected a unit vector, got norm {norm_a:.6g}")
        if abs(norm_q - 1.0) > 1e-6:
            raise ValueError(f"GraspPlan.quat_xyzw: expected a unit quaternion, got norm {norm_q:.6g}")
        if self.kind not in self.KINDS:
            raise ValueError(f"GraspPlan.kind: expected one of {self.KINDS}, got {self.kind!r}")
        if not (math.isfinite(float(self.opening_width_m)) and float(self.opening_width_m) > 0):
            raise ValueError(f"GraspPlan.opening_width_m: expected a positive number, got {self.opening_width_m}")
        object.__setattr__(self, "approach", a)
        object.__setattr__(self, "quat_xyzw", q)
        object.__setattr__(self, "opening_width_m", float(self.opening_width_m))
        object.__setattr__(self, "score", float(self.score))
        object.__setattr__(self, "vertex_id", int(self.vertex_id))


def _check_count(name: str, value) -> int:
    """Return ``value`` as a non-negative int (never a bool or float); raise ValueError naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name}: expected a non-negative integer, got {value!r}")
    return int(value)


def _check_request_id(owner: str, value) -> int:
    """Return ``value`` as a non-negative int; raise ValueError naming ``owner.request_id``."""
    return _check_count(f"{owner}.request_id", value)


def _check_frame_seq(owner: str, value) -> int:
    """Return ``value`` as an int >= -1 (a frame's ``seq``, or -1 for none in particular);
    raise ValueError naming ``owner.seq``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < -1:
        raise ValueError(f"{owner}.seq: expected a frame seq >= 0 or -1, got {value!r}")
    return int(value)


def _check_number(name: str, value, lo: float = 0.0, hi: float = math.inf, optional: bool = False) -> float | None:
    """Return ``value`` as a finite float in [lo, hi], or None when ``optional`` and it is None.

    "No data" travels as nil, never as NaN: NaN compares false to everything and has no
    JSON form, so each reader in another language would need its own rule for it.
    """
    if value is None and optional:
        return None
    ok = not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.integer, np.floating))
    if not ok or not (math.isfinite(float(value)) and lo <= float(value) <= hi):
        want = f"a number >= {lo:g}" if hi == math.inf else f"a number in [{lo:g}, {hi:g}]"
        raise ValueError(f"{name}: expected {want}{' or None' if optional else ''}, got {value!r}")
    return float(value)


def _check_parameters(name: str, params, allow_empty: bool) -> dict:
    """Return a copy of ``params`` (str -> bool | int | float | str), checked.

    Floats must be finite; NumPy scalars become Python scalars so that the codec and
    a reader of the dict see one type per value.
    """
    if not isinstance(params, dict):
        raise ValueError(f"{name}: expected a dict, got {type(params).__name__}")
    if not params and not allow_empty:
        raise ValueError(f"{name}: expected at least one parameter")
    out = {}
    for key, value in params.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"{name}: parameter names must be non-empty strings, got {key!r}")
        if isinstance(value, (bool, np.bool_)):
            value = bool(value)
        elif isinstance(value, (int, np.integer)):
            value = int(value)
        elif isinstance(value, (float, np.floating)):
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"{name}[{key!r}]: expected a finite number, got {value}")
        elif not isinstance(value, str):
            raise ValueError(f"{name}[{key!r}]: expected bool, int, float or str, got {type(value).__name__}")
        out[key] = value
    return out


def _check_max_candidates(owner: str, value) -> int:
    """Return ``value`` as an int in [1, ``GraspRequest.MAX_CANDIDATES``]; raise ValueError naming the field."""
    top = GraspRequest.MAX_CANDIDATES
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 1 <= value <= top:
        raise ValueError(f"{owner}.max_candidates: expected an integer in [1, {top}], got {value!r}")
    return int(value)


@dataclass(frozen=True)
class GraspRequest:
    """Ask the grasp planner for grasp candidates.

    request_id : int >= 0, echoed in the reply
    max_candidates : int in [1, 100], most candidates wanted in the reply
    kinds : non-empty tuple of distinct ``GraspPlan.KINDS``, the kinds of grasp to consider
    estimate : MeshEstimate to plan on, or None to plan on the newest estimate the
        planner has received from the perception service
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    max_candidates: int = wire.field(wire.Int(), default=5)
    kinds: tuple = wire.field(wire.List(wire.Str()), default=GraspPlan.KINDS)
    estimate: MeshEstimate | None = wire.field(wire.Optional(wire.Nested(MeshEstimate)), default=None)

    MAX_CANDIDATES = 100

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("GraspRequest", self.request_id))
        object.__setattr__(self, "max_candidates", _check_max_candidates("GraspRequest", self.max_candidates))
        if isinstance(self.kinds, str):
            raise ValueError(f"GraspRequest.kinds: expected a sequence of kinds, got the string {self.kinds!r}")
        kinds = tuple(self.kinds)
        if not kinds or len(set(kinds)) != len(kinds) or any(k not in GraspPlan.KINDS for k in kinds):
            raise ValueError(f"GraspRequest.kinds: expected distinct values among {GraspPlan.KINDS}, got {kinds!r}")
        object.__setattr__(self, "kinds", kinds)
        if self.estimate is not None and not isinstance(self.estimate, MeshEstimate):
            raise ValueError(f"GraspRequest.estimate: expected MeshEstimate or None, got {type(self.estimate).__name__}")


@dataclass(frozen=True)
class GraspPlanReply:
    """The grasp planner's answer to a GraspRequest.

    request_id : int >= 0, the request's id
    candidates : tuple of GraspPlan, best first (scores non-increasing); empty when no
        grasp was found on the mesh
    estimate_seq : ``seq`` of the MeshEstimate planned on
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    candidates: tuple = wire.field(wire.List(wire.Nested(GraspPlan)), default=())
    estimate_seq: int = wire.field(wire.Int(), default=0)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("GraspPlanReply", self.request_id))
        candidates = tuple(self.candidates)
        for i, c in enumerate(candidates):
            if not isinstance(c, GraspPlan):
                raise ValueError(f"GraspPlanReply.candidates[{i}]: expected GraspPlan, got {type(c).__name__}")
        scores = [c.score for c in candidates]
        if any(a < b for a, b in zip(scores, scores[1:])):
            raise ValueError(f"GraspPlanReply.candidates: expected best first (non-increasing scores), got scores {scores}")
        object.__setattr__(self, "candidates", candidates)
        object.__setattr__(self, "estimate_seq", int(self.estimate_seq))


@dataclass(frozen=True)
class AdjacentCorner:
    """A corner of the cloth's outline next to a held material point, for a second grasp.

    plan : GraspPlan of kind "corner" at the corner on the current estimate (camera frame
        ``plan.frame_id``); ``plan.vertex_id`` is the corner's vertex of the canonical mesh
        and ``plan.score`` the candidate's score in [0, 1] (0 when it is out of reach)
    side : +1 when reached going forward along the outline's order from the held point
        (the cloth on the left about the face winding normal), -1 going backward
    material_distance_m : float >= 0, metres, length of the outline between the held
        point and the corner on the canonical (rest) mesh: the edge the two grasps stretch
    visible : float in [0, 1], the part of the material around the corner that was seen
    reachable : True when the grasp lies inside the planner's workspace
    tip_offset_m : float >= 0, metres from the estimate's corner vertex to the tip of the
        measured surface the grasp was moved to, or None when it was not moved (no tip
        search, no frame, or no tip within the search): how far the frame says the
        estimate's corner is from where the cloth ends
    """

    plan: GraspPlan = wire.field(wire.Nested(GraspPlan))
    side: int = wire.field(wire.Int(lo=-1, hi=1))
    material_distance_m: float = wire.field(wire.Float(lo=0.0))
    visible: float = wire.field(wire.Float(lo=0.0))
    reachable: bool = wire.field(wire.Bool())
    tip_offset_m: float | None = wire.field(wire.Optional(wire.Float(lo=0.0)), default=None)

    SIDES = (1, -1)

    def __post_init__(self):
        if not isinstance(self.plan, GraspPlan):
            raise ValueError(f"AdjacentCorner.plan: expected GraspPlan, got {type(self.plan).__name__}")
        if self.plan.kind != "corner":
            raise ValueError(f"AdjacentCorner.plan: expected a grasp of kind 'corner', got {self.plan.kind!r}")
        side = self.side
        if isinstance(side, (bool, np.bool_)) or not isinstance(side, (int, np.integer)) or side not in self.SIDES:
            raise ValueError(f"AdjacentCorner.side: expected +1 or -1, got {side!r}")
        object.__setattr__(self, "side", int(side))
        object.__setattr__(self, "material_distance_m",
                           _check_number("AdjacentCorner.material_distance_m", self.material_distance_m))
        object.__setattr__(self, "visible", _check_number("AdjacentCorner.visible", self.visible, hi=1.0))
        if not isinstance(self.reachable, (bool, np.bool_)):
            raise ValueError(f"AdjacentCorner.reachable: expected a bool, got {self.reachable!r}")
        object.__setattr__(self, "reachable", bool(self.reachable))
        object.__setattr__(self, "tip_offset_m",
                           _check_number("AdjacentCorner.tip_offset_m", self.tip_offset_m, optional=True))


@dataclass(frozen=True)
class AdjacentCornersRequest:
    """Ask the grasp planner for the outline corners adjacent to a held material point.

    request_id : int >= 0, echoed in the reply
    held_vertex : int >= 0, required (keyword-only), vertex of the canonical mesh the robot
        holds (the ``GraspPlan.vertex_id`` of the grasp it executed)
    max_candidates : int in [1, 100], most corners wanted in the reply (there are at
        most two: one on each side of the held point)
    estimate : MeshEstimate to plan on, or None to plan on the newest estimate the
        planner has received from the perception service
    even_if_lost : bool, plan also on an estimate flagged lost or below the planner's
        minimum confidence (default False: no candidates then), for a controller that
        checks each corner against the frame itself (``AdjacentCorner.tip_offset_m``)
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    held_vertex: int = wire.field(wire.Int(lo=0), kw_only=True)  # required: no vertex is a safe default
    max_candidates: int = wire.field(wire.Int(), default=2)
    estimate: MeshEstimate | None = wire.field(wire.Optional(wire.Nested(MeshEstimate)), default=None)
    even_if_lost: bool = wire.field(wire.Bool(), default=False)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("AdjacentCornersRequest", self.request_id))
        object.__setattr__(self, "held_vertex", _check_count("AdjacentCornersRequest.held_vertex", self.held_vertex))
        object.__setattr__(self, "max_candidates", _check_max_candidates("AdjacentCornersRequest", self.max_candidates))
        if self.estimate is not None and not isinstance(self.estimate, MeshEstimate):
            raise ValueError(f"AdjacentCornersRequest.estimate: expected MeshEstimate or None, "
                             f"got {type(self.estimate).__name__}")
        if not isinstance(self.even_if_lost, (bool, np.bool_)):
            raise ValueError(f"AdjacentCornersRequest.even_if_lost: expected a bool, got {self.even_if_lost!r}")
        object.__setattr__(self, "even_if_lost", bool(self.even_if_lost))


@dataclass(frozen=True)
class AdjacentCornersReply:
    """The grasp planner's answer to an AdjacentCornersRequest.

    request_id : int >= 0, the request's id
    estimate_seq : ``seq`` of the MeshEstimate planned on
    held_vertex : the request's ``held_vertex``
    held_outline_vertex : int, the canonical mesh's outline vertex taken as the held
        point (``held_vertex`` itself when it lies on the outline, else the outline
        vertex nearest to it); -1 when the mesh has no outline
    candidates : tuple of AdjacentCorner, best first (``plan.score`` non-increasing), at
        most one per side; empty when there is no other corner or no usable estimate
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    estimate_seq: int = wire.field(wire.Int(), default=0)
    held_vertex: int = wire.field(wire.Int(lo=0), default=0)
    held_outline_vertex: int = wire.field(wire.Int(lo=-1), default=-1)
    candidates: tuple = wire.field(wire.List(wire.Nested(AdjacentCorner)), default=())

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("AdjacentCornersReply", self.request_id))
        object.__setattr__(self, "estimate_seq", int(self.estimate_seq))
        object.__setattr__(self, "held_vertex", _check_count("AdjacentCornersReply.held_vertex", self.held_vertex))
        outline_vertex = self.held_outline_vertex
        if isinstance(outline_vertex, (bool, np.bool_)) or not isinstance(outline_vertex, (int, np.integer)) \
                or outline_vertex < -1:
            raise ValueError(f"AdjacentCornersReply.held_outline_vertex: expected a vertex id >= 0 or -1, "
                             f"got {outline_vertex!r}")
        object.__setattr__(self, "held_outline_vertex", int(outline_vertex))
        candidates = tuple(self.candidates)
        for i, c in enumerate(candidates):
            if not isinstance(c, AdjacentCorner):
                raise ValueError(f"AdjacentCornersReply.candidates[{i}]: expected AdjacentCorner, got {type(c).__name__}")
        scores = [c.plan.score for c in candidates]
        if any(a < b for a, b in zip(scores, scores[1:])):
            raise ValueError(f"AdjacentCornersReply.candidates: expected best first (non-increasing plan scores), "
                             f"got scores {scores}")
        sides = [c.side for c in candidates]
        if len(set(sides)) != len(sides):
            raise ValueError(f"AdjacentCornersReply.candidates: expected at most one corner per side, got sides {sides}")
        object.__setattr__(self, "candidates", candidates)


@dataclass(frozen=True)
class InitialiseRequest:
    """Ask the perception service to build a new mesh, on the frame ``seq`` or on the next
    frame it receives.

    request_id : int >= 0, echoed in the reply
    mask : (H, W) uint8, non-zero on the object in that frame (H, W of the frame), or
        None to find the object by depth segmentation. A bool mask is converted.
    background : RGBDFrame of the empty workspace seen by the same fixed camera, or None.
        From then on (until the next InitialiseRequest or a reset) only what differs from
        it can be the object, so that a cloth lifted off a table is not held to the table
        by its depth. The robot takes it before the cloth is put down, or knows it.
    seq : the ``seq`` of the frame to build the mesh on (the frame the mask was made
        from): one the service received recently, or one still to come; -1 for the next
        frame the service receives
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    mask: np.ndarray | None = wire.field(wire.Optional(wire.Array(("uint8",), 2)), default=None)
    background: RGBDFrame | None = wire.field(wire.Optional(wire.Nested(RGBDFrame)), default=None)
    seq: int = wire.field(wire.Int(lo=-1), default=-1)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("InitialiseRequest", self.request_id))
        object.__setattr__(self, "seq", _check_frame_seq("InitialiseRequest", self.seq))
        if self.mask is None:
            return
        mask = np.asarray(self.mask)
        if mask.dtype == np.bool_:
            mask = mask.astype(np.uint8)
        mask = _check_array("InitialiseRequest.mask", mask, (None, None), np.uint8)
        if not mask.any():
            raise ValueError(f"InitialiseRequest.mask: no non-zero pixel in the {mask.shape} mask")
        object.__setattr__(self, "mask", mask)


@dataclass(frozen=True)
class ResetRequest:
    """Ask the perception service to drop its mesh and wait for an InitialiseRequest.

    request_id : int >= 0, echoed in the reply
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("ResetRequest", self.request_id))


@dataclass(frozen=True)
class SetParametersRequest:
    """Change tracker parameters of the perception service (e.g. energy weights).

    request_id : int >= 0, echoed in the reply
    parameters : non-empty dict, name -> bool | int | float (finite) | str. The names a
        service accepts are those in its StatusReply.parameters; others are refused.
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    parameters: dict = wire.field(wire.Map(wire.Scalar()), default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("SetParametersRequest", self.request_id))
        parameters = _check_parameters("SetParametersRequest.parameters", self.parameters, allow_empty=False)
        object.__setattr__(self, "parameters", parameters)


@dataclass(frozen=True)
class OccluderMaskRequest:
    """Tell the perception service where a known occluder (the robot's own gripper or arm)
    covers the image, so that the tracker never binds the object to those pixels.

    request_id : int >= 0, echoed in the reply
    mask : (H, W) uint8, non-zero where the occluder is (H, W of the frames), or None to
        clear. A bool mask is converted.
    seq : the ``seq`` of the one frame the mask belongs to, or -1 for a standing mask that
        applies to every frame from now on until it is replaced or cleared
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    mask: np.ndarray | None = wire.field(wire.Optional(wire.Array(("uint8",), 2)), default=None)
    seq: int = wire.field(wire.Int(lo=-1), default=-1)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("OccluderMaskRequest", self.request_id))
        object.__setattr__(self, "seq", _check_frame_seq("OccluderMaskRequest", self.seq))
        if self.mask is not None:
            mask = np.asarray(self.mask)
            if mask.dtype == np.bool_:
                mask = mask.astype(np.uint8)
            object.__setattr__(self, "mask", _check_array("OccluderMaskRequest.mask", mask, (None, None), np.uint8))


@dataclass(frozen=True)
class StatusRequest:
    """Ask the perception service for its StatusReply.

    request_id : int >= 0, echoed in the reply
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("StatusRequest", self.request_id))


@dataclass(frozen=True)
class StatusReply:
    """The perception service's state; the reply to every control request that succeeded.

    Every counter and measurement is a field of its own, so that a controller in any
    language reads numbers, not text. Counters run from the service's start (compare
    ``uptime_s`` to notice a restart), except ``frames_processed``.

    request_id : int >= 0, the request's id
    state : one of ``STATES``: "idle" (no mesh), "initialising" (mesh to be built on
        the next frame), "tracking", "lost" (the data no longer explains the mesh)
    frames_processed : int >= 0, frames tracked since the last initialisation
    last_seq : ``seq`` of the last frame processed, -1 if none
    parameters : dict, name -> bool | int | float | str, every tracker parameter the
        service accepts in a SetParametersRequest, with its current value
    message : one line for a person, may be empty
    uptime_s : float >= 0, seconds since the service started
    source : one of ``SOURCES``: "waiting" (nothing received from the frame source yet),
        "live" (messages arriving), "stale" (silent for the stale limit: the source is gone)
    frame_age_s : float >= 0, seconds since the last frame arrived; None before the first
    frames_received : int >= 0, frames received from the frame source
    frames_tracked : int >= 0, frames initialised on or tracked, one estimate published each
    frames_dropped : int >= 0, frames skipped because a newer one arrived first
    frames_rejected : int >= 0, frames not tracked because they were unusable
    rejected_by_kind : dict, kind -> int >= 0, ``frames_rejected`` by cause, kinds seen only;
        the counts sum to ``frames_rejected``
    messages_malformed : int >= 0, messages on the frames endpoint that could not be decoded
    latency_ms_median, latency_ms_p99 : float >= 0, milliseconds from a frame's arrival
        to its estimate's publication, over the recent estimates; None before the first
    tracking_ms_median : float >= 0, median ``MeshEstimate.timing_ms`` of the recent
        estimates; None before the first
    confidence : float in [0, 1], ``confidence`` of the last estimate published; None before the first
    lost_streak : int >= 0, consecutive lost or rejected frames while tracking
    reinitialisations : int >= 0, automatic re-initialisations
    discontinuities : int >= 0, discontinuities of the frame stream seen

    None stands for "no data yet" (nil on the wire), never NaN.
    """

    request_id: int = wire.field(_REQUEST_ID, default=0)
    state: str = wire.field(wire.Str(), default="idle")
    frames_processed: int = wire.field(_COUNT, default=0)
    last_seq: int = wire.field(wire.Int(), default=-1)
    parameters: dict = wire.field(wire.Map(wire.Scalar()), default_factory=dict)
    message: str = wire.field(wire.Str(), default="")
    uptime_s: float = wire.field(wire.Float(lo=0.0), default=0.0)
    source: str = wire.field(wire.Str(), default="waiting")
    frame_age_s: float | None = wire.field(_DURATION_OR_NIL, default=None)
    frames_received: int = wire.field(_COUNT, default=0)
    frames_tracked: int = wire.field(_COUNT, default=0)
    frames_dropped: int = wire.field(_COUNT, default=0)
    frames_rejected: int = wire.field(_COUNT, default=0)
    rejected_by_kind: dict = wire.field(wire.Map(_COUNT), default_factory=dict)
    messages_malformed: int = wire.field(_COUNT, default=0)
    latency_ms_median: float | None = wire.field(_DURATION_OR_NIL, default=None)
    latency_ms_p99: float | None = wire.field(_DURATION_OR_NIL, default=None)
    tracking_ms_median: float | None = wire.field(_DURATION_OR_NIL, default=None)
    confidence: float | None = wire.field(wire.Optional(wire.Float(lo=0.0)), default=None)
    lost_streak: int = wire.field(_COUNT, default=0)
    reinitialisations: int = wire.field(_COUNT, default=0)
    discontinuities: int = wire.field(_COUNT, default=0)

    STATES = ("idle", "initialising", "tracking", "lost")
    SOURCES = ("waiting", "live", "stale")
    COUNTERS = ("frames_processed", "frames_received", "frames_tracked", "frames_dropped", "frames_rejected",
                "messages_malformed", "lost_streak", "reinitialisations", "discontinuities")
    OPTIONAL_TIMES = ("frame_age_s", "latency_ms_median", "latency_ms_p99", "tracking_ms_median")

    def __post_init__(self):
        object.__setattr__(self, "request_id", _check_request_id("StatusReply", self.request_id))
        if self.state not in self.STATES:
            raise ValueError(f"StatusReply.state: expected one of {self.STATES}, got {self.state!r}")
        if self.source not in self.SOURCES:
            raise ValueError(f"StatusReply.source: expected one of {self.SOURCES}, got {self.source!r}")
        if not isinstance(self.message, str) or "\n" in self.message:
            raise ValueError("StatusReply.message: expected a single-line string")
        for name in self.COUNTERS:
            object.__setattr__(self, name, _check_count(f"StatusReply.{name}", getattr(self, name)))
        object.__setattr__(self, "last_seq", int(self.last_seq))
        object.__setattr__(self, "parameters", _check_parameters("StatusReply.parameters", self.parameters, allow_empty=True))
        object.__setattr__(self, "uptime_s", _check_number("StatusReply.uptime_s", self.uptime_s))
        for name in self.OPTIONAL_TIMES:
            object.__setattr__(self, name, _check_number(f"StatusReply.{name}", getattr(self, name), optional=True))
        object.__setattr__(self, "confidence", _check_number("StatusReply.confidence", self.confidence, hi=1.0, optional=True))
        if not isinstance(self.rejected_by_kind, dict):
            raise ValueError(f"StatusReply.rejected_by_kind: expected a dict, got {type(self.rejected_by_kind).__name__}")
        by_kind = {}
        for kind, n in self.rejected_by_kind.items():
            if not isinstance(kind, str) or not kind:
                raise ValueError(f"StatusReply.rejected_by_kind: kinds must be non-empty strings, got {kind!r}")
            by_kind[kind] = _check_count(f"StatusReply.rejected_by_kind[{kind!r}]", n)
        if sum(by_kind.values()) != self.frames_rejected:
            raise ValueError(f"StatusReply.rejected_by_kind: counts sum to {sum(by_kind.values())}, "
                             f"expected frames_rejected = {self.frames_rejected}")
        object.__setattr__(self, "rejected_by_kind", by_kind)


@dataclass(frozen=True)
class ErrorReply:
    """The reply to a request that could not be served.

    code : one of ``CODES``:
        "protocol" the request could not be decoded (bad msgpack, framing, version, field);
        "unsupported" a valid message of a type this server does not answer;
        "invalid" well-formed, but its values cannot be applied (e.g. a mask of the wrong size);
        "not_ready" the server cannot answer yet (e.g. planner with no estimate); retry later;
        "internal" the server failed; the request may be retried
    message : one line for a person, names what was wrong
    request_id : the request's id when it could be decoded, else 0
    """

    code: str = wire.field(wire.Str())
    message: str = wire.field(wire.Str())
    request_id: int = wire.field(_REQUEST_ID, default=0)

    CODES = ("protocol", "unsupported", "invalid", "not_ready", "internal")

    def __post_init__(self):
        if self.code not in self.CODES:
            raise ValueError(f"ErrorReply.code: expected one of {self.CODES}, got {self.code!r}")
        if not isinstance(self.message, str) or not self.message or "\n" in self.message:
            raise ValueError("ErrorReply.message: expected a non-empty single-line string")
        object.__setattr__(self, "request_id", _check_request_id("ErrorReply", self.request_id))


@dataclass(frozen=True)
class Heartbeat:
    """Sent by every publisher every ``period_s`` so subscribers notice when it vanishes.

    source : non-empty name of the publishing process, e.g. "perception"
    seq : int >= 0, counts heartbeats from 0 at the publisher's start (a drop to 0
        means the publisher restarted)
    timestamp_s : sender's wall clock (Unix time), seconds
    period_s : > 0, seconds until the next heartbeat
    """

    source: str = wire.field(wire.Str())
    seq: int = wire.field(wire.Int(lo=0), default=0)
    timestamp_s: float = wire.field(wire.Float(), default=0.0)
    period_s: float = wire.field(wire.Float(positive=True), default=1.0)

    def __post_init__(self):
        if not isinstance(self.source, str) or not self.source:
            raise ValueError(f"Heartbeat.source: expected a non-empty string, got {self.source!r}")
        if int(self.seq) < 0:
            raise ValueError(f"Heartbeat.seq: expected a non-negative integer, got {self.seq}")
        if not math.isfinite(float(self.timestamp_s)):
            raise ValueError(f"Heartbeat.timestamp_s: expected a finite number, got {self.timestamp_s}")
        if not (math.isfinite(float(self.period_s)) and float(self.period_s) > 0):
            raise ValueError(f"Heartbeat.period_s: expected a positive number, got {self.period_s}")
        object.__setattr__(self, "seq", int(self.seq))
        object.__setattr__(self, "timestamp_s", float(self.timestamp_s))
        object.__setattr__(self, "period_s", float(self.period_s))


#: Every message that travels, in the order docs/protocol.md lists them.
MESSAGES = (CameraInfo, RGBDFrame, MeshEstimate, GraspPlan, GraspRequest, GraspPlanReply, AdjacentCorner,
            AdjacentCornersRequest, AdjacentCornersReply, InitialiseRequest, OccluderMaskRequest, ResetRequest,
            SetParametersRequest, StatusRequest, StatusReply, ErrorReply, Heartbeat)
