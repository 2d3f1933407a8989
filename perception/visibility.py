"""Which mesh vertices the camera sees in a frame, and what hides the others.

A vertex of the estimate is, in one frame:

- ``VISIBLE``: it projects into the image onto measured depth that is not nearer than
  the vertex by more than a margin (the data may agree with it or contradict it);
- ``OCCLUDED``: something nearer covers it: the measured surface at its pixel lies more
  than the margin in front of it (a gripper, a hand, another layer of the cloth), or its
  pixel belongs to a known occluder (``RGBDFrame.occluder_mask``);
- ``OUT_OF_VIEW``: it projects outside the image or lies behind the camera;
- ``NO_DEPTH``: its pixel has no depth measurement.

Only visible vertices are pulled by the data terms; the others are carried by the
mesh's smoothness and motion prior (``perception.energy.MotionPriorTerm``).

Arrays: vertices (N, 3) float metres in the camera frame; depth (H, W) float32 metres
along the optical axis, 0 or NaN where unmeasured; masks (H, W) bool.
"""

from __future__ import annotations

import numpy as np

from perception.geometry import pixel_index, project

VISIBLE, OCCLUDED, OUT_OF_VIEW, NO_DEPTH = 0, 1, 2, 3
STATES = ("visible", "occluded", "out_of_view", "no_depth")


def classify_vertices(vertices: np.ndarray, depth_m: np.ndarray, K: np.ndarray, margin_m: float,
                      occluder_mask: np.ndarray | None = None) -> np.ndarray:
    """The state of each vertex (see the module docstring).

    vertices : (N, 3) float, metres, camera frame
    depth_m : (H, W) float32 metres, 0 or NaN = no measurement
    K : (3, 3) intrinsics; margin_m : how much nearer the measured surface must be to hide a vertex
    occluder_mask : (H, W) bool, True on known occluders, or None
    returns (N,) int8 among VISIBLE, OCCLUDED, OUT_OF_VIEW, NO_DEPTH
    """
    h, w = depth_m.shape
    cols, rows, inside = pixel_index(project(vertices, K), w, h)
    d = depth_m[rows, cols]
    measured = inside & np.isfinite(d) & (d > 0)
    state = np.full(len(vertices), NO_DEPTH, np.int8)
    state[~inside] = OUT_OF_VIEW
    nearer = measured & (d < vertices[:, 2] - margin_m)
    state[measured & ~nearer] = VISIBLE
    state[nearer] = OCCLUDED
    if occluder_mask is not None:
        state[inside & occluder_mask[rows, cols]] = OCCLUDED
    return state


FACE_VISIBLE, FACE_HIDDEN, FACE_OUT_OF_VIEW = 0, 1, 2


def face_states(state: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) int8 for faces (M, 3) given vertex states (N,) from ``classify_vertices``:
    FACE_OUT_OF_VIEW when a vertex is out of view, else FACE_HIDDEN when a vertex is hidden
    behind something nearer, else FACE_VISIBLE (a vertex without depth is still seen in
    the colour image)."""
    s = state[faces]
    out = np.full(len(faces), FACE_VISIBLE, np.int8)
    out[np.any(s == OCCLUDED, axis=1)] = FACE_HIDDEN
    out[np.any(s == OUT_OF_VIEW, axis=1)] = FACE_OUT_OF_VIEW
    return out
