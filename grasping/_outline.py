"""The outline of a canonical (rest) cloth mesh: ordered boundary loops and corners.

Data form: the canonical mesh of ``MeshEstimate`` -- ``canonical`` (N, 3) float64
metres, a flat rest mesh (material coordinates, normally in the z = 0 plane),
``faces`` (M, 3) int vertex ids, ``boundary`` (B,) int vertex ids. Everything here
depends on the canonical mesh only, so it is computed once per mesh and reused for
every tracked frame.

The tracker's canonical mesh is a hexagonal grid of equilateral triangles laid over
the cloth, so its outline follows the real outline but is ragged at the scale of
one grid spacing (steps of 60 degrees between neighbouring boundary vertices, and
notches of single missing triangles). The turn of the outline is therefore measured
on the smoothed outline: between the vertex and two chord ends a few spacings
behind and ahead, each end the mean of the outline over a stretch of arc length
that spans whole periods of the grid's zigzag.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, vstack

from perception.geometry import (
    boundary_half_edges,
    check_ids,
    check_points,
    unique_edges,
)

log = logging.getLogger(__name__)

#: Default largest interior angle of the outline, radians, that still counts as a
#: corner. Over grid phases and rotations of a T-shirt outline, a 106 degree corner
#: measures at most about 122 degrees and a 163 degree bend at least about 147.
DEFAULT_CORNER_MAX_ANGLE_RAD = float(np.deg2rad(135.0))
#: Default chord half-length L, in grid spacings: chord ends are the mean of the
#: outline between L / 2 and 3 L / 2 of arc length behind and ahead of a vertex.
DEFAULT_WINDOW_SPACINGS = 4.0
# Fraction of L over which each chord end is averaged, on either side of L.
_END_HALF_WIDTH = 0.5
# Half-width, in grid spacings, of the arc averaged for the vertex itself: one
# spacing on each side covers the zigzag of two boundary edges.
_APEX_HALF_WIDTH_SPACINGS = 1.0
# Half-width, in grid spacings, of the arc averaged for ``Outline.middle``, which measures
# the length of the cloth's edges: wider than the apex's, as it need not keep corners
# sharp (a straight side's zigzag has a period of two spacings). On the sides of rectangles
# at 13 angles to the grid and 3 grid phases, spacing 2 cm, the length so measured exceeds
# the straight distance by at most 0.52 cm (0.14 cm on average), against 8.7 cm (4.1 cm)
# along the raw outline (benchmarks/bench_adjacent.py; tests/unit/test_grasp_adjacent.py
# checks a bound).
_MIDDLE_HALF_WIDTH_SPACINGS = 2.0


@dataclass(frozen=True, eq=False)
class Outline:
    """Outer outline of a canonical mesh, ordered, with corners and even samples.

    All arrays with a leading ``R`` have one row per outline position ("row"): the
    outer loops concatenated, each loop ordered so that the cloth lies to the left
    of the travel direction with respect to the face winding normal. A vertex where
    two parts of the outline touch (a pinch) appears in two rows.

    Attributes
    ----------
    vertex_ids : (R,) int64, mesh vertex of each row
    loop_ids : (R,) int64, index of the loop each row belongs to
    arclength_m : (R,) float64, metres, position of the row along its loop, from
        the loop's first row, measured on the canonical mesh
    perimeters_m : (L,) float64, metres, length of each loop
    middle : (R, N) sparse float64, rows summing to 1: ``middle @ X`` is the outline
        averaged over ``middle_half_width_m`` of arc length on each side of each row,
        which evens out the hex grid's zigzag (a straight side crossing the lattice rows
        is a path of edges 2 / sqrt(3) times its length) but rounds corners off
    middle_half_width_m : float, metres, two grid spacings
    behind, ahead : (R, N) sparse float64, rows summing to 1: the chord end behind
        (ahead of) each row is ``behind @ X`` (``ahead @ X``) for vertex positions
        ``X`` (N, D) of the mesh, canonical or tracked. Being affine combinations
        of vertices, the chord ends move exactly with any rigid motion.
    interior_angle_rad : (R,) float64 in (0, 2 pi), radians, interior angle of the
        smoothed outline at each row, between its two chords; below pi is convex
    spacing_m : float, metres, median edge length of the canonical mesh
    window_m : float, metres, chord half-length before clamping to small loops
        (``loop_window_m`` gives it clamped)
    corner_rows : (C,) int64, rows of the corners, in outline order
    """

    vertex_ids: np.ndarray
    loop_ids: np.ndarray
    arclength_m: np.ndarray
    perimeters_m: np.ndarray
    middle: csr_matrix
    middle_half_width_m: float
    behind: csr_matrix
    ahead: csr_matrix
    interior_angle_rad: np.ndarray
    spacing_m: float
    window_m: float
    corner_rows: np.ndarray

    @property
    def corner_ids(self) -> np.ndarray:
        """(C,) int64, mesh vertex ids of the corners, in outline order."""
        return self.vertex_ids[self.corner_rows]

    def loop_window_m(self, loop: int) -> float:
        """Chord half-length L on loop ``loop``, metres: ``window_m``, or less on a small loop.

        Two corners of a loop are at least this far apart along it (one corner's dip in
        the interior angle spreads over about L on either side).
        """
        return _loop_window(self.window_m, float(self.perimeters_m[loop]))

    def chord_points(self, points: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Chord ends of ``rows`` for vertex positions ``points``.

        Parameters
        ----------
        points : (N, D) float64, positions of all mesh vertices in any frame (the
            canonical mesh, or a tracked estimate in the camera frame)
        rows : (K,) int64, outline rows

        Returns
        -------
        behind, ahead : (K, D) float64 each, the chord ends behind and ahead of each
            row along the outline
        """
        return self.behind[rows] @ points, self.ahead[rows] @ points

    def sample_rows(self, spacing_m: float) -> np.ndarray:
        """Rows evenly spaced along each loop, about ``spacing_m`` apart.

        Samples sit half a step after the loop's first corner (or its first row when
        it has none) so that on a polygonal cloth they fall between corners, where
        the outline direction is well defined; corners are the corner grasps' job.

        Parameters
        ----------
        spacing_m : float, metres along the canonical outline, > 0

        Returns
        -------
        (S,) int64 rows, in outline order, without repeats
        """
        picked = []
        for loop, perimeter in enumerate(self.perimeters_m):
            rows = np.flatnonzero(self.loop_ids == loop)
            s = self.arclength_m[rows]
            corners = np.intersect1d(self.corner_rows, rows)
            count = max(1, int(round(perimeter / spacing_m)))
            step = perimeter / count
            start = (self.arclength_m[corners[0]] if corners.size else 0.0) + 0.5 * step
            targets = np.mod(start + step * np.arange(count), perimeter)
            # Nearest row along the loop, with wrap-around at the loop's start.
            gap = np.abs(targets[:, None] - s[None, :])
            gap = np.minimum(gap, perimeter - gap)
            picked.append(rows[np.argmin(gap, axis=1)])
        rows = np.concatenate(picked)
        _, first = np.unique(rows, return_index=True)
        return rows[np.sort(first)]


def _flatten(canonical: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """2D coordinates of a flat canonical mesh with its faces counter-clockwise.

    The canonical mesh lies in the z = 0 plane by contract; projecting on its best
    fitting plane instead of dropping z keeps this correct for a flat mesh in any
    plane. The result is mirrored if needed so that the faces' winding is
    counter-clockwise, which fixes which side of a boundary edge is the cloth.

    Returns (N, 2) float64, metres.
    """
    centred = canonical - canonical.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ValueError(f"Expected a canonical mesh spanning a plane, got singular values {sv.tolist()}")
    if sv[2] > 1e-3 * sv[0]:
        log.debug("canonical mesh is not flat (singular values %s); using its best-fit plane", sv.tolist())
    pts = centred @ vt[:2].T
    a, b, c = pts[faces[:, 0]], pts[faces[:, 1]], pts[faces[:, 2]]
    twice_area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    if abs(twice_area.sum()) < 1e-12:
        raise ValueError("Expected faces with non-zero total area on the canonical mesh, got zero")
    if twice_area.sum() < 0:
        pts[:, 1] *= -1.0
    return pts


def _trace_loops(half_edges: np.ndarray, pts: np.ndarray) -> list[np.ndarray]:
    """Chain boundary half-edges into closed loops of vertex ids.

    Where several loops touch at one vertex (two triangles sharing only a corner,
    which a grid laid over a concave outline can produce), the next edge is the
    first one met turning clockwise from the way back: that keeps each loop on the
    boundary of one fan of triangles, so loops stay simple.
    """
    outgoing = defaultdict(list)
    for e, u in enumerate(half_edges[:, 0]):
        outgoing[int(u)].append(e)
    used = np.zeros(len(half_edges), bool)
    loops = []
    for start in range(len(half_edges)):
        if used[start]:
            continue
        loop, e = [], start
        while True:
            used[e] = True
            u, v = half_edges[e]
            loop.append(int(u))
            options = [f for f in outgoing[int(v)] if not used[f] or f == start]
            if not options:
                log.warning("open boundary chain of %d vertices (non-manifold mesh); ignored", len(loop))
                loop = []
                break
            back = pts[u] - pts[v]
            ahead = pts[half_edges[options, 1]] - pts[v]
            clockwise = np.mod(np.arctan2(back[1], back[0]) - np.arctan2(ahead[:, 1], ahead[:, 0]), 2 * np.pi)
            e = options[int(np.argmin(clockwise))]
            if e == start:
                break
        if len(loop) >= 3:
            loops.append(np.asarray(loop, np.int64))
    return loops


def _loop_window(window_m: float, perimeter_m: float) -> float:
    """Chord half-length L on a loop, metres: ``window_m`` clamped to small loops.

    Chord ends reach 1.5 L along the outline; on a loop shorter than twelve L those
    of a mid-edge vertex would wrap round the neighbouring corners and make it look
    like a corner too.
    """
    return min(window_m, perimeter_m / 12.0)


def _arc_means(loop: np.ndarray, loop_pts: np.ndarray, n: int, centres: np.ndarray, half_width: float, step: float) -> csr_matrix:
    """Weights that average a closed loop over arc-length intervals.

    Parameters
    ----------
    loop : (n_loop,) int64 vertex ids of the loop, in order
    loop_pts : (n_loop, 2) float64, their canonical positions, metres
    n : number of mesh vertices
    centres : (K,) float64, metres of arc length from the loop's first vertex
    half_width : float >= 0, metres: interval ``[c - half_width, c + half_width]``
    step : float > 0, metres between quadrature samples in the interval

    Returns
    -------
    (K, n) sparse float64, rows summing to 1: row k averages the outline over
    interval k as an affine combination of loop vertices
    """
    seg = np.linalg.norm(np.roll(loop_pts, -1, axis=0) - loop_pts, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    count = 2 * int(np.ceil(half_width / step)) + 1
    t = np.mod(centres[:, None] + np.linspace(-half_width, half_width, count)[None, :], cum[-1])
    edge = np.clip(np.searchsorted(cum, t, side="right") - 1, 0, len(loop) - 1)
    frac = (t - cum[edge]) / np.maximum(seg[edge], 1e-300)
    rows = np.repeat(np.arange(len(centres)), 2 * count)
    cols = np.stack([loop[edge], loop[(edge + 1) % len(loop)]], axis=-1).ravel()
    weights = np.stack([1.0 - frac, frac], axis=-1).ravel() / count
    # COO -> CSR sums the weights of samples that share a vertex.
    return coo_matrix((weights, (rows, cols)), shape=(len(centres), n)).tocsr()


def _suppress(angle: np.ndarray, arclength: np.ndarray, perimeter: float, radius: float, max_angle: float) -> np.ndarray:
    """Rows of one loop that are corners: sharp, and the sharpest within ``radius``.

    Greedy non-maximum suppression on sharpness: the smoothed outline spreads a
    corner's dip in the interior angle over about L of outline on each side, of
    which only the deepest vertex is the corner.
    """
    keep = []
    for i in np.argsort(angle, kind="stable"):
        if angle[i] >= max_angle:
            break
        gap = np.abs(arclength[keep] - arclength[i])
        if not np.any(np.minimum(gap, perimeter - gap) < radius):
            keep.append(i)
    return np.sort(np.asarray(keep, np.int64))


def _shoelace(loop_pts: np.ndarray) -> float:
    """Signed area of a closed polygon (n, 2), positive when counter-clockwise."""
    x, y = loop_pts[:, 0], loop_pts[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def build_outline(
    canonical,
    faces,
    boundary,
    max_angle_rad: float = DEFAULT_CORNER_MAX_ANGLE_RAD,
    window_spacings: float = DEFAULT_WINDOW_SPACINGS,
) -> Outline:
    """Trace the outer outline of a canonical mesh and find its corners.

    Parameters
    ----------
    canonical : (N, 3) float64, metres, flat rest mesh (material coordinates)
    faces : (M, 3) int vertex ids, M >= 1
    boundary : (B,) int vertex ids of the boundary vertices, B >= 1
    max_angle_rad : float, radians in (0, pi): largest interior angle of a corner
    window_spacings : float > 0, half-length of the chords measuring the outline's
        turn, in grid spacings (median canonical edge length)

    Returns
    -------
    Outline

    Raises
    ------
    ValueError : wrong shapes, ids out of range, empty faces or boundary, a
        degenerate canonical mesh, or parameters out of range
    """
    canonical = check_points("canonical", canonical)
    n = canonical.shape[0]
    faces = check_ids("faces", faces, n, ndim=2)
    boundary = check_ids("boundary", boundary, n)
    if not 0.0 < max_angle_rad < np.pi:
        raise ValueError(f"Expected max_angle_rad in (0, pi), got {max_angle_rad}")
    if not window_spacings > 0:
        raise ValueError(f"Expected window_spacings > 0, got {window_spacings}")

    pts = _flatten(canonical, faces)
    edges = unique_edges(faces)
    spacing = float(np.median(np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)))
    window = window_spacings * spacing

    # Holes (loops turning clockwise) are left out: grasping the rim of a hole is
    # not a corner or edge grasp of the cloth.
    loops = [lp for lp in _trace_loops(boundary_half_edges(faces), pts) if _shoelace(pts[lp]) > 0]
    if not loops:
        raise ValueError("Expected the faces to have an outer boundary loop, found none")
    in_boundary = np.zeros(n, bool)
    in_boundary[boundary] = True

    ids, loop_ids, arcs, middle, behind, ahead, angles, corners, perimeters = [], [], [], [], [], [], [], [], []
    row0 = 0
    for k, loop in enumerate(loops):
        loop_pts = pts[loop]
        seg = np.linalg.norm(np.roll(loop_pts, -1, axis=0) - loop_pts, axis=1)
        perimeter = float(seg.sum())
        arc = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
        loop_window = _loop_window(window, perimeter)
        step = 0.25 * spacing  # quadrature samples: several per boundary edge
        end_width = _END_HALF_WIDTH * loop_window
        loop_behind = _arc_means(loop, loop_pts, n, arc - loop_window, end_width, step)
        loop_ahead = _arc_means(loop, loop_pts, n, arc + loop_window, end_width, step)
        apex = _arc_means(loop, loop_pts, n, arc, _APEX_HALF_WIDTH_SPACINGS * spacing, step) @ pts
        loop_middle = _arc_means(loop, loop_pts, n, arc, _MIDDLE_HALF_WIDTH_SPACINGS * spacing, step)
        into = apex - loop_behind @ pts
        out = loop_ahead @ pts - apex
        turn = np.arctan2(into[:, 0] * out[:, 1] - into[:, 1] * out[:, 0], np.sum(into * out, axis=1))
        angle = np.pi - turn
        # Corners are boundary vertices by contract: only the caller's ids qualify.
        sharp = np.where(in_boundary[loop], angle, np.inf)
        corners.append(row0 + _suppress(sharp, arc, perimeter, loop_window, max_angle_rad))
        ids.append(loop)
        loop_ids.append(np.full(len(loop), k, np.int64))
        arcs.append(arc)
        middle.append(loop_middle)
        behind.append(loop_behind)
        ahead.append(loop_ahead)
        angles.append(angle)
        perimeters.append(perimeter)
        row0 += len(loop)

    vertex_ids = np.concatenate(ids)
    corner_rows = np.concatenate(corners)
    # A vertex where two loops touch can be a corner of both; one grasp is enough.
    _, first = np.unique(vertex_ids[corner_rows], return_index=True)
    outline = Outline(
        vertex_ids=vertex_ids,
        loop_ids=np.concatenate(loop_ids),
        arclength_m=np.concatenate(arcs),
        perimeters_m=np.asarray(perimeters),
        middle=vstack(middle, format="csr"),
        middle_half_width_m=_MIDDLE_HALF_WIDTH_SPACINGS * spacing,
        behind=vstack(behind, format="csr"),
        ahead=vstack(ahead, format="csr"),
        interior_angle_rad=np.concatenate(angles),
        spacing_m=spacing,
        window_m=window,
        corner_rows=corner_rows[np.sort(first)],
    )
    log.debug(
        "outline: %d loop(s), %d rows, spacing %.4f m, %d corner(s)",
        len(loops), len(outline.vertex_ids), spacing, len(outline.corner_rows),
    )
    return outline


def find_corners(
    canonical,
    faces,
    boundary,
    max_angle_rad: float = DEFAULT_CORNER_MAX_ANGLE_RAD,
    window_spacings: float = DEFAULT_WINDOW_SPACINGS,
) -> np.ndarray:
    """Corner vertices of a cloth from the geometry of its canonical mesh.

    A corner is a boundary vertex where the outer outline turns sharply: its
    interior angle on the smoothed outline is below ``max_angle_rad``, and it is
    the sharpest vertex within L of outline on either side (one physical corner
    gives one vertex). The angle is taken at the vertex (the outline averaged over
    one grid spacing on each side) between chord ends L = ``window_spacings``
    spacings behind and ahead (the outline averaged from L / 2 to 3 L / 2 away),
    which evens out the hex grid's ragged outline. Concave turns (armpits,
    notches) and the rims of holes are never corners. Features shorter than about
    1.5 L (a sleeve end 5 spacings wide with L = 4) are not resolved: build the
    canonical mesh finer, or lower ``window_spacings``.

    Parameters
    ----------
    canonical : (N, 3) float64, metres, flat rest mesh (``MeshEstimate.canonical``)
    faces : (M, 3) int vertex ids (``MeshEstimate.faces``), M >= 1
    boundary : (B,) int vertex ids with fewer than six neighbours
        (``MeshEstimate.boundary``), B >= 1. The outline's order comes from the
        faces (edges used by one face); corners are restricted to these ids.
    max_angle_rad : float in (0, pi), radians, default 135 degrees
    window_spacings : float > 0, chord half-length L in grid spacings (median edge
        length of the canonical mesh), default 4

    Returns
    -------
    (C,) int64 vertex ids, ordered along the outline (cloth on the left of the
    travel direction with respect to the face winding); C may be 0 (a round cloth)

    Raises
    ------
    ValueError : wrong shapes, ids out of range, empty faces or boundary, or a
        degenerate canonical mesh
    """
    return build_outline(canonical, faces, boundary, max_angle_rad, window_spacings).corner_ids


def corner_angles(
    canonical,
    faces,
    boundary,
    max_angle_rad: float = DEFAULT_CORNER_MAX_ANGLE_RAD,
    window_spacings: float = DEFAULT_WINDOW_SPACINGS,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The corners of ``find_corners`` (same arguments, same errors) with the interior angle
    of the smoothed outline at each.

    Returns (C,) int64 vertex ids in outline order, (C,) float64 interior angles, radians,
    and the half-length in metres of the chords that measured them (``window_spacings``
    canonical spacings; less on a loop too small for it): an angle is the corner's own only
    where the outline runs straight for that long on either side.
    """
    outline = build_outline(canonical, faces, boundary, max_angle_rad, window_spacings)
    return outline.corner_ids, outline.interior_angle_rad[outline.corner_rows], outline.window_m
