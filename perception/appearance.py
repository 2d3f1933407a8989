"""How the cloth's material points looked when the mesh was made, to check later views against.

The samples are the mesh's vertices and the centroids of its faces, as material points
(a sparse matrix S with ``S @ V`` their positions). Their colour is read from an image
blurred to the mesh's resolution (a Gaussian of a third of its spacing in pixels): an
estimate is good to a fraction of a spacing at best, so detail finer than that (a weave,
a heathered yarn) would make a right estimate look wrong. A later estimate is checked on
the same material points in its frame:

- on a textured cloth, by the normalised correlation of their grey values: near 1 where
  the mesh sits on the texture it was made on, near 0 on another surface, whatever the
  change of overall brightness and contrast; and region by region (patches of the cloth a
  few spacings wide, in material coordinates), since a mesh whose material points slid
  by a few centimetres over part of the cloth (a corner lifted and folded over) still
  correlates well as a whole, where the rest of it lies right;
- on a plain cloth, by their colour: the median ratio of brightness (a lamp or a turn
  of the cloth changes it, within limits) and the median difference of chromaticity.

Images are (H, W, 3) uint8 RGB; vertices (N, 3) metres in the camera frame; faces (M, 3).
"""

from __future__ import annotations

import cv2
import numpy as np
import scipy.sparse as sp

from perception.geometry import project
from perception.raster import shrink

MIN_BLUR_PX = 1.5
#: grey-level spread (standard deviation) above which a surface counts as textured
MIN_SPREAD = 6.0
MIN_SAMPLES = 20
#: chromaticity spread (standard deviation) above which a cloth counts as colourful
MIN_CHROMA_SPREAD = 0.01
#: a surface found later is not the cloth when its spread is under this fraction of the cloth's
#: (shading alone gives a plain arm a grey spread, never a print's spread of hue)
SPREAD_KEPT = 0.25
#: side of the regions of the regional check, in mesh spacings (in material coordinates)
REGION_SPACINGS = 3.0
#: a region is compared when it has this many samples seen then and now, textured then
REGION_MIN_SAMPLES = 8
#: the regional check says something when at least this many regions are compared
MIN_REGIONS = 4
#: a region whose correlation is under this has slid off its own texture
REGION_SLID_NCC = 0.2


def _material_points(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(N + M, N) sparse: the vertices, then each face's centroid."""
    m = len(faces)
    centroid = sp.csr_matrix((np.full(3 * m, 1.0 / 3.0), (np.repeat(np.arange(m), 3), faces.ravel())),
                             shape=(m, n_vertices))
    return sp.vstack([sp.identity(n_vertices, format="csr"), centroid]).tocsr()


def _colour_at(rgb: np.ndarray, uv: np.ndarray, blur_px: float) -> np.ndarray:
    """Colour (P, 3) float32 at pixels (P, 2) of ``rgb`` blurred by a Gaussian of ``blur_px``; NaN outside."""
    h, w = rgb.shape[:2]
    inside = np.all(np.isfinite(uv), axis=1)
    inside &= (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    out = np.full((len(uv), 3), np.nan, np.float32)
    if not inside.any():
        return out
    u, v = uv[inside, 0], uv[inside, 1]
    pad = int(3 * blur_px) + 2
    x0, x1 = max(0, int(u.min()) - pad), min(w, int(u.max()) + pad + 1)
    y0, y1 = max(0, int(v.min()) - pad), min(h, int(v.max()) + pad + 1)
    # A wide blur keeps nothing finer than itself: shrink the crop first (far cheaper), then
    # blur what remains of it.
    factor = max(1, int(blur_px / MIN_BLUR_PX))
    crop = cv2.GaussianBlur(shrink(rgb[y0:y1, x0:x1], factor).astype(np.float32), (0, 0), blur_px / factor)
    # pixel centres: x in the crop maps to (x + 0.5) / factor - 0.5 in the shrunk one
    mx = ((u - x0 + 0.5) / factor - 0.5).astype(np.float32).reshape(-1, 1)
    my = ((v - y0 + 0.5) / factor - 0.5).astype(np.float32).reshape(-1, 1)
    out[inside] = cv2.remap(crop, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
    return out


def _brightness(colours: np.ndarray) -> np.ndarray:
    """(P,) the channel sum of colours (P, 3), plus 3 so that black divides nothing by zero."""
    return colours.sum(axis=1) + 3.0


def _ncc(before: np.ndarray, now: np.ndarray) -> float:
    """Normalised correlation of the grey values of colours (P, 3) then and now; 0 when either is flat."""
    a, b = before.mean(axis=1), now.mean(axis=1)
    a, b = a - a.mean(), b - b.mean()
    spread = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b) / spread) if spread > 1e-6 else 0.0


def _region_ncc(before: np.ndarray, now: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per region: (normalised correlation of the grey values then and now, samples,
    grey-level spread then), each (R,) over region labels 0..R-1; colours (P, 3), region (P,) int."""
    a, b = before.mean(axis=1).astype(np.float64), now.mean(axis=1).astype(np.float64)
    n = np.bincount(region).astype(np.float64)
    count = np.maximum(n, 1.0)
    a = a - (np.bincount(region, a, len(n)) / count)[region]
    b = b - (np.bincount(region, b, len(n)) / count)[region]
    saa, sbb, sab = (np.bincount(region, x, len(n)) for x in (a * a, b * b, a * b))
    spread = np.sqrt(saa * sbb)
    ncc = np.where(spread > 1e-6, sab / np.maximum(spread, 1e-12), 0.0)
    return ncc, n, np.sqrt(saa / count)


def _ramp(value: float, zero: float, one: float) -> float:
    """0 at ``zero``, 1 at ``one``, linear between (either order), clipped."""
    return float(np.clip((value - zero) / (one - zero), 0.0, 1.0))


class AppearanceModel:
    """Colours of the material points of a mesh in the frame it was made in.

    rgb : (H, W, 3) uint8; vertices : (N, 3); faces : (M, 3) int; K : (3, 3);
    visible : (N,) bool, the vertices seen in that frame; spacing_m : the mesh's edge length
    boundary : (B,) int, the mesh's boundary vertices, or None. A texture is also correlated
        without the material points on them and on the faces that touch them, and the lower
        of the two correlations counts: blurred, their colour is partly the background's,
        and the darker or lighter ring that makes along any surface's outline correlates as
        well on a plain surface as on the print (while on a mesh slid off the cloth it is
        what shows the slide)
    canonical : (N, 3) the mesh's material coordinates (its rest shape), which the regions
        of the regional check divide; None: ``vertices`` as they are now
    """

    def __init__(self, rgb: np.ndarray, vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, visible: np.ndarray,
                 spacing_m: float, boundary: np.ndarray | None = None, canonical: np.ndarray | None = None):
        faces = np.asarray(faces)
        self.S = _material_points(faces, len(vertices))
        on_outline = np.zeros(len(vertices), bool)
        if boundary is not None:
            on_outline[np.asarray(boundary, np.int64)] = True
        self._inner = ~np.concatenate([on_outline, np.any(on_outline[faces], axis=1)])
        spacing_px = K[0, 0] * spacing_m / float(np.median(vertices[:, 2]))
        self.blur_px = max(MIN_BLUR_PX, spacing_px / 3.0)
        self.colours = _colour_at(rgb, project(self.S @ vertices, K), self.blur_px)
        self.colours[~self._seen(visible, faces)] = np.nan
        known = np.all(np.isfinite(self.colours), axis=1)
        seen = self.colours[known]
        grey = seen.mean(axis=1)
        self.textured = bool(known.sum() >= MIN_SAMPLES and np.std(grey) >= MIN_SPREAD)
        chroma = seen[:, :2] / _brightness(seen)[:, None]
        self.chroma_spread = float(np.std(chroma, axis=0).max()) if known.sum() >= MIN_SAMPLES else 0.0
        rest = self.S @ np.asarray(vertices if canonical is None else canonical, np.float64)
        cells = np.floor((rest - rest.min(axis=0)) / (REGION_SPACINGS * spacing_m)).astype(np.int64)
        _, self._region = np.unique(cells, axis=0, return_inverse=True)
        self._region = self._region.reshape(-1)
        self.last_regions_slid = 0.0  # the regional check's last value (see ``_regions_slid``)

    def could_be(self, other: AppearanceModel) -> bool:
        """Whether the surface ``other`` was made on (found later, by segmentation) can be this
        cloth: a colourful print keeps at least ``SPREAD_KEPT`` of its spread of hue, whatever
        the light; a plain cloth cannot be told from another plain surface by its colours."""
        if self.chroma_spread < MIN_CHROMA_SPREAD:
            return True
        return other.chroma_spread >= SPREAD_KEPT * self.chroma_spread

    @staticmethod
    def _seen(visible: np.ndarray, faces: np.ndarray) -> np.ndarray:
        return np.concatenate([visible, np.all(visible[faces], axis=1)])

    @staticmethod
    def _regions_slid(before: np.ndarray, now: np.ndarray, region: np.ndarray) -> float:
        """The share of the compared samples that lie in regions whose texture no longer
        correlates (under ``REGION_SLID_NCC``); 0 when fewer than ``MIN_REGIONS`` regions have
        ``REGION_MIN_SAMPLES`` samples and a texture then (a grey spread of ``MIN_SPREAD``)."""
        if not len(region):
            return 0.0
        ncc, n, spread = _region_ncc(before, now, region)
        compared = (n >= REGION_MIN_SAMPLES) & (spread >= MIN_SPREAD)
        if compared.sum() < MIN_REGIONS:
            return 0.0
        return float(n[compared & (ncc < REGION_SLID_NCC)].sum() / n[compared].sum())

    def likeness(self, rgb: np.ndarray, vertices: np.ndarray, faces: np.ndarray, K: np.ndarray,
                 visible: np.ndarray) -> float:
        """In [0, 1]: how alike the material points seen now look to how they looked at the
        start (see the module docstring); 1 when too few are seen in both to tell."""
        now = _colour_at(rgb, project(self.S @ vertices, K), self.blur_px)
        both = np.all(np.isfinite(now), axis=1) & np.all(np.isfinite(self.colours), axis=1) & self._seen(visible, faces)
        if both.sum() < MIN_SAMPLES:
            return 1.0
        before, now = self.colours[both], now[both]
        if self.textured:
            inner = self._inner[both]
            ncc = _ncc(before, now)
            if inner.sum() >= MIN_SAMPLES:
                ncc = min(ncc, _ncc(before[inner], now[inner]))
            self.last_value = ncc
            self.last_regions_slid = self._regions_slid(before[inner], now[inner], self._region[both][inner])
            return min(_ramp(ncc, 0.15, 0.4), _ramp(self.last_regions_slid, 0.45, 0.15))
        bright_before, bright_now = _brightness(before), _brightness(now)
        ratio = float(np.median(bright_now / bright_before))
        chroma = float(np.median(np.linalg.norm(now / bright_now[:, None] - before / bright_before[:, None], axis=1)))
        self.last_value = (ratio, chroma)
        brightness = min(_ramp(ratio, 0.35, 0.6), _ramp(ratio, 3.0, 1.7))
        return brightness * _ramp(chroma, 0.12, 0.04)
