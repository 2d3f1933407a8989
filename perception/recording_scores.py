"""Scores of a mesh estimate against a real recording's references: how much of the object's
reference mask the projected mesh covers, how many vertices project onto the object, and,
where the recording has ground-truth scene flow, how far the vertices are from where the
surface moved.

Pure numerics on arrays: vertices (N, 3) float metres in the camera frame, faces (M, 3)
int, K (3, 3) pixels, masks (H, W) bool.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from perception.geometry import pixel_index, project
from perception.raster import faces_mask


def mask_coverage(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, mask: np.ndarray) -> float:
    """Fraction of the ``mask`` pixels covered by the projected triangles (0 for an empty mask)."""
    total = int(mask.sum())
    if total == 0:
        return 0.0
    covered = faces_mask(project(vertices, K), faces, mask.shape)
    return float((covered & mask).sum() / total)


def vertices_on_mask(vertices: np.ndarray, K: np.ndarray, mask: np.ndarray, tolerance_px: float = 0.0) -> float:
    """Fraction of vertices whose projection lies on ``mask`` or within ``tolerance_px`` of it
    (a vertex behind the camera or off the image is off the mask)."""
    if len(vertices) == 0:
        return 0.0
    h, w = mask.shape
    uv = project(vertices, K)
    cols, rows, inside = pixel_index(uv, w, h)
    if tolerance_px > 0:
        distance = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
        near = distance <= tolerance_px
    else:
        near = mask
    on = inside & near[rows, cols]
    return float(on.mean())


@dataclass(frozen=True)
class FlowScore:
    """Errors of the vertices that the ground truth covers.

    used : how many vertices were scored (projected at the source frame onto a pixel with
        known scene flow, within ``surface_tol_m`` of the measured depth there)
    error_m : (used,) float64, distance of each vertex at the target frame from its source
        position moved by the ground-truth scene flow, metres
    zero_motion_m : (used,) float64, the same for a tracker that does not move (the flow's length)
    error_px : (used,) float64, image distance of the projected vertex at the target frame
        from its source projection moved by the ground-truth optical flow, pixels (NaN where unknown)
    """

    used: int
    error_m: np.ndarray
    zero_motion_m: np.ndarray
    error_px: np.ndarray

    def summary(self) -> dict:
        def stats(values, scale):
            values = values[np.isfinite(values)]
            if len(values) == 0:
                return None
            return dict(mean=float(values.mean() * scale), median=float(np.median(values) * scale),
                        p95=float(np.percentile(values, 95) * scale))
        return dict(vertices_scored=self.used, error_mm=stats(self.error_m, 1000.0),
                    zero_motion_mm=stats(self.zero_motion_m, 1000.0), error_px=stats(self.error_px, 1.0))


def flow_score(source_vertices: np.ndarray, target_vertices: np.ndarray, source_depth_m: np.ndarray,
               scene_flow_m: np.ndarray, optical_flow_px: np.ndarray | None, K: np.ndarray,
               surface_tol_m: float = 0.03) -> FlowScore:
    """Score an estimate's motion between a flow pair's frames.

    source_vertices, target_vertices : (N, 3) the estimates at the source and target frames
    source_depth_m : (H, W) float32 depth of the source frame (0/NaN = none)
    scene_flow_m : (H, W, 3) float32; optical_flow_px : (H, W, 2) float32 or None; NaN = unknown

    A vertex's material point is the surface point seen at its source pixel; it is scored
    only when it lies on that surface (depth within ``surface_tol_m``), and its offset from
    the surface is carried along: expected target = source vertex + scene flow there.
    """
    h, w = source_depth_m.shape
    uv = project(source_vertices, K)
    cols, rows, inside = pixel_index(uv, w, h)
    flow = scene_flow_m[rows, cols]
    depth = source_depth_m[rows, cols]
    known = inside & np.isfinite(flow).all(axis=1) & np.isfinite(depth) & (depth > 0)
    on_surface = known & (np.abs(depth - source_vertices[:, 2]) < surface_tol_m)
    expected = source_vertices[on_surface] + flow[on_surface]
    error = np.linalg.norm(target_vertices[on_surface] - expected, axis=1)
    zero = np.linalg.norm(flow[on_surface], axis=1)
    if optical_flow_px is not None:
        expected_uv = uv[on_surface] + optical_flow_px[rows[on_surface], cols[on_surface]]
        error_px = np.linalg.norm(project(target_vertices[on_surface], K) - expected_uv, axis=1)
    else:
        error_px = np.full(int(on_surface.sum()), np.nan)
    return FlowScore(int(on_surface.sum()), error, zero, error_px)
