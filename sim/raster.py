"""A small z-buffered rasteriser for one textured triangle mesh (NumPy + cv2.remap).

Why it exists: PyBullet's TinyRenderer draws the cloth correctly, but re-drawing the
whole room every frame costs ~150 ms at 640x480 (~40 ms of it fixed overhead). The
virtual camera renders the static room once with PyBullet and composites the cloth,
drawn here in ~30 ms at 640x480, over it.

Conventions: points in the OpenCV optical frame (x right, y down, z forward), pixel
centres at integer (u, v) as OpenCV, so a vertex projected with ``K`` lands exactly where
it is drawn. Depth and texture coordinates are interpolated perspective-correctly.
Triangles are two-sided (no culling); normals are flipped to face the camera.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from ipc.messages import CameraInfo
from perception.geometry import project, vertex_normals

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Shading:
    """Lambert plus Blinn-Phong lighting, as the TinyRenderer's, evaluated at the vertices.

    light_dir_cam : (3,) unit vector towards the light, camera frame
    ambient, diffuse, specular : weights; shininess : specular exponent
    """

    light_dir_cam: np.ndarray
    ambient: float = 0.55
    diffuse: float = 0.45
    specular: float = 0.05
    shininess: float = 20.0


@dataclass(frozen=True)
class MeshRaster:
    """A rasterised mesh.

    rgb : (H, W, 3) uint8, shaded texture where ``mask``, 0 elsewhere
    depth_m : (H, W) float32 metres along z where ``mask``, 0 elsewhere
    mask : (H, W) bool, pixels whose centre the mesh covers
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    mask: np.ndarray


def _vertex_lighting(points: np.ndarray, faces: np.ndarray, shading: Shading) -> np.ndarray:
    """(V, 2) diffuse factor (ambient + diffuse * Lambert) and specular term at each vertex.

    Two-sided: each vertex normal is flipped to face the camera before lighting.
    """
    normal = vertex_normals(points, faces)
    to_eye = -points / np.linalg.norm(points, axis=1, keepdims=True)
    normal *= np.where(np.sum(normal * to_eye, axis=1) < 0, -1.0, 1.0)[:, None]
    light = np.asarray(shading.light_dir_cam, dtype=np.float64)
    light = light / np.linalg.norm(light)
    lambert = np.clip(normal @ light, 0.0, None)
    half = light + to_eye
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
    spec = np.clip(np.sum(normal * half, axis=1), 0.0, None) ** shading.shininess
    return np.stack([shading.ambient + shading.diffuse * lambert, spec], axis=1)


def _sample_bilinear(texture_rgb: np.ndarray, st: np.ndarray) -> np.ndarray:
    """(N, 3) float32 colours of texture_rgb at OBJ texture coordinates st (N, 2)."""
    Ht, Wt = texture_rgb.shape[:2]
    n = len(st)
    # cv2.remap wants maps narrower than 32767 pixels: fold the N samples into rows
    cols = 1024
    rows = -(-n // cols)
    map_x = np.zeros(rows * cols, np.float32)
    map_y = np.zeros(rows * cols, np.float32)
    map_x[:n] = st[:, 0] * Wt - 0.5
    map_y[:n] = (1.0 - st[:, 1]) * Ht - 0.5
    out = cv2.remap(texture_rgb, map_x.reshape(rows, cols), map_y.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n].astype(np.float32)


def rasterise_mesh(points_cam: np.ndarray, faces: np.ndarray, tex_coords: np.ndarray, texture_rgb: np.ndarray,
                   camera: CameraInfo, shading: Shading, near_m: float = 0.05) -> MeshRaster:
    """Draw a textured triangle mesh with a z-buffer.

    points_cam : (V, 3) float, metres, camera optical frame
    faces : (F, 3) int vertex ids
    tex_coords : (V, 2) float in [0, 1], OBJ convention (s right, t up; t = 1 is the
        texture's top row)
    texture_rgb : (Ht, Wt, 3) uint8
    camera : CameraInfo (pinhole, K only)
    shading : Shading
    near_m : triangles with a vertex nearer than this are skipped
    returns MeshRaster
    """
    pts = np.asarray(points_cam, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"rasterise_mesh: expected points_cam of shape (V, 3), got {pts.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"rasterise_mesh: expected faces of shape (F, 3), got {f.shape}")
    tc = np.asarray(tex_coords, dtype=np.float64)
    if tc.shape != (len(pts), 2):
        raise ValueError(f"rasterise_mesh: expected tex_coords of shape ({len(pts)}, 2), got {tc.shape}")
    W, H = camera.width, camera.height
    rgb = np.zeros((H, W, 3), np.uint8)
    depth = np.zeros((H, W), np.float32)
    mask = np.zeros((H, W), bool)

    z = pts[:, 2]
    u, v = project(pts, camera.K).T
    f = f[np.all(z[f] > near_m, axis=1)]
    U, V = u[f], v[f]  # (F, 3) screen coordinates of each corner
    x0 = np.maximum(np.ceil(U.min(axis=1)), 0).astype(np.int64)
    x1 = np.minimum(np.floor(U.max(axis=1)), W - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(V.min(axis=1)), 0).astype(np.int64)
    y1 = np.minimum(np.floor(V.max(axis=1)), H - 1).astype(np.int64)
    area2 = (U[:, 1] - U[:, 0]) * (V[:, 2] - V[:, 0]) - (U[:, 2] - U[:, 0]) * (V[:, 1] - V[:, 0])
    keep = (x1 >= x0) & (y1 >= y0) & (np.abs(area2) > 1e-12)
    f, U, V, y0, area2 = f[keep], U[keep], V[keep], y0[keep], area2[keep]
    if len(f) == 0:
        return MeshRaster(rgb, depth, mask)

    # per triangle: screen-space barycentric weights of corners 0 and 1 as affine
    # functions of the pixel (w_k = A_k x + B_k y + C_k, the signed area of the
    # sub-triangle opposite corner k), and 1/z at the corners, gathered once per candidate
    i, j = [1, 2], [2, 0]  # the corners opposite 0 and 1, in order
    coef = np.empty((len(f), 9))
    coef[:, 0:2] = (V[:, i] - V[:, j]) / area2[:, None]
    coef[:, 2:4] = (U[:, j] - U[:, i]) / area2[:, None]
    coef[:, 4:6] = (U[:, i] * V[:, j] - U[:, j] * V[:, i]) / area2[:, None]
    coef[:, 6:9] = 1.0 / z[f]

    # scanlines: for each (triangle, row) the span of pixel centres inside it, from the
    # crossings of the row with the triangle's non-horizontal edges
    rows = y1[keep] - y0 + 1
    span_tri = np.repeat(np.arange(len(f)), rows)
    span_y = y0[span_tri] + np.arange(rows.sum()) - np.repeat(np.cumsum(rows) - rows, rows)
    left = np.full(len(span_tri), np.inf)
    right = np.full(len(span_tri), -np.inf)
    Us, Vs = U[span_tri], V[span_tri]
    for a, b in ((0, 1), (1, 2), (2, 0)):
        va, vb = Vs[:, a], Vs[:, b]
        crosses = (np.minimum(va, vb) <= span_y) & (span_y <= np.maximum(va, vb)) & (va != vb)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = Us[:, a] + (span_y - va) * (Us[:, b] - Us[:, a]) / (vb - va)
        left = np.where(crosses, np.minimum(left, x), left)
        right = np.where(crosses, np.maximum(right, x), right)
    finite = np.isfinite(left)
    span_x0 = np.where(finite, np.maximum(np.ceil(left - 1e-9), 0), 0).astype(np.int64)
    span_x1 = np.where(finite, np.minimum(np.floor(right + 1e-9), W - 1), -1).astype(np.int64)
    widths = np.maximum(span_x1 - span_x0 + 1, 0)

    tri = np.repeat(span_tri, widths)
    px = np.repeat(span_x0, widths) + np.arange(widths.sum()) - np.repeat(np.cumsum(widths) - widths, widths)
    py = np.repeat(span_y, widths)
    c = coef[tri]
    w0 = c[:, 0] * px + c[:, 2] * py + c[:, 4]
    w1 = c[:, 1] * px + c[:, 3] * py + c[:, 5]
    w2 = 1.0 - w0 - w1

    # screen-space weights interpolate 1/z linearly
    inv_depth = w0 * c[:, 6] + w1 * c[:, 7] + w2 * c[:, 8]
    cand_z = 1.0 / inv_depth
    pix = py * W + px
    zbuf = np.full(W * H, np.inf)
    np.minimum.at(zbuf, pix, cand_z)
    win = np.nonzero(cand_z <= zbuf[pix])[0]
    owner = np.full(W * H, -1, np.int64)
    owner[pix[win]] = win  # ties (shared edges): the last candidate wins
    drawn = np.nonzero(owner >= 0)[0]
    if len(drawn) == 0:  # triangles thinner than a pixel that cover no pixel centre
        return MeshRaster(rgb, depth, mask)
    k = owner[drawn]

    # perspective-correct weights, then per-vertex attributes: texture coordinates and
    # the lighting computed at the vertices (Gouraud shading)
    scale = cand_z[k]
    ck = c[k]
    wp = np.stack([w0[k] * ck[:, 6], w1[k] * ck[:, 7], w2[k] * ck[:, 8]], axis=1) * scale[:, None]
    attr = np.concatenate([tc, _vertex_lighting(pts, f, shading)], axis=1)[f]  # (F, 3 corners, 4)
    interp = np.einsum("nk,nkd->nd", wp.astype(np.float32), attr.astype(np.float32)[tri[k]])
    colour = _sample_bilinear(texture_rgb, interp[:, :2])
    shaded = colour * interp[:, 2:3] + 255.0 * shading.specular * interp[:, 3:4]

    rgb.reshape(-1, 3)[drawn] = np.clip(np.rint(shaded), 0, 255).astype(np.uint8)
    depth.reshape(-1)[drawn] = scale
    mask.reshape(-1)[drawn] = True
    return MeshRaster(rgb, depth, mask)
