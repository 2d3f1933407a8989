"""A held cloth's reach: no material point farther from a held one than along the cloth.

Cloth hardly stretches, so a point of it can never be farther (in space) from a point the
robot holds than the shortest path between the two along the cloth. The tracker's data
terms do not know this: during a lift most of the cloth turns away from the camera, and
the vertices without data are carried by smoothness and a motion prior, which let them
trail far below or beside the gripper. Cloth simulators keep such long-range limits as
"tethers" (long-range attachments); here they are a projection: each vertex beyond its
limit from a held point is moved straight towards that point onto the limit.

Data form: vertices (N, 3) float64 metres, any one frame (the tracker's: camera); held ids
(H,) int into them and the held points (H, 3) float64 in the same frame; the mesh as it was
laid on the object (rest vertices (N, 3) metres and faces (F, 3) int).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra

from perception.geometry import edge_length_graph


class Tethers:
    """Shortest distances along a mesh from the vertices it is held by, and the projection.

    rest_vertices : (N, 3) float metres, the mesh as laid on the object (its edges' lengths
        are the cloth's); faces : (F, 3) int
    The distances from each held vertex are computed once and kept (a robot holds the same
    few points for many frames).
    """

    def __init__(self, rest_vertices: np.ndarray, faces: np.ndarray):
        self._graph = edge_length_graph(rest_vertices, faces)
        self._along: dict[int, np.ndarray] = {}

    def along(self, vertex: int) -> np.ndarray:
        """(N,) float64 metres: each vertex's shortest distance to ``vertex`` along the mesh
        (inf: not joined to it)."""
        vertex = int(vertex)
        if vertex not in self._along:
            self._along[vertex] = dijkstra(self._graph, directed=False, indices=vertex)
        return self._along[vertex]

    def apply(self, vertices: np.ndarray, held_ids: np.ndarray, held_points_m: np.ndarray, slack: float) -> np.ndarray:
        """(N, 3) float64: ``vertices`` with every vertex farther from a held point than
        (1 + ``slack``) times its distance along the mesh (the mesh's own stretch, and its
        paths along edges, a little longer than straight on the cloth) moved towards that
        point onto that reach, one held point after the other."""
        if not (np.isfinite(slack) and slack >= 0):
            raise ValueError(f"Tethers.apply: slack must be a non-negative number, got {slack!r}")
        V = np.array(vertices, dtype=np.float64, copy=True)
        for vertex, point in zip(np.asarray(held_ids).reshape(-1), np.asarray(held_points_m, np.float64).reshape(-1, 3)):
            limit = (1.0 + slack) * self.along(vertex)
            offset = V - point
            distance = np.linalg.norm(offset, axis=1)
            over = distance > limit
            if over.any():
                V[over] = point + offset[over] * (limit[over] / distance[over])[:, None]
        return V
