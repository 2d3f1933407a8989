"""A peer to compare against: pycpd's deformable Coherent Point Drift, frame to frame.

Given the mesh vertices of the previous frame and the object's points in the current frame
(the same mask the tracker used), CPD moves the vertices onto the points. It uses depth
only (no colour, no mesh structure beyond the motion-coherence prior), which is the
usual baseline for RGB-D cloth tracking. pycpd is an optional dependency (``.[test]``).
"""

from __future__ import annotations

import numpy as np

from perception.geometry import rays


class CPDTracker:
    """Frame-to-frame deformable CPD.

    alpha, beta : pycpd's regularisation weight and motion-coherence width (metres)
    max_points : object points sampled per frame (CPD is O(points x vertices) per iteration)
    """

    def __init__(self, alpha: float = 2.0, beta: float = 0.1, max_points: int = 1500, max_iterations: int = 50,
                 rng: np.random.Generator | None = None):
        try:
            from pycpd import DeformableRegistration  # noqa: F401
        except ImportError as e:  # optional dependency
            raise ImportError("the CPD baseline needs pycpd: pip install pycpd") from e
        self.alpha, self.beta = alpha, beta
        self.max_points = max_points
        self.max_iterations = max_iterations
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.vertices: np.ndarray | None = None

    def initialise(self, vertices: np.ndarray) -> None:
        """Start from known vertices (N, 3), e.g. the tracker's first-frame mesh."""
        self.vertices = np.array(vertices, dtype=np.float64)

    def object_points(self, depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(P, 3) points of the object: masked pixels with depth, randomly subsampled."""
        ys, xs = np.nonzero(mask & np.isfinite(depth_m) & (depth_m > 0))
        if len(xs) > self.max_points:
            pick = self.rng.choice(len(xs), self.max_points, replace=False)
            ys, xs = ys[pick], xs[pick]
        uv = np.column_stack([xs, ys]).astype(np.float64)
        return rays(uv, K) * depth_m[ys, xs, None].astype(np.float64)

    def track(self, depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Register the previous vertices to this frame's object points; returns (N, 3)."""
        from pycpd import DeformableRegistration

        pts = self.object_points(depth_m, mask, K)
        if len(pts) < 10:
            return self.vertices.copy()
        reg = DeformableRegistration(X=pts, Y=self.vertices, alpha=self.alpha, beta=self.beta,
                                     max_iterations=self.max_iterations, tolerance=1e-4)
        self.vertices, _ = reg.register()
        return self.vertices.copy()
