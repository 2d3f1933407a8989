"""Accuracy of an estimated mesh against the simulated cloth (pure NumPy).

Each estimated vertex is bound at frame 0 to its closest point on the true cloth
surface (a true triangle and barycentric coordinates in it); at frame t its error is
the distance to where that material point has moved. Errors are reported as mean and
95th percentile in millimetres.

Under occlusion (``hidden_behind_occluder``, ``occluded_area_ratio``): an estimated
vertex is truly hidden when its material point projects onto the occluder's exact mask
and lies behind the occluder there; the faces whose three vertices are hidden are the
occluded part of the mesh, and their area, over the same faces' area where their material
points truly are, tells whether that part kept its size.

Arrays: points and vertices are (N, 3) / (T, N, 3) float, metres, all in one frame
(the camera frame for recorded sequences); faces are (F, 3) int vertex ids.
"""

from __future__ import annotations

import logging

import numpy as np

from perception.geometry import check_ids, check_points, face_areas, pixel_index, project

log = logging.getLogger(__name__)

# pairs (point, triangle) evaluated at once in bind_to_surface, bounds memory to ~100 MB
_PAIRS_PER_CHUNK = 400_000


def _check_vertex_stack(name: str, vertices) -> np.ndarray:
    """``vertices`` as a finite (T, N, 3) float64 array of T frames, else ValueError naming it."""
    arr = np.asarray(vertices, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"Expected {name} with shape (T, N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"Expected {name} with finite values, got NaN or infinity")
    return arr


def closest_point_barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of the point of triangle (a, b, c) closest to p.

    p, a, b, c : (..., 3) float, broadcastable
    returns (..., 3) float64 weights (wa, wb, wc) >= 0 summing to 1; the closest point is
    ``wa * a + wb * b + wc * c``

    Voronoi-region test of Ericson, Real-Time Collision Detection, 5.1.5: the regions of
    the vertices, then of the edges, then the interior, decided by dot products only.
    """
    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = _safe_ratio(d1, d1 - d3)
        t_ac = _safe_ratio(d2, d2 - d6)
        t_bc = _safe_ratio(d4 - d3, (d4 - d3) + (d5 - d6))
        total = va + vb + vc
        v_in = _safe_ratio(vb, total)
        w_in = _safe_ratio(vc, total)

    zero = np.zeros_like(d1)
    one = np.ones_like(d1)
    conditions = [
        (d1 <= 0) & (d2 <= 0),  # vertex a
        (d3 >= 0) & (d4 <= d3),  # vertex b
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),  # edge ab
        (d6 >= 0) & (d5 <= d6),  # vertex c
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),  # edge ac
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),  # edge bc
    ]
    wa = np.select(conditions, [one, zero, 1 - t_ab, zero, 1 - t_ac, zero], default=1 - v_in - w_in)
    wb = np.select(conditions, [zero, one, t_ab, zero, zero, 1 - t_bc], default=v_in)
    wc = np.select(conditions, [zero, zero, zero, one, t_ac, t_bc], default=w_in)
    return np.stack([wa, wb, wc], axis=-1)


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.sum(x * y, axis=-1)


def _safe_ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den, 0 where den is 0 (degenerate triangles: any point of them will do)."""
    return np.where(den != 0, num / np.where(den != 0, den, 1.0), 0.0)


def bind_to_surface(points: np.ndarray, gt_vertices: np.ndarray, gt_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on a triangle mesh for each point, as triangle and barycentrics.

    points : (N, 3) float, metres
    gt_vertices : (V, 3) float, metres, same frame
    gt_faces : (F, 3) int vertex ids
    returns tri_ids (N,) int64 and bary (N, 3) float64 (weights of the triangle's
    vertices, >= 0, summing to 1)
    """
    pts = check_points("points", points, allow_empty=True)
    verts = check_points("gt_vertices", gt_vertices, allow_empty=True)
    faces = check_ids("gt_faces", gt_faces, len(verts), ndim=2)
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    tri_ids = np.empty(len(pts), np.int64)
    bary = np.empty((len(pts), 3))
    chunk = max(1, _PAIRS_PER_CHUNK // len(faces))
    for start in range(0, len(pts), chunk):
        p = pts[start:start + chunk, None, :]
        w = closest_point_barycentric(p, a[None], b[None], c[None])  # (n, F, 3)
        closest = w[..., :1] * a + w[..., 1:2] * b + w[..., 2:] * c
        dist2 = np.sum((closest - p) ** 2, axis=-1)
        best = np.argmin(dist2, axis=1)
        tri_ids[start:start + chunk] = best
        bary[start:start + chunk] = w[np.arange(len(best)), best]
    return tri_ids, bary


def surface_points(vertices: np.ndarray, faces: np.ndarray, tri_ids: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Material points on a mesh from triangle ids and barycentric coordinates.

    vertices : (V, 3) or (T, V, 3) float; faces : (F, 3) int; tri_ids : (N,) int;
    bary : (N, 3) float
    returns (N, 3) or (T, N, 3) float64
    """
    v = np.asarray(vertices, dtype=np.float64)
    corners = v[..., np.asarray(faces)[np.asarray(tri_ids)], :]  # (..., N, 3, 3)
    return np.einsum("...nkd,nk->...nd", corners, np.asarray(bary, dtype=np.float64))


def material_point_tracks(first_vertices: np.ndarray, gt_vertices: np.ndarray, gt_faces: np.ndarray) -> np.ndarray:
    """Where the true cloth's material points under a mesh's first-frame vertices move.

    first_vertices : (N, 3) float, metres, the estimated mesh in the first frame
    gt_vertices : (T, V, 3) float, metres, true cloth per frame (the first is bound to)
    gt_faces : (F, 3) int
    returns (T, N, 3) float64: each vertex's closest point on the first true surface,
    followed through the frames as a material point (triangle and barycentrics fixed)
    """
    first = check_points("first_vertices", first_vertices, allow_empty=True)
    gt = _check_vertex_stack("gt_vertices", gt_vertices)
    if gt.shape[0] == 0:
        raise ValueError("material_point_tracks: expected at least one frame of gt_vertices, got 0")
    tri_ids, bary = bind_to_surface(first, gt[0], gt_faces)
    return surface_points(gt, gt_faces, tri_ids, bary)


def vertex_errors(est_vertices: np.ndarray, gt_vertices: np.ndarray, gt_faces: np.ndarray) -> np.ndarray:
    """Distance of each estimated vertex to its material point on the true cloth.

    est_vertices : (T, N, 3) float, metres, estimated mesh per frame
    gt_vertices : (T, V, 3) float, metres, true cloth per frame, same frame and timing
    gt_faces : (F, 3) int
    returns (T, N) float64 metres; each estimated vertex is bound at frame 0 to its
    closest point on the true surface and followed as that material point moves
    """
    est = _check_vertex_stack("est_vertices", est_vertices)
    gt = _check_vertex_stack("gt_vertices", gt_vertices)
    if est.shape[0] != gt.shape[0]:
        raise ValueError(f"vertex_errors: est_vertices has {est.shape[0]} frames, gt_vertices {gt.shape[0]}")
    if est.shape[0] == 0:
        raise ValueError("vertex_errors: expected at least one frame, got 0")
    return np.linalg.norm(est - material_point_tracks(est[0], gt, gt_faces), axis=-1)


def hidden_behind_occluder(points_cam: np.ndarray, occluder_mask: np.ndarray, occluder_depth_m: np.ndarray,
                           K: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
    """Which points an occluder hides from the camera.

    points_cam : (N, 3) float, metres, camera optical frame (e.g. material points of the
        true cloth)
    occluder_mask : (H, W) bool, where the occluder is seen (exact, before noise)
    occluder_depth_m : (H, W) float, metres, the occluder's depth where it is seen
    K : (3, 3) pinhole intrinsics; margin_m : a point must lie this far behind
    returns (N,) bool: the point projects (to the nearest pixel centre) onto the mask and
    lies behind the occluder there; points outside the image or behind the camera are not
    hidden by it
    """
    pts = check_points("points_cam", points_cam, allow_empty=True)
    mask = np.asarray(occluder_mask, dtype=bool)
    depth = np.asarray(occluder_depth_m, dtype=np.float64)
    if mask.ndim != 2 or depth.shape != mask.shape:
        raise ValueError(f"hidden_behind_occluder: expected an (H, W) mask and depth of one shape, got "
                         f"{mask.shape} and {depth.shape}")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"hidden_behind_occluder: expected K of shape (3, 3), got {K.shape}")
    H, W = mask.shape
    cols, rows, inside = pixel_index(project(pts, K), W, H)
    hidden = np.zeros(len(pts), bool)
    c, r = cols[inside], rows[inside]
    hidden[inside] = mask[r, c] & (pts[inside, 2] > depth[r, c] + float(margin_m))
    return hidden


def occluded_area_ratio(vertices: np.ndarray, reference: np.ndarray, faces: np.ndarray,
                        hidden: np.ndarray) -> tuple[float, float]:
    """Does the occluded part of an estimated mesh keep its area?

    vertices : (N, 3) the estimate in one frame; reference : (N, 3) where its vertices'
    material points truly are in that frame (``material_point_tracks``), or the tracker's
    rest mesh; faces : (F, 3) int; hidden : (N,) bool, the vertices truly hidden
    (``hidden_behind_occluder``)
    returns (ratio, reference_area_m2): the summed area of the faces whose three vertices are
    hidden, over the same faces' area in ``reference``; (nan, 0.0) when no face is hidden.
    1 means the hidden part has its true size; below 1 it was squeezed, above stretched.
    Against the true positions rather than the rest mesh, cloth that is really bunched
    (in a gripper's fingers, or crumpled) does not count as squeezed.
    """
    hid = np.asarray(hidden, dtype=bool)
    v = check_points("vertices", vertices, allow_empty=True)
    if hid.shape != (len(v),):
        raise ValueError(f"occluded_area_ratio: expected hidden of shape ({len(v)},), got {hid.shape}")
    f = check_ids("faces", faces, len(v), ndim=2)
    covered = f[hid[f].all(axis=1)]
    if len(covered) == 0:
        return float("nan"), 0.0
    rest = float(face_areas(reference, covered).sum())
    if rest <= 0:
        raise ValueError("occluded_area_ratio: the hidden faces have no area in the reference")
    return float(face_areas(v, covered).sum()) / rest, rest


def error_summary(errors_m: np.ndarray) -> dict:
    """Mean, 95th percentile and maximum of errors, in millimetres.

    errors_m : (T, N) or any shape, float, metres
    returns {"mean_mm": float, "p95_mm": float, "max_mm": float, "count": int}
    """
    e = np.asarray(errors_m, dtype=np.float64).ravel()
    if e.size == 0 or not np.all(np.isfinite(e)):
        raise ValueError(f"error_summary: expected a non-empty array of finite errors, got {e.size} values")
    mm = 1000.0 * e
    return {"mean_mm": float(mm.mean()), "p95_mm": float(np.percentile(mm, 95)), "max_mm": float(mm.max()), "count": int(e.size)}
