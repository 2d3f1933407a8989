"""How much to trust an estimate: the evidence for it, each part in [0, 1], and their product.

A robot grasps where the estimate says the cloth is, so a wrong estimate must say so. One
cue alone is fooled: depth agrees as well on a wall as on the cloth, a mesh squeezed into
part of the cloth agrees everywhere it lies, a textureless cloth gives appearance nothing
to compare. So confidence multiplies the cues, each mapped to [0, 1] so that an estimate
that is right scores about 1 on it:

- ``depth``: of the vertices seen, the fraction whose measured depth agrees with them
  (within ``tol_m``); a vertex the camera sees through, or one more than ``tol_m`` behind
  the measured surface, disagrees;
- ``coverage``: the fraction of the segmented object that the projected mesh covers (a
  mesh squeezed or slid off part of the object leaves it uncovered); where colour tells the
  object from its surroundings, the object as far as its colour reaches beyond the
  segmentation's search, since a mesh that lost part of the object predicts a search that
  misses that part; where the segmentation could not find the object's edge (a cloth on a
  table of its own colour is continuous with the table), it says nothing and counts 1;
- ``precision``: the fraction of the vertices seen that project onto the object;
- ``appearance``: how alike the mesh's material points look now and when the mesh was
  made: their texture (normalised correlation, over the whole mesh and region by region),
  or on a plain cloth their colour (a mesh on the wrong surface sees another texture or
  colour; one slid over part of a print sees another texture there);
- ``unstretched``: cloth hardly stretches, so a mesh whose edges are much longer than when
  it was laid on the object (median over the edges) has been pulled onto something else,
  such as a surface farther away;
- ``uncrumpled``: a mesh that cannot follow the cloth (a fold that turns part of it over,
  which a single smooth sheet cannot represent) crushes the edges along the fold; cloth
  bunched finer than the mesh shortens a few edges, but rarely a tenth of them to under
  half their length;
- ``seen``: how much of the mesh the camera sees (a mesh almost entirely hidden is carried
  by its motion prior, not by data);
- ``followed``: how little of the mesh has moved far while hidden. A hidden vertex is carried
  by its neighbours and the motion prior; while the cloth lies still that holds, but a part
  that moved several centimetres since the camera last saw it (a corner folding over as the
  cloth is lifted) may be anywhere along the way. A fifth of the mesh so carried costs
  nothing; more lowers the cue, to 0 at ``CARRIED_NONE`` of it;
- ``opaque``: how little of the mesh the camera sees the empty workspace through, where the
  workspace was captured empty (``MeshTracker.initialise(background=...)``). A pixel that
  shows the empty workspace has nothing in front of it, so a vertex in view there, nearer
  than the surface seen, is in the air beside the cloth. Depth and precision cannot see it:
  such a vertex usually has no depth at its pixel (a wall beyond the sensor's range) or is
  taken as hidden. A right mesh lies there only along the outline's blur; a mesh whose
  material slid along a hanging cloth sticks out beside it. Up to ``EXPOSED_ALL`` of the
  vertices in view so exposed cost nothing; at ``EXPOSED_NONE`` the cue is 0.
- ``within_reach``: cloth does not stretch, so no part of it hangs farther from a point a
  gripper holds than the material farthest from that point (``reach_ratio``). Where the
  robot says which vertex it holds and where (``RGBDFrame.held_vertices``), the object
  measured farther from the gripper than the mesh's material reaches from the held vertex
  has material the mesh lacks: a mesh laid on a folded cloth, whose hidden layer falls
  open as the cloth is lifted. Up to ``REACH_ALL`` times the mesh's reach costs nothing
  (the simulated cloth stretches a few per cent under its own weight); at ``REACH_NONE``
  the cue is 0.

One bound comes on top of the product: on a cloth without print, the frame shows where the
surface is but not which material lies where on it. While the mesh keeps the shape it was
laid in (moved or turned as a whole), its material points stay where they were laid; once its
shape has changed by more than ``RESHAPED_M`` (``reshaping``), nothing confirms them, and on
development lifts of plain cloth most such estimates were wrong. The confidence is then at
most ``UNCONFIRMED_CAP`` (``material_cap``): below the 0.5 a grasp should ask for, above the
``lost_confidence`` that makes the tracker look for the object again, since the mesh still
lies on it. On a printed cloth the frame's feature matches confirm them: each match follows the
print from frame to frame and is bound to the material point it was found on. A mesh that
slid along the cloth leaves its matches behind, while depth, outline and coverage still agree
with it; when at least ``MIN_DISAGREEING`` matches, and more than half of them, lie farther from
their material points than the solver's last outlier radius, the confidence is at most
``UNCONFIRMED_CAP`` too (``matches_cap``). Neither bound flags the estimate lost.

Arrays: vertices (N, 3) metres, camera frame; images and masks (H, W).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from perception.geometry import pixel_index, project
from perception.raster import disc
from perception.registration import rigid_fit

#: cue value below which an estimate is lost whatever the others say
FLOOR = 0.25
#: share of the mesh hidden and moved far since last seen: up to the first, the ``followed``
#: cue is 1; at the second, 0
CARRIED_ALL, CARRIED_NONE = 0.2, 0.45
#: share of the vertices in view seen through to the empty workspace: up to the first, the
#: ``opaque`` cue is 1; at the second, 0
EXPOSED_ALL, EXPOSED_NONE = 0.04, 0.12
#: how far the object reaches from a held point, over the mesh's material reach from the
#: held vertex (``reach_ratio``): up to the first, the ``within_reach`` cue is 1; at the
#: second, 0. Measured in the simulation (development scripts): a flat towel and a T-shirt
#: lifted by a corner hang 1.04 and 1.06 times their rest reach (the cloth's springs give), and
#: a mesh laid on the whole cloth held by the vertex nearest the gripper, up to 3 cm from the
#: corner, reads up to 1.09 (``gripper_corner_move``); a 50 x 45 cm towel folded in half
#: reaches 1.23 or 1.31 times (by the fold's direction) as far from a corner as the half on top
REACH_ALL, REACH_NONE = 1.1, 1.25
#: RMS change of shape (metres, ``reshaping``) beyond which a plain cloth's material points are
#: unconfirmed. On 13 development lifts of plain cloth (even seeds 0-58, the unfold trials'
#: tracker), of the estimates with confidence 0.5 or more, 68 % were wrong (mean error over 30
#: mm) beyond 3 cm of change and 7 % within it; a plain shirt turning on its hangers
#: (``shirt_textureless_rotate``, 10 mm of error) changes by at most 1.9 cm
RESHAPED_M = 0.03
#: the highest confidence of an estimate whose material points nothing confirms
UNCONFIRMED_CAP = 0.45
#: feature matches that must lie off their material points (and be more than half of the
#: frame's matches) to unconfirm them: one or two are a point slipped on the print, not a
#: mesh slid along the cloth
MIN_DISAGREEING = 3


@dataclass(frozen=True)
class Assessment:
    """The cues of one estimate, each in [0, 1]; see the module docstring."""

    depth: float
    coverage: float
    precision: float
    appearance: float
    unstretched: float
    uncrumpled: float
    seen: float
    followed: float
    opaque: float = 1.0
    within_reach: float = 1.0
    material_cap: float = 1.0

    @property
    def confidence(self) -> float:
        product = (self.depth * self.coverage * self.precision * self.appearance * self.unstretched * self.uncrumpled
                   * self.seen * self.followed * self.opaque * self.within_reach)
        return float(np.clip(min(product, self.material_cap), 0.0, 1.0))

    def lost(self, threshold: float) -> bool:
        """True when the confidence is below ``threshold`` or any cue is below ``FLOOR`` (the
        material cap, at ``UNCONFIRMED_CAP``, is above the default threshold and ``FLOOR``)."""
        return self.confidence < threshold or min(asdict(self).values()) < FLOOR

    def as_dict(self) -> dict:
        return {**asdict(self), "confidence": self.confidence}


def reshaping(rest: np.ndarray, vertices: np.ndarray) -> float:
    """How much ``vertices`` (N, 3) differ in shape from ``rest`` (N, 3), metres: the RMS
    distance between them once ``rest`` is moved rigidly onto ``vertices`` (Kabsch)."""
    R, t = rigid_fit(rest, vertices)
    return float(np.sqrt(np.mean(np.sum((rest @ R.T + t - vertices) ** 2, axis=1))))


def material_cap(textured: bool, reshaped_m: float) -> float:
    """``UNCONFIRMED_CAP`` for a cloth without print (not ``textured``) whose mesh has changed
    shape by more than ``RESHAPED_M`` (``reshaped_m``, ``reshaping``) since it was laid, else 1."""
    return UNCONFIRMED_CAP if not textured and reshaped_m > RESHAPED_M else 1.0


def matches_cap(residuals_m: np.ndarray, radius_m: float) -> float:
    """``UNCONFIRMED_CAP`` when at least ``MIN_DISAGREEING`` of the frame's feature matches,
    and more than half of them, lie farther than ``radius_m`` from their material points on the
    estimate (``residuals_m`` (P,) metres, P >= 0), else 1."""
    off = int(np.count_nonzero(np.asarray(residuals_m) > radius_m))
    return UNCONFIRMED_CAP if off >= MIN_DISAGREEING and 2 * off > len(residuals_m) else 1.0


def reach_ratio(object_points_m: np.ndarray, held_points_m: np.ndarray, held_reach_m: np.ndarray) -> float:
    """How far the measured object reaches from the points a robot holds, relative to how far
    the mesh's material reaches from the vertices held there: the largest, over the held
    points (K, 3), of the 99th percentile of the object points' (P, 3) distances from it over
    its vertex's material reach (K,) metres (the canonical mesh's largest distance from that
    vertex; the percentile leaves out a few stray pixels). 0 without points or held points."""
    pts = np.asarray(object_points_m, np.float64).reshape(-1, 3)
    held = np.asarray(held_points_m, np.float64).reshape(-1, 3)
    reach = np.asarray(held_reach_m, np.float64).reshape(-1)
    if not len(pts) or not len(held):
        return 0.0
    far = np.percentile(np.linalg.norm(pts[None, :, :] - held[:, None, :], axis=2), 99, axis=1)
    return float(np.max(far / np.maximum(reach, 1e-9)))


def within_reach(ratio: float) -> float:
    """The ``within_reach`` cue of a ``reach_ratio``: 1 up to ``REACH_ALL``, 0 at ``REACH_NONE``."""
    return float(np.clip((REACH_NONE - ratio) / (REACH_NONE - REACH_ALL), 0.0, 1.0))


def _ramp(value: float, good: float) -> float:
    """0 at 0, rising linearly to 1 at ``good`` and above."""
    return float(np.clip(value / good, 0.0, 1.0))


def assess(vertices: np.ndarray, edges: np.ndarray, rest_lengths_m: np.ndarray, visible: np.ndarray,
           depth_m: np.ndarray, object_mask: np.ndarray, K: np.ndarray, tol_m: float, appearance: float,
           leak: float = 0.0, carried: float = 0.0, extent: np.ndarray | None = None,
           exposed: np.ndarray | None = None, cap: float = 1.0, reach: float = 1.0) -> Assessment:
    """The Assessment of an estimate.

    vertices : (N, 3); visible : (N,) bool, the vertices seen
    edges : (E, 2) int, the mesh's edges; rest_lengths_m : (E,) float, their lengths when the
        mesh was laid on the object
    depth_m : (H, W) float32 measured depth (0 or NaN: none); object_mask : (H, W) bool, the
    segmented object (known occluders excluded); K : (3, 3)
    tol_m : depth agreement tolerance, metres
    appearance : in [0, 1], how alike the material points look now and at the start
        (``perception.appearance.AppearanceModel.likeness``)
    leak : the segmentation's (``perception.segmentation.Segment.leak``); above 0.3 the object
        mask's extent is not the object's, and coverage is not measured
    carried : in [0, 1], the share of the vertices hidden now that have moved far since the
        camera last saw them (``MeshTracker`` keeps where each was last seen)
    extent : (H, W) bool, the object as far as its colour reaches beyond the segmentation's
        search (``perception.segmentation.Segment.extent``, known occluders excluded), or
        None: what coverage is measured on
    exposed : (N,) bool, the vertices the camera sees the empty workspace through
        (``perception.background.seen_through``), or None where the workspace is not known
    cap : the highest confidence the evidence for the material points allows (``material_cap``,
        ``matches_cap``)
    reach : the ``within_reach`` cue (``within_reach`` of ``reach_ratio``; 1 when nothing is held)
    """
    n = len(vertices)
    h, w = depth_m.shape
    uv = project(vertices, K)
    cols, rows, inside = pixel_index(uv, w, h)
    seen = visible & inside
    d = depth_m[rows, cols]
    measured = seen & np.isfinite(d) & (d > 0)
    agree = measured & (np.abs(d - vertices[:, 2]) < tol_m)
    depth = agree.sum() / measured.sum() if measured.any() else 0.0
    precision = (seen & object_mask[rows, cols]).sum() / seen.sum() if seen.any() else 0.0
    # The mesh's footprint, at quarter resolution: each projected vertex grown to cover its
    # share of the surface (three quarters of a spacing, so neighbours overlap). As the
    # triangles drawn would be, to a few pixels, at a fraction of the cost.
    q = 4
    small = (object_mask if extent is None else extent)[::q, ::q]
    area = small.sum()
    coverage = 0.0
    if area:
        footprint = np.zeros(small.shape, np.uint8)
        c, r, ok = pixel_index(uv / q, small.shape[1], small.shape[0])
        footprint[r[ok], c[ok]] = 1
        spacing_px = K[0, 0] * float(np.median(rest_lengths_m)) / max(float(np.median(vertices[:, 2])), 1e-6)
        # at most the image's size: a mesh pushed against the camera has huge spacings in pixels
        radius = int(np.clip(np.ceil(0.75 * spacing_px / q), 1, max(small.shape)))
        footprint = cv2.dilate(footprint, disc(radius))
        coverage = (footprint.astype(bool) & small).sum() / area
    if leak > 0.3:
        coverage = 1.0
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1) / np.maximum(rest_lengths_m, 1e-9)
    stretch = float(np.median(lengths))
    crushed = float(np.mean(lengths < 0.5))
    opaque = 1.0
    if exposed is not None and inside.any():
        share = float((exposed & inside).sum() / inside.sum())
        opaque = float(np.clip((EXPOSED_NONE - share) / (EXPOSED_NONE - EXPOSED_ALL), 0.0, 1.0))
    return Assessment(depth=_ramp(depth, 0.85), coverage=_ramp(coverage, 0.8), precision=_ramp(precision, 0.85),
                      appearance=float(appearance), unstretched=float(np.clip((1.35 - stretch) / 0.25, 0.0, 1.0)),
                      uncrumpled=float(np.clip((0.15 - crushed) / 0.09, 0.0, 1.0)),
                      seen=_ramp(seen.sum() / max(n, 1), 0.25),
                      followed=float(np.clip((CARRIED_NONE - carried) / (CARRIED_NONE - CARRIED_ALL), 0.0, 1.0)),
                      opaque=opaque, within_reach=float(reach), material_cap=float(cap))
