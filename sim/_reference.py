"""Slow, obviously correct versions of the optimised kernels, for tests only."""

from __future__ import annotations

import numpy as np


def _closest_on_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    denom = ab @ ab
    t = 0.0 if denom == 0 else float(np.clip((p - a) @ ab / denom, 0.0, 1.0))
    return a + t * ab


def closest_point_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The point of triangle (a, b, c) nearest to p, all (3,) float.

    The nearest point is either p's projection on the triangle's plane, when that lies
    inside the triangle, or the nearest point of one of the three edges.
    """
    candidates = [_closest_on_segment(p, a, b), _closest_on_segment(p, b, c), _closest_on_segment(p, c, a)]
    n = np.cross(b - a, c - a)
    area2 = n @ n
    if area2 > 0:
        q = p - ((p - a) @ n) / area2 * n
        # inside when q is on the same side of all three edges as the triangle
        inside = all(np.cross(y - x, q - x) @ n >= 0 for x, y in ((a, b), (b, c), (c, a)))
        if inside:
            candidates.append(q)
    return min(candidates, key=lambda x: float(np.sum((x - p) ** 2)))


def bind_to_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) closest point on the mesh to each point, by trying every triangle."""
    out = []
    for p in np.asarray(points, dtype=np.float64):
        best = None
        for f in np.asarray(faces):
            q = closest_point_on_triangle(p, *np.asarray(vertices, dtype=np.float64)[f])
            if best is None or np.sum((q - p) ** 2) < np.sum((best - p) ** 2):
                best = q
        out.append(best)
    return np.array(out)


def rasterise_depth(points_cam: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H, W) depth of the nearest triangle whose projection covers each pixel centre, 0 if none.

    Pixel by pixel and triangle by triangle: the pixel centre's barycentric coordinates
    in the projected triangle decide coverage, and the depth is the z where the pixel's
    ray meets the triangle's plane.
    """
    depth = np.zeros((height, width))
    pts = np.asarray(points_cam, dtype=np.float64)
    for tri in np.asarray(faces):
        p = pts[tri]
        uv = (p @ np.asarray(K).T)[:, :2] / p[:, 2:]
        normal = np.cross(p[1] - p[0], p[2] - p[0])
        M = np.array([uv[1] - uv[0], uv[2] - uv[0]]).T
        if abs(np.linalg.det(M)) < 1e-12:
            continue
        for row in range(max(0, int(np.ceil(uv[:, 1].min()))), min(height - 1, int(np.floor(uv[:, 1].max()))) + 1):
            for col in range(max(0, int(np.ceil(uv[:, 0].min()))), min(width - 1, int(np.floor(uv[:, 0].max()))) + 1):
                b1, b2 = np.linalg.solve(M, np.array([col, row]) - uv[0])
                if min(b1, b2, 1 - b1 - b2) < -1e-9:
                    continue
                ray = np.linalg.solve(np.asarray(K, dtype=np.float64), np.array([col, row, 1.0]))
                z = (normal @ p[0]) / (normal @ ray)
                if depth[row, col] == 0 or z < depth[row, col]:
                    depth[row, col] = z
    return depth
