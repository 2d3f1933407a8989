"""Ground truth of a laundry cloth from its construction (pure NumPy): true corners and outline.

Material coordinates ``uv`` (``sim.cloth_mesh``): metres on the flat cloth, u right, v down
from the top-left of its bounding box, so a distance is measured along the cloth whatever
its pose. The corners come from the outline's construction, never from mesh indices.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import pdist

from sim.cloth_mesh import TShirtShape


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


#: Pairs of true corners (indices into the corners of ``rectangle_corners_uv`` and
#: ``tshirt_corners_uv``) that share an edge of the cloth: what an unfolding robot
#: stretches between its two grippers. A towel's four sides; a T-shirt's hem (the two hem
#: corners) and each cuff (a sleeve end's two corners). A shirt's side seam, from a hem
#: corner past the armpit to a cuff, is not one edge.
CORNER_EDGES = {
    "towel": ((0, 1), (1, 2), (2, 3), (3, 0)),
    "tshirt": ((0, 1), (2, 3), (4, 5)),
}


def material_extent(uv_m: np.ndarray, nodes: np.ndarray) -> float:
    """The largest distance between two of ``nodes`` on the flat cloth (material coordinates), metres.

    uv_m : (V, 2) float metres, every node's material coordinates; nodes : (K,) int, e.g.
    the nodes a gripper's jaw holds. A jaw a few centimetres wide that closes on one layer
    holds nodes a few centimetres apart; one that closes on a fold's two layers holds
    material points far apart on the cloth (the two corners of a towel folded in half),
    and no stretch can pull those apart. 0 for fewer than two nodes.
    """
    uv = np.asarray(uv_m, dtype=np.float64)[np.asarray(nodes, dtype=np.int64).reshape(-1)]
    return float(pdist(uv).max()) if len(uv) >= 2 else 0.0


def share_an_edge(cloth_kind: str, corner_a: int, corner_b: int) -> bool:
    """Whether two true corners (indices) of a cloth of kind ``cloth_kind`` share an edge (``CORNER_EDGES``)."""
    if cloth_kind not in CORNER_EDGES:
        raise ValueError(f"share_an_edge: unknown cloth kind {cloth_kind!r}; expected one of {', '.join(CORNER_EDGES)}")
    return (corner_a, corner_b) in CORNER_EDGES[cloth_kind] or (corner_b, corner_a) in CORNER_EDGES[cloth_kind]
