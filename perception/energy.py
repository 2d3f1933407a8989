"""The four energy terms of the paper (section III-A to III-D), each as a pure function of V.

Every term has ``evaluate(V) -> (energy, gradient)`` for V (N, 3) float64 metres in the
camera frame; the gradient is (N, 3). Data terms look their data up at V's current
projection with nearest-pixel / nearest-point association, which is piecewise constant
in V, so the returned gradient is the exact gradient of the returned energy almost
everywhere (the tests check this against finite differences).

Where the paper is silent or orthographic, choices made here:

- Depth (eq. 14): the residual is measured along the vertex's camera ray through the
  pinhole intrinsics, ``||v|| - rho(pi(v))`` with ``rho`` the measured range image, so
  the force moves the vertex along its viewing ray (the paper's Fig. 1). Residuals beyond
  ``outlier_m`` are ignored (a vertex hidden behind another layer, or seeing past an edge).
  ``PlaneDepthTerm`` measures it along the measured surface's normal instead (an option).
- Boundary (eq. 15): the distance to the nearest 3D outline point is signed (negative when
  the vertex projects outside the object), so a vertex that slid past the outline is
  pulled back rather than pushed further out to the canonical distance.
- Correspondences (eq. 13): each match has a weight, 0 for matches rejected as outliers.
- Hidden vertices: the paper has no term for vertices the camera does not see. Here the
  data terms pull only vertices classified visible (``perception.visibility``), and
  ``MotionPriorTerm`` keeps the predicted shape of the mesh around the others, so that an
  occluded part moves with its visible neighbours instead of being squeezed or dragged.
- Vertices seen off the object: the paper's data terms say nothing about a vertex whose
  pixel shows something other than the object; ``OutsideTerm`` pulls it back to the
  object's outline.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from perception.geometry import pixel_index, project
from perception.raster import bounding_box

_last_pixels = None  # (V, K, shape, pixel_index's answer) of the last look-up (``_pixels``)


def _pixels(V: np.ndarray, K: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``pixel_index(project(V, K))`` on an image of ``shape`` (H, W), kept for the last V
    and K: the data terms look the same V up one after another (V is never changed in
    place). Read and replaced whole, so a tracker on another thread only misses."""
    global _last_pixels
    last = _last_pixels
    if last is not None and last[0] is V and last[1] is K and last[2] == shape:
        return last[3]
    found = pixel_index(project(V, K), shape[1], shape[0])
    _last_pixels = (V, K, shape, found)
    return found


def _kept(term, V: np.ndarray, compute):
    """``compute(V)``, kept in ``term._last`` for the last V: the solver asks for the energy
    and then the Gauss-Newton model at the same V (never changed in place)."""
    if term._last is None or term._last[0] is not V:
        term._last = (V, compute(V))
    return term._last[1]


@dataclass
class SmoothnessTerm:
    """Psi_S = 1/2 (X^T K X + Y^T K Y + Z^T K Z), paper eq. 10. K : (N, N) sparse."""

    K: sp.spmatrix
    name: str = "smoothness"

    def evaluate(self, V: np.ndarray):
        KV = self.K @ V
        return 0.5 * float(np.sum(V * KV)), KV


@dataclass
class CorrespondenceTerm:
    """Psi_C = 1/2 sum_j w_j ||c_j - B_j V||^2, paper eq. 13 and 19.

    B : (P, N) sparse barycentric rows, one per match
    targets : (P, 3) float64 metres, the matched 3D points c_j in the current frame
    weights : (P,) float64, 1 for inliers, 0 for rejected matches
    """

    B: sp.csr_matrix
    targets: np.ndarray
    weights: np.ndarray
    name: str = "correspondence"

    def __post_init__(self):
        self._BT = self.B.T.tocsr()  # the gradient's transpose, built once per frame

    def residuals(self, V: np.ndarray) -> np.ndarray:
        """(P,) float64 metres: distance of each match from its mesh point."""
        return np.linalg.norm(self.B @ V - self.targets, axis=1)

    def evaluate(self, V: np.ndarray):
        r = self.B @ V - self.targets
        wr = r * self.weights[:, None]
        return 0.5 * float(np.sum(wr * r)), np.asarray(self._BT @ wr)

    def gauss_newton(self, V: np.ndarray):
        """Hessian-vector product of the (already quadratic) term: P (N, 3) -> (N, 3)."""
        w = self.weights[:, None]
        return lambda P: np.asarray(self._BT @ (w * (self.B @ P)))


@dataclass
class DepthTerm:
    """Psi_D = 1/2 sum_i (||v_i|| - rho(pi(v_i)))^2 over vertices that see valid depth.

    range_m : (H, W) float32 metres, measured range (distance from the camera centre) of
        the object's surface at each pixel, 0 where unmeasured or not the object
    K : (3, 3) intrinsics; outlier_m : residuals larger than this contribute nothing
    vertex_mask : (N,) bool, the vertices the term may pull (the visible ones), or None for all
    """

    range_m: np.ndarray
    K: np.ndarray
    outlier_m: float
    vertex_mask: np.ndarray | None = None
    name: str = "depth"
    _last: tuple | None = field(default=None, init=False, repr=False)

    def lookup(self, V: np.ndarray):
        """Residual (N,) metres along each ray, the (N,) bool mask of vertices it applies to
        and the (N,) ray lengths ||v||. The solver asks for the energy and then the
        Gauss-Newton model at the same V, so the last answer is kept (V is never changed
        in place)."""
        return _kept(self, V, self._lookup)

    def _lookup(self, V: np.ndarray):
        cols, rows, inside = _pixels(V, self.K, self.range_m.shape)
        rho = self.range_m[rows, cols].astype(np.float64)
        norm = np.linalg.norm(V, axis=1)
        r = norm - rho
        active = inside & (rho > 0) & (np.abs(r) < self.outlier_m)
        if self.vertex_mask is not None:
            active &= self.vertex_mask
        return np.where(active, r, 0.0), active, norm

    def evaluate(self, V: np.ndarray):
        r, active, norm = self.lookup(V)
        grad = np.zeros_like(V)
        grad[active] = (r[active] / norm[active])[:, None] * V[active]
        return 0.5 * float(np.sum(r * r)), grad

    def gauss_newton(self, V: np.ndarray):
        """Gauss-Newton Hessian-vector product at V: rank one along each active vertex's ray."""
        _, active, norm = self.lookup(V)
        n = np.where(active[:, None], V / np.maximum(norm, 1e-12)[:, None], 0.0)
        return lambda P: n * np.einsum("ij,ij->i", n, P)[:, None]


#: How the depth term measures a vertex's distance from the measured surface: along the
#: vertex's camera ray (the paper's, ``DepthTerm``) or along the surface's normal
#: (``PlaneDepthTerm``).
DEPTH_RESIDUALS = ("ray", "plane")


def measured_surface(depth_m: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The measured surface's points and unit normals at each pixel of ``depth_m``.

    depth_m : (H, W) float32 metres, 0 where there is none (an observation's smoothed object
    depth); K : (3, 3). Returns points (H, W, 3) and normals (H, W, 3) float64 in the camera
    frame (a normal from the central differences of the points around the pixel), and
    (H, W) bool where both are known (the pixel and its four neighbours have depth).
    Only the box around the pixels with depth is computed; elsewhere the normal is unknown.
    """
    h, w = depth_m.shape
    points = np.zeros((h, w, 3))
    normals = np.zeros((h, w, 3))
    known = np.zeros((h, w), bool)
    box = bounding_box(depth_m > 0, pad=1)
    if box is None:
        return points, normals, known
    y0, y1, x0, x1 = box
    d = depth_m[y0:y1, x0:x1].astype(np.float64)
    uu, vv = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
    P = np.stack([(uu - K[0, 2]) / K[0, 0] * d, (vv - K[1, 2]) / K[1, 1] * d, d], axis=-1)
    has = d > 0
    ok = np.zeros_like(has)
    ok[1:-1, 1:-1] = has[1:-1, 1:-1] & has[1:-1, 2:] & has[1:-1, :-2] & has[2:, 1:-1] & has[:-2, 1:-1]
    n = np.zeros_like(P)
    n[1:-1, 1:-1] = np.cross(P[1:-1, 2:] - P[1:-1, :-2], P[2:, 1:-1] - P[:-2, 1:-1])
    length = np.linalg.norm(n, axis=-1)
    ok &= length > 0
    points[y0:y1, x0:x1] = P
    normals[y0:y1, x0:x1] = n / np.maximum(length, 1e-12)[..., None]
    known[y0:y1, x0:x1] = ok
    return points, normals, known


@dataclass
class PlaneDepthTerm:
    """Psi_D = 1/2 sum_i (n(pi(v_i)) . (v_i - p(pi(v_i))))^2: depth as distance to the measured
    surface's tangent plane at the vertex's pixel (point-to-plane), not along its ray.

    Not the paper's residual (``DepthTerm``). Along the ray, a vertex on a surface seen at a
    grazing angle (a cloth lifted edge-on to the camera, or hanging) is moved mostly across
    the surface, so the depth term drags material points sideways; along the surface's
    normal it is moved onto the surface and no further.

    points, normals : (H, W, 3) and known : (H, W) bool from ``measured_surface``; K : (3, 3);
    outlier_m : residuals larger than this contribute nothing; vertex_mask : as DepthTerm's
    """

    points: np.ndarray
    normals: np.ndarray
    known: np.ndarray
    K: np.ndarray
    outlier_m: float
    vertex_mask: np.ndarray | None = None
    name: str = "depth"
    _last: tuple | None = field(default=None, init=False, repr=False)

    def lookup(self, V: np.ndarray):
        """Residual (N,) metres, the (N,) bool mask of vertices it applies to and the (N, 3)
        normals there; the last answer is kept, as in ``DepthTerm.lookup``."""
        return _kept(self, V, self._lookup)

    def _lookup(self, V: np.ndarray):
        cols, rows, inside = _pixels(V, self.K, self.known.shape)
        n = self.normals[rows, cols]
        r = np.einsum("ij,ij->i", V - self.points[rows, cols], n)
        active = inside & self.known[rows, cols] & (np.abs(r) < self.outlier_m)
        if self.vertex_mask is not None:
            active &= self.vertex_mask
        return np.where(active, r, 0.0), active, np.where(active[:, None], n, 0.0)

    def evaluate(self, V: np.ndarray):
        r, _, n = self.lookup(V)
        return 0.5 * float(np.sum(r * r)), r[:, None] * n

    def gauss_newton(self, V: np.ndarray):
        """Gauss-Newton Hessian-vector product at V: rank one along each active vertex's normal."""
        _, _, n = self.lookup(V)
        return lambda P: n * np.einsum("ij,ij->i", n, P)[:, None]


class _Contour:
    """An object's contour in two parts, the outline (where the object ends) and the hidden
    stretches (where something nearer hides it or the image's border cuts it), (P, 3) and
    (Q, 3) float64 metres: which point of it is nearest, and whether that one is the
    outline's. One k-d tree over both, built at the first question (most frames of the
    outside term ask none)."""

    def __init__(self, outline_points: np.ndarray, hidden_points: np.ndarray):
        self.points = np.vstack([outline_points, hidden_points]) if len(hidden_points) else outline_points
        self.n_outline = len(outline_points)
        self._tree = None

    def nearest(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For (M, 3) points: the distance (M,) to the nearest contour point, that point
        (M, 3), and whether it lies on the outline (M,) bool. The outline must not be empty."""
        if self._tree is None:
            self._tree = cKDTree(self.points)
        dist, idx = self._tree.query(P)
        return dist, self.points[idx], idx < self.n_outline


@dataclass
class BoundaryTerm:
    """Psi_B = 1/2 sum_{i in B} (g(v_i) - g0_i)^2, paper eq. 15, with a signed distance g.

    vertex_ids : (B,) int boundary vertex ids
    g0 : (B,) float64 metres, the canonical distance of each to the outline
    outline_points : (P, 3) float64 metres, the object's outline in 3D
    mask : (H, W) bool object mask (decides the sign); K : (3, 3)
    gate_m : boundary vertices farther than this from the outline are left alone
    hidden_points : (Q, 3) float64 metres, the rest of the object's contour, where the image's
        border cuts it or something nearer hides it (``Observation.hidden_contour_cam``). A
        boundary vertex nearer to it than to the outline is left alone: it lies where the data
        do not say where the object ends, and the outline's nearest point is the end of a gap
        in it, along the object's edge, not across it.
    """

    vertex_ids: np.ndarray
    g0: np.ndarray
    outline_points: np.ndarray
    mask: np.ndarray
    K: np.ndarray
    gate_m: float
    hidden_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    name: str = "boundary"

    def __post_init__(self):
        self._contour = _Contour(self.outline_points, self.hidden_points)
        self._last = None

    def signed_distance(self, V: np.ndarray):
        """For each boundary vertex: signed distance (B,), offset v - q (B, 3), sign (B,), active (B,).
        The last answer is kept, as in ``DepthTerm.lookup``."""
        return _kept(self, V, self._signed_distance)

    def _signed_distance(self, V: np.ndarray):
        n = len(self.vertex_ids)
        if not len(self.outline_points) or n == 0:
            z = np.zeros(n)
            return z, np.zeros((n, 3)), np.ones(n), np.zeros(n, bool)
        vb = V[self.vertex_ids]
        dist, nearest, own = self._contour.nearest(vb)
        offset = vb - nearest
        cols, rows, inside = (a[self.vertex_ids] for a in _pixels(V, self.K, self.mask.shape))
        sign = np.where(inside & self.mask[rows, cols], 1.0, -1.0)
        active = (dist < self.gate_m) & (dist > 1e-12) & own
        return sign * dist, offset, sign, active

    def evaluate(self, V: np.ndarray):
        s, offset, sign, active = self.signed_distance(V)
        r = np.where(active, s - self.g0, 0.0)
        grad = np.zeros_like(V)
        dist = np.abs(s)
        with np.errstate(invalid="ignore", divide="ignore"):
            g = (r * sign / np.where(active, dist, 1.0))[:, None] * offset
        grad[self.vertex_ids[active]] = g[active]  # boundary ids are unique
        return 0.5 * float(np.sum(r * r)), grad

    def gauss_newton(self, V: np.ndarray):
        """Gauss-Newton Hessian-vector product at V: rank one along each vertex's offset from the outline."""
        s, offset, _, active = self.signed_distance(V)
        u = np.zeros((len(V), 3))
        dist = np.maximum(np.abs(s), 1e-12)[:, None]
        u[self.vertex_ids[active]] = (offset / dist)[active]
        return lambda P: u * np.einsum("ij,ij->i", u, P)[:, None]


@dataclass
class OutsideTerm:
    """Psi_O = 1/2 sum_{i seen outside the object} ||v_i - q_i||^2, q_i the nearest outline point.

    Not in the paper. A vertex the camera sees where the segmented object is not (the
    empty table where the cloth lay before it was lifted) has no depth there and, unless it
    is a boundary vertex near the outline, no other pull: the part of a mesh left behind
    stays behind, held only by the stretch of its edges. This pulls every such vertex to
    the object's outline; a vertex hidden behind something nearer is not seen and not pulled.
    Nor is one on a pixel without measured depth (``measured``): the segmentation may have
    missed the cloth there (a part of the table's colour, seen at a grazing angle, loses its
    depth), unless nothing there had depth before (the tracker's ``_open``).

    With ``free_space_m``, only the vertices the camera sees past are pulled: those whose
    pixel shows a surface more than ``free_space_m`` behind them in ``depth_m``. Nothing can
    lie there, or the camera would see it instead of that surface, so this needs no
    segmentation to trust (``MeshTracker``'s free-space term, ``TrackerConfig.lambda_f``):
    a corner the mesh left in the air when a gripper carried the cloth's corner away, in front
    of a wall far behind, is brought back; a vertex left on the table the cloth lay on, which
    the table's depth explains, is not.

    outline_points : (P, 3) float64 metres, the object's outline in 3D
    mask : (H, W) bool object mask; K : (3, 3)
    vertex_mask : (N,) bool, the vertices seen (the only ones the term may pull)
    measured : (H, W) bool, the pixels a seen vertex may be pulled from (those with measured
        depth, or where depth is missing for want of any surface), or None for all
    depth_m : (H, W) float metres, the frame's depth (0 or NaN: missing); needed with ``free_space_m``
    free_space_m : float > 0 or None: pull only the vertices seen past by more than this
    hidden_points : (Q, 3) float64 metres, the rest of the object's contour, where the image's
        border cuts it or something nearer hides it (``Observation.hidden_contour_cam``). A
        vertex nearer to it than to the outline is not pulled: it may lie behind what hides
        the object there (a gripper holding the cloth's corner), and the outline's nearest
        point is elsewhere along the object's edge, not where the vertex belongs.
    """

    outline_points: np.ndarray
    mask: np.ndarray
    K: np.ndarray
    vertex_mask: np.ndarray
    measured: np.ndarray | None = None
    depth_m: np.ndarray | None = None
    free_space_m: float | None = None
    hidden_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    name: str = "outside"

    def __post_init__(self):
        if self.free_space_m is not None and (self.depth_m is None or not self.free_space_m > 0):
            raise ValueError(f"OutsideTerm: free_space_m needs a positive value and depth_m, got {self.free_space_m!r} "
                             f"and {'no' if self.depth_m is None else 'a'} depth image")
        self._contour = _Contour(self.outline_points, self.hidden_points)
        self._last = None

    def offsets(self, V: np.ndarray) -> np.ndarray:
        """(N, 3) v_i - q_i for the vertices seen outside the object (and, with
        ``free_space_m``, seen past), 0 for the others. The last answer is kept, as in
        ``DepthTerm.lookup``."""
        return _kept(self, V, self._offsets)

    def _offsets(self, V: np.ndarray) -> np.ndarray:
        out = np.zeros_like(V)
        if len(self.outline_points):
            cols, rows, inside = _pixels(V, self.K, self.mask.shape)
            outside = self.vertex_mask & inside & ~self.mask[rows, cols]
            if self.measured is not None:
                outside &= self.measured[rows, cols]
            if self.free_space_m is not None:
                with np.errstate(invalid="ignore"):
                    d = np.asarray(self.depth_m)[rows, cols]
                    outside &= (d > 0) & (d > V[:, 2] + self.free_space_m)
            if outside.any():
                _, nearest, own = self._contour.nearest(V[outside])
                ids = np.flatnonzero(outside)[own]
                out[ids] = V[ids] - nearest[own]
        return out

    def evaluate(self, V: np.ndarray):
        D = self.offsets(V)
        return 0.5 * float(np.sum(D * D)), D

    def gauss_newton(self, V: np.ndarray):
        pulled = np.any(self.offsets(V) != 0, axis=1)[:, None]
        return lambda P: np.where(pulled, P, 0.0)


@dataclass
class StretchTerm:
    """Psi_L = 1/2 sum_(i,j) (||v_i - v_j|| - l_ij)^2 over the mesh edges: cloth barely stretches.

    Not in the paper, whose smoothness term (second differences) does not resist a mesh
    shrinking evenly: while the features hold it, that costs nothing, but a cloth that
    turns away from the camera (lifted off a table, hanging) loses its features and its
    mesh contracts onto the part still seen. Keeping edge lengths makes the mesh fold away
    instead, its hidden part carried by the motion prior.

    edges : (E, 2) int64 vertex ids; lengths : (E,) float64 metres, rest lengths
    n_vertices : N, the mesh's vertex count (0: one more than the largest id in ``edges``)
    Gauss-Newton model: each edge's residual linearised along its current direction.
    Built once per mesh: the solver applies the model tens of times a frame, through the
    sparse edge-incidence matrix (scatter-adds over the edges cost several times more).
    """

    edges: np.ndarray
    lengths: np.ndarray
    name: str = "stretch"
    n_vertices: int = 0
    _incidence: sp.csr_matrix = field(init=False, repr=False)
    _incidence_t: sp.csr_matrix = field(init=False, repr=False)
    _last: tuple | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        E = len(self.edges)
        n = max(int(self.n_vertices), int(self.edges.max()) + 1 if E else 0)
        rows = np.repeat(np.arange(E), 2)
        self._incidence = sp.csr_matrix((np.tile([1.0, -1.0], E), (rows, self.edges.reshape(-1))), shape=(E, n))
        self._incidence_t = self._incidence.T.tocsr()  # row-major both ways: a transposed view is slower

    def _parts(self, V: np.ndarray):
        """(E, 3) unit edge directions and (E,) residuals; the last answer is kept, as in
        ``DepthTerm.lookup``."""
        return _kept(self, V, self._compute_parts)

    def _compute_parts(self, V: np.ndarray):
        d = self._incidence @ V
        n = np.linalg.norm(d, axis=1)
        u = d / np.maximum(n, 1e-12)[:, None]
        return u, n - self.lengths

    def evaluate(self, V: np.ndarray):
        u, r = self._parts(V)
        return 0.5 * float(np.sum(r * r)), self._incidence_t @ (r[:, None] * u)

    def gauss_newton(self, V: np.ndarray):
        u, _ = self._parts(V)

        def apply(P: np.ndarray) -> np.ndarray:
            along = np.einsum("ij,ij->i", u, self._incidence @ P)
            return self._incidence_t @ (along[:, None] * u)

        return apply


@dataclass
class HoldTerm:
    """Psi_H = 1/2 sum_k ||v_{i_k} - h_k||^2: vertices held by the robot, at its grippers.

    Not in the paper. A robot knows where its grippers are (its kinematics) and which
    vertex of the mesh each one closed on (the grasp it planned): a correspondence as sure
    as the kinematics, which holds the mesh where the cloth is held while the gripper
    itself hides that part from the camera.

    ids : (K,) int64 held vertices; points : (K, 3) float64 metres, where they are held
    """

    ids: np.ndarray
    points: np.ndarray
    name: str = "hold"

    def evaluate(self, V: np.ndarray):
        D = V[self.ids] - self.points
        G = np.zeros_like(V)
        np.add.at(G, self.ids, D)
        return 0.5 * float(np.sum(D * D)), G

    def gauss_newton(self, V: np.ndarray):
        def apply(P: np.ndarray) -> np.ndarray:
            out = np.zeros_like(P)
            np.add.at(out, self.ids, P[self.ids])
            return out

        return apply


@dataclass
class MotionPriorTerm:
    """Psi_M = 1/2 sum_{(i,j)} ||(v_i - v_j) - (p_i - p_j)||^2 + 1/2 anchor sum_i ||v_i - p_i||^2.

    The first sum runs over the mesh edges that touch an unobserved vertex, the second over
    the unobserved vertices: the unobserved part keeps the shape it has in the prior P (the
    mesh predicted from the previous frames) and moves with its observed neighbours, which
    the data place. Quadratic in V, so its Gauss-Newton model is exact.

    L : (N, N) sparse, the term's Hessian (edge Laplacian plus the anchor on the diagonal)
    prior : (N, 3) float64 metres, P
    """

    L: sp.csr_matrix
    prior: np.ndarray
    name: str = "motion_prior"

    @classmethod
    def around(cls, edges: np.ndarray, unobserved: np.ndarray, prior: np.ndarray, anchor: float = 0.05):
        """The term for ``unobserved`` (N,) bool vertices, over mesh ``edges`` (E, 2) int."""
        n = len(prior)
        e = edges[unobserved[edges[:, 0]] | unobserved[edges[:, 1]]]
        rows = np.tile(np.arange(len(e)), 2)
        values = np.concatenate([np.ones(len(e)), -np.ones(len(e))])
        A = sp.csr_matrix((values, (rows, np.concatenate([e[:, 0], e[:, 1]]))), shape=(len(e), n))  # v_i - v_j
        L = (A.T @ A + sp.diags(anchor * unobserved.astype(np.float64))).tocsr()
        return cls(L, np.asarray(prior, np.float64))

    def evaluate(self, V: np.ndarray):
        D = V - self.prior
        LD = self.L @ D
        return 0.5 * float(np.sum(D * LD)), LD

    def gauss_newton(self, V: np.ndarray):
        return lambda P: self.L @ P
