"""The canonical mesh: a hexagonal grid of equilateral triangles (paper, section III-A).

Vertices live on a triangular lattice with spacing ``s`` in a flat 2D "material" frame:
vertex (q, r) sits at ``q * a + r * b`` with ``a = (s, 0)`` and ``b = (s/2, s*sqrt(3)/2)``.
On that lattice the collinear, equidistant triplets E of the paper are the three lattice
directions a, b and b - a, and interior vertices have exactly six neighbours.

A mesh is built by keeping the lattice vertices for which a predicate holds (inside a
rectangle of known size, or whose lifted position falls on the object's mask), keeping
the triangles whose three corners survive, and the largest connected piece.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from perception.geometry import unique_edges

SQRT3_2 = math.sqrt(3.0) / 2.0
_DIRECTIONS = np.array([[1, 0], [0, 1], [-1, 1]])  # lattice steps a, b, b - a


@dataclass(frozen=True)
class CanonicalMesh:
    """A triangulated hexagonal grid and the matrices of its smoothness term.

    lattice : (N, 2) int64 lattice coordinates (q, r) of each vertex
    spacing_m : edge length of the equilateral triangles, metres
    faces : (M, 3) int32 vertex ids, counter-clockwise in the material frame
    triplets : (E, 3) int32 collinear equidistant vertex triplets (i, j, k), j in the middle
    boundary : (B,) int32 ids of vertices with fewer than six neighbours
    """

    lattice: np.ndarray
    spacing_m: float
    faces: np.ndarray
    triplets: np.ndarray
    boundary: np.ndarray

    @property
    def n_vertices(self) -> int:
        return int(self.lattice.shape[0])

    @property
    def material_xy(self) -> np.ndarray:
        """(N, 2) float64, metres: vertex positions in the flat material frame."""
        return lattice_to_xy(self.lattice, self.spacing_m)

    @property
    def canonical(self) -> np.ndarray:
        """(N, 3) float64, metres: the flat canonical mesh in its own z = 0 plane."""
        xy = self.material_xy
        return np.column_stack([xy, np.zeros(len(xy))])

    def edges(self) -> np.ndarray:
        """(E, 2) int32 unique undirected edges, i < j."""
        return unique_edges(self.faces).astype(np.int32)

    def k_col(self) -> sp.csr_matrix:
        """(E, N) sparse second-difference matrix, rows (1, -2, 1) on each triplet (paper eq. 9)."""
        return second_difference_matrix(self.triplets, self.n_vertices)

    def stiffness(self) -> sp.csc_matrix:
        """(N, N) sparse ``K = Kcol^T Kcol`` (paper eq. 10)."""
        kc = self.k_col()
        return (kc.T @ kc).tocsc()


def lattice_to_xy(lattice: np.ndarray, spacing_m: float) -> np.ndarray:
    """(N, 2) int lattice coordinates to (N, 2) float64 metres in the material frame."""
    q = lattice[:, 0].astype(np.float64)
    r = lattice[:, 1].astype(np.float64)
    return np.column_stack([(q + 0.5 * r) * spacing_m, r * SQRT3_2 * spacing_m])


def lattice_covering(x_range: tuple[float, float], y_range: tuple[float, float], spacing_m: float) -> np.ndarray:
    """All lattice points whose material position lies in the box (with one spacing of margin).

    returns (N, 2) int64 lattice coordinates (q, r)
    """
    if not spacing_m > 0:
        raise ValueError(f"spacing_m must be positive, got {spacing_m}")
    x0, x1 = x_range
    y0, y1 = y_range
    h = SQRT3_2 * spacing_m
    r = np.arange(math.floor(y0 / h) - 1, math.ceil(y1 / h) + 2)
    qs = []
    for ri in r:
        q = np.arange(math.floor(x0 / spacing_m - 0.5 * ri) - 1, math.ceil(x1 / spacing_m - 0.5 * ri) + 2)
        qs.append(np.column_stack([q, np.full(len(q), ri)]))
    return np.concatenate(qs).astype(np.int64)


def mesh_from_lattice(lattice: np.ndarray, spacing_m: float) -> CanonicalMesh:
    """Triangulate kept lattice points; keep the largest connected piece.

    lattice : (N, 2) int lattice coordinates of the kept vertices
    raises ValueError when fewer than one triangle survives
    """
    lattice = np.asarray(lattice, dtype=np.int64)
    if lattice.ndim != 2 or lattice.shape[1] != 2:
        raise ValueError(f"lattice: expected shape (N, 2), got {lattice.shape}")
    index = {(int(q), int(r)): i for i, (q, r) in enumerate(lattice)}

    def ids(offset):
        return np.array([index.get((int(q) + offset[0], int(r) + offset[1]), -1) for q, r in lattice])

    right, up, up_left = ids((1, 0)), ids((0, 1)), ids((-1, 1))
    here = np.arange(len(lattice))
    # Each triangle is listed once, from its lowest corner (q, r): the "up" triangle
    # (q,r) (q+1,r) (q,r+1) and the "down" triangle (q,r) (q,r+1) (q-1,r+1).
    tri_up = np.column_stack([here, right, up])
    tri_dn = np.column_stack([here, up, up_left])
    faces = np.concatenate([tri_up, tri_dn])
    faces = faces[np.all(faces >= 0, axis=1)]
    if len(faces) == 0:
        raise ValueError("no triangle fits: the object is smaller than one mesh cell (reduce spacing_m)")

    # Largest connected piece (through shared triangle edges' vertices).
    n = len(lattice)
    e = unique_edges(faces)
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, labels = connected_components(adj, directed=False)
    used = np.zeros(n, bool)
    used[faces.ravel()] = True
    counts = np.bincount(labels[used], minlength=labels.max() + 1)
    keep = used & (labels == np.argmax(counts))

    new_id = np.full(n, -1, np.int64)
    new_id[keep] = np.arange(keep.sum())
    faces = new_id[faces]
    faces = faces[np.all(faces >= 0, axis=1)].astype(np.int32)
    lattice = lattice[keep]
    return _finish(lattice, spacing_m, faces)


def _finish(lattice: np.ndarray, spacing_m: float, faces: np.ndarray) -> CanonicalMesh:
    n = len(lattice)
    index = {(int(q), int(r)): i for i, (q, r) in enumerate(lattice)}
    edges = unique_edges(faces)
    degree = np.bincount(edges.ravel(), minlength=n)
    edge_set = {(int(i), int(j)) for i, j in edges}

    def connected(i, j):
        return (min(i, j), max(i, j)) in edge_set

    triplets = []
    for j, (q, r) in enumerate(lattice):
        for dq, dr in _DIRECTIONS:
            i = index.get((int(q) - dq, int(r) - dr))
            k = index.get((int(q) + dq, int(r) + dr))
            # Both edges must exist in the mesh, not only the vertices (a notch in the
            # outline can leave two lattice neighbours unconnected).
            if i is not None and k is not None and connected(i, j) and connected(j, k):
                triplets.append((i, j, k))
    triplets = np.array(triplets, dtype=np.int32).reshape(-1, 3)
    boundary = np.flatnonzero(degree < 6).astype(np.int32)
    return CanonicalMesh(lattice=lattice, spacing_m=float(spacing_m), faces=faces, triplets=triplets, boundary=boundary)


def rectangle_mesh(width_m: float, height_m: float, spacing_m: float) -> CanonicalMesh:
    """Canonical mesh of a ``width_m`` x ``height_m`` rectangle, built off-line.

    The material frame has its origin at the rectangle's corner; x along the width,
    y along the height. Every vertex lies inside the rectangle (rows alternate between
    starting at 0 and at s/2, so the side edges are ragged by half a spacing).
    """
    for name, value in (("width_m", width_m), ("height_m", height_m), ("spacing_m", spacing_m)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value}")
    lat = lattice_covering((0.0, width_m), (0.0, height_m), spacing_m)
    xy = lattice_to_xy(lat, spacing_m)
    eps = 1e-9 * spacing_m
    inside = (xy[:, 0] >= -eps) & (xy[:, 0] <= width_m + eps) & (xy[:, 1] >= -eps) & (xy[:, 1] <= height_m + eps)
    return mesh_from_lattice(lat[inside], spacing_m)


def material_reach(canonical: np.ndarray, vertices) -> np.ndarray:
    """(K,) float64 metres: for each of ``vertices`` (K,) int, the largest distance from it to
    any vertex of the ``canonical`` (N, 3) mesh, at rest. No part of a cloth held there hangs
    farther from the hand, since cloth does not stretch."""
    rest = np.asarray(canonical, dtype=np.float64)
    ids = np.atleast_1d(np.asarray(vertices, dtype=np.int64))
    return np.array([np.linalg.norm(rest - rest[v], axis=1).max() for v in ids])


def second_difference_matrix(triplets: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(E, N) sparse matrix with (1, -2, 1) at columns (i, j, k) of each triplet row."""
    t = np.asarray(triplets)
    rows = np.repeat(np.arange(len(t)), 3)
    vals = np.tile([1.0, -2.0, 1.0], len(t))
    return sp.csr_matrix((vals, (rows, t.ravel())), shape=(len(t), n_vertices))


def barycentric_2d(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of 2D points in 2D triangles (paper eq. 11).

    points : (P, 2) float
    triangles : (P, 3, 2) float, the triangle each point is expressed in
    returns (P, 3) float64, rows sum to 1; NaN for degenerate triangles
    """
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.float64)
    a = t[:, 0] - t[:, 2]
    b = t[:, 1] - t[:, 2]
    d = p - t[:, 2]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        bi = (d[:, 0] * b[:, 1] - d[:, 1] * b[:, 0]) / det
        bj = (a[:, 0] * d[:, 1] - a[:, 1] * d[:, 0]) / det
    return np.column_stack([bi, bj, 1.0 - bi - bj])


def locate_in_faces(points: np.ndarray, vertices_2d: np.ndarray, faces: np.ndarray,
                    vertex_depth: np.ndarray | None = None, chunk: int = 256):
    """Find the face containing each 2D point.

    points : (P, 2) float; vertices_2d : (N, 2) float; faces : (M, 3) int
    vertex_depth : (N,) float, optional; where faces overlap (a folded projection) the face
        nearest the camera at the point wins; without it, the first containing face
    returns (face_ids (P,) int64, -1 where no face contains the point; bary (P, 3) float64)
    """
    p = np.asarray(points, dtype=np.float64)
    tri = vertices_2d[faces]  # (M, 3, 2)
    face_ids = np.full(len(p), -1, np.int64)
    bary = np.zeros((len(p), 3))
    a = tri[:, 0] - tri[:, 2]
    b = tri[:, 1] - tri[:, 2]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    ok = np.abs(det) > 1e-12
    for s in range(0, len(p), chunk):
        d = p[s : s + chunk, None, :] - tri[None, :, 2]  # (c, M, 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            bi = (d[..., 0] * b[None, :, 1] - d[..., 1] * b[None, :, 0]) / det
            bj = (a[None, :, 0] * d[..., 1] - a[None, :, 1] * d[..., 0]) / det
        bk = 1.0 - bi - bj
        eps = -1e-9
        inside = ok[None, :] & (bi >= eps) & (bj >= eps) & (bk >= eps)
        has = inside.any(axis=1)
        if vertex_depth is None:
            first = np.argmax(inside, axis=1)
        else:
            zf = vertex_depth[faces]  # (M, 3)
            z = bi * zf[None, :, 0] + bj * zf[None, :, 1] + bk * zf[None, :, 2]
            first = np.argmin(np.where(inside, z, np.inf), axis=1)
        rows = np.arange(len(d))
        face_ids[s : s + chunk] = np.where(has, first, -1)
        bary[s : s + chunk] = np.column_stack([bi[rows, first], bj[rows, first], bk[rows, first]])
    return face_ids, bary


def barycentric_matrix(face_ids: np.ndarray, bary: np.ndarray, faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(P, N) sparse matrix B with ``B @ V`` = the points ``T_V`` of paper eq. 12/19."""
    cols = faces[face_ids].ravel()
    rows = np.repeat(np.arange(len(face_ids)), 3)
    return sp.csr_matrix((np.asarray(bary).ravel(), (rows, cols)), shape=(len(face_ids), n_vertices))

