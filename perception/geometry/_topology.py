"""Triangle-mesh topology and per-face and per-vertex geometry.

Data form: ``faces`` (F, 3) int vertex ids, counter-clockwise (right-hand rule) about the
side a normal points to; ``vertices`` (N, 3) float metres in any one frame. Edges are
(E, 2) int64 vertex-id pairs: "directed" in a face's winding, "undirected" with the
smaller id first.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def directed_edges(faces: np.ndarray) -> np.ndarray:
    """(3F, 2) int64 edges of every face in the face's winding: all (a, b), then (b, c), then (c, a)."""
    f = np.asarray(faces, dtype=np.int64)
    return np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) int64 unique undirected edges of the faces (F, 3), smaller id first, sorted."""
    return np.unique(np.sort(directed_edges(faces), axis=1), axis=0)


def edge_length_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """(N, N) sparse float64: each unique edge of the faces (F, 3) once, weighted by its
    length in ``vertices`` (N, 3); for shortest paths along the mesh (``scipy.sparse.csgraph``
    with ``directed=False``)."""
    v = np.asarray(vertices, dtype=np.float64)
    e = unique_edges(faces)
    lengths = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    return sp.coo_matrix((lengths, (e[:, 0], e[:, 1])), shape=(len(v), len(v))).tocsr()


def boundary_half_edges(faces: np.ndarray) -> np.ndarray:
    """(B, 2) int64 directed edges used by exactly one face, in that face's winding and in
    the order of ``directed_edges``. With counter-clockwise faces the mesh lies to the left
    of each."""
    directed = directed_edges(faces)
    if len(directed) == 0:
        return directed
    n = int(directed.max()) + 1
    keys = np.minimum(directed[:, 0], directed[:, 1]) * n + np.maximum(directed[:, 0], directed[:, 1])
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return directed[counts[inverse] == 1]


def boundary_chains(faces: np.ndarray) -> list[np.ndarray]:
    """The outline's loops: the boundary half-edges (``boundary_half_edges``) chained into
    closed loops, a list of int64 arrays of vertex ids (the outer loop and one per hole, in
    the faces' winding). Empty when the outline touches itself at a vertex (two triangles
    meeting only at a corner, which a grid laid over a concave outline can produce) or does
    not close (a mesh that is not a manifold there): then there is no one way to chain it."""
    half = boundary_half_edges(faces)
    if not len(half) or len(np.unique(half[:, 0])) < len(half):
        return []
    following = dict(zip(half[:, 0].tolist(), half[:, 1].tolist()))
    if set(following.values()) != set(following):
        return []
    chains, left = [], set(following)
    while left:
        start = left.pop()
        chain, v = [start], following[start]
        while v != start:
            left.discard(v)
            chain.append(v)
            v = following[v]
        chains.append(np.asarray(chain, np.int64))
    return chains


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """(B, 2) int64 undirected edges used by exactly one face (the outline), smaller id first,
    sorted. A mesh whose outline touches itself at a vertex has no single loop of them."""
    pairs = np.sort(directed_edges(faces), axis=1)
    edges, counts = np.unique(pairs, axis=0, return_counts=True)
    return edges[counts == 1]


def boundary_vertices(faces: np.ndarray) -> np.ndarray:
    """(B,) int64 sorted ids of the vertices on an edge used by only one face."""
    return np.unique(boundary_edges(faces))


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) float64 right-hand-rule normals of the faces, of length twice the face area (m^2)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    a = v[f[:, 0]]
    return np.cross(v[f[:, 1]] - a, v[f[:, 2]] - a)


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) float64 areas of the faces, square metres."""
    return 0.5 * np.linalg.norm(face_normals(vertices, faces), axis=1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, unit: bool = True) -> np.ndarray:
    """Area-weighted vertex normals, following the faces' winding.

    vertices : (N, 3) float, metres; faces : (F, 3) int
    unit : normalise each normal to unit length (else each is the sum over the vertex's
        faces of the face normal times twice the face area, m^2)
    returns (N, 3) float64; zero for a vertex without faces (or whose faces cancel)
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    normals_f = face_normals(v, f)
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, f[:, k], normals_f)
    if not unit:
        return normals
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
