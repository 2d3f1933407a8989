"""Which mesh vertices the camera sees in a frame, and what hides the others.

A vertex of the estimate is, in one frame:

- ``VISIBLE``: it projects into the image onto measured depth that is not nearer than
  the vertex by more than a margin (the data may agree with it or contradict it);
- ``OCCLUDED``: something nearer covers it: the measured surface at its pixel lies more
  than the margin in front of it (a gripper, a hand, another layer of the cloth), its
  pixel belongs to a known occluder (``RGBDFrame.occluder_mask``), or, given the mesh's
  faces, another part of the mesh itself lies in front of it (``hidden_by_mesh``);
- ``OUT_OF_VIEW``: it projects outside the image or lies behind the camera;
- ``NO_DEPTH``: its pixel has no depth measurement.

Only visible vertices are pulled by the data terms; the others are carried by the
mesh's smoothness and motion prior (``perception.energy.MotionPriorTerm``).

Arrays: vertices (N, 3) float metres in the camera frame; depth (H, W) float32 metres
along the optical axis, 0 or NaN where unmeasured; masks (H, W) bool.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from perception.geometry import pixel_index, project
from perception.mesh import barycentric_2d
from perception.raster import face_index_image

VISIBLE, OCCLUDED, OUT_OF_VIEW, NO_DEPTH = 0, 1, 2, 3
STATES = ("visible", "occluded", "out_of_view", "no_depth")


#: The search for faces covering a vertex looks this many median face radii around it; a mesh
#: with larger faces in the image is drawn instead (``_hidden_by_drawing``).
SEARCH_REACH = 10.0


def _hidden_by_drawing(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, ids: np.ndarray, margin_m: float,
                       shape: tuple[int, int]) -> np.ndarray:
    """``hidden_by_mesh`` for the vertices ``ids`` by drawing the faces, the nearest (by mean
    depth) drawn last, and comparing each vertex with the face drawn at its pixel."""
    hidden = np.zeros(len(vertices), bool)
    h, w = shape
    cols, rows, _ = pixel_index(uv, w, h)
    y0, y1 = int(rows[ids].min()), int(rows[ids].max()) + 1
    x0, x1 = int(cols[ids].min()), int(cols[ids].max()) + 1
    front = face_index_image(uv - [x0, y0], faces, vertices[:, 2], (y1 - y0, x1 - x0))
    face = front[rows[ids] - y0, cols[ids] - x0]
    drawn = face >= 0
    ids, face = ids[drawn], face[drawn]
    own = np.any(faces[face] == ids[:, None], axis=1)
    ids, face = ids[~own], face[~own]
    bary = barycentric_2d(uv[ids], uv[faces[face]])
    hidden[ids] = _face_in_front(vertices, faces, ids, face, bary, margin_m)
    return hidden


def _face_in_front(vertices: np.ndarray, faces: np.ndarray, ids: np.ndarray, face: np.ndarray, bary: np.ndarray,
                   margin_m: float) -> np.ndarray:
    """(P,) bool: face ``face[p]``, at the point of barycentric coordinates ``bary[p]`` (where
    it covers vertex ``ids[p]``'s pixel), lies more than ``margin_m`` nearer than the vertex."""
    z_face = np.einsum("pk,pk->p", bary, vertices[faces[face], 2])
    return np.isfinite(z_face) & (z_face < vertices[ids, 2] - margin_m)


def hidden_by_mesh(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                   margin_m: float) -> np.ndarray:
    """(N,) bool: the vertices that another part of the mesh hides from the camera.

    A cloth folded over itself shows one layer; the measured surface at a vertex of the
    layer behind lies only a few centimetres in front of it, closer than any margin that
    tolerates depth noise, so the depth test alone would take it as seen and pull it onto
    the front layer. Here a vertex is hidden when a face of the mesh that does not contain
    it covers its projection and lies there more than ``margin_m`` in front of it.
    vertices (N, 3) metres; faces (M, 3); shape (H, W) of the image.
    """
    n = len(vertices)
    hidden = np.zeros(n, bool)
    h, w = shape
    uv = project(vertices, K)
    _, _, inside = pixel_index(uv, w, h)
    inside &= vertices[:, 2] > 0
    drawn = np.all(inside[faces], axis=1)
    if not inside.any() or not drawn.any():
        return hidden
    faces = faces[drawn]
    triangles = uv[faces]  # (M, 3, 2)
    # A mesh folds over itself, in the image, only where some of its triangles are seen from
    # their other side; where all turn the same side to the camera, none can cover another
    # (short of a sheet wound like a spiral staircase), and the search below is skipped.
    e1, e2 = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    if not (np.any(area > 0) and np.any(area < 0)):
        return hidden
    centres = triangles.mean(axis=1)
    radius = np.max(np.linalg.norm(triangles - centres[:, None], axis=2), axis=1)
    reach = float(radius.max())
    ids = np.flatnonzero(inside)
    if reach > SEARCH_REACH * float(np.median(radius)):
        # A few faces stretched across the image would make every vertex a candidate of
        # every face: draw the mesh instead, nearest face last (bounded work, whatever the shape).
        return _hidden_by_drawing(vertices, faces, uv, ids, margin_m, shape)
    # Candidate (vertex, face) pairs: faces whose centre is within any face's reach of the
    # vertex's pixel; a face covering the pixel is always among them.
    pairs = cKDTree(uv[ids]).sparse_distance_matrix(cKDTree(centres), reach, output_type="coo_matrix")
    v, f = ids[pairs.row], pairs.col
    keep = np.all(faces[f] != v[:, None], axis=1)  # a vertex's own faces do not hide it
    v, f = v[keep], f[keep]
    if len(v) == 0:
        return hidden
    bary = barycentric_2d(uv[v], triangles[f])
    covers = np.all(bary >= -1e-9, axis=1)  # False for NaN (degenerate faces) too
    v, f = v[covers], f[covers]
    hidden[v[_face_in_front(vertices, faces, v, f, bary[covers], margin_m)]] = True
    return hidden


def classify_vertices(vertices: np.ndarray, depth_m: np.ndarray, K: np.ndarray, margin_m: float,
                      occluder_mask: np.ndarray | None = None, faces: np.ndarray | None = None,
                      self_margin_m: float = 0.0) -> np.ndarray:
    """The state of each vertex (see the module docstring).

    vertices : (N, 3) float, metres, camera frame
    depth_m : (H, W) float32 metres, 0 or NaN = no measurement
    K : (3, 3) intrinsics; margin_m : how much nearer the measured surface must be to hide a vertex
    occluder_mask : (H, W) bool, True on known occluders, or None
    faces : (M, 3) int, the mesh's faces: with them, a vertex that the mesh itself hides by
        more than ``self_margin_m`` (``hidden_by_mesh``) is occluded too when the measured
        surface at its pixel is also more than ``self_margin_m`` in front of it; None skips
        that test
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
    if faces is not None:
        # Only where the data agrees that something is in front: a layer the mesh wrongly
        # folded over a vertex must not hide it from the data that would unfold it.
        behind_measured = measured & (d < vertices[:, 2] - self_margin_m)
        state[behind_measured & hidden_by_mesh(vertices, faces, K, (h, w), self_margin_m)] = OCCLUDED
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
