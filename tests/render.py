"""A small z-buffered software renderer of textured triangle meshes, for tests.

Tests build surfaces whose true shape is known exactly (a plane, a bent sheet), render
them through a pinhole camera and check that the tracker recovers them.
"""

from __future__ import annotations

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame


def grid_surface(width_m: float, height_m: float, n_u: int, n_v: int):
    """A flat (n_v, n_u) grid: material uv (P, 2) in metres and faces (F, 3)."""
    u, v = np.meshgrid(np.linspace(0, width_m, n_u), np.linspace(0, height_m, n_v))
    uv = np.column_stack([u.ravel(), v.ravel()])
    idx = np.arange(n_u * n_v).reshape(n_v, n_u)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return uv, faces


def texture(rng: np.random.Generator, size: int = 512, textured: bool = True) -> np.ndarray:
    """(size, size, 3) uint8 texture: random blobs and rectangles, or a plain colour."""
    img = np.full((size, size, 3), (200, 120, 90), np.uint8)
    if not textured:
        return img
    import cv2

    for _ in range(260):
        col = tuple(int(x) for x in rng.integers(0, 256, 3))
        x, y = (int(t) for t in rng.integers(0, size, 2))
        r = int(rng.integers(3, 18))
        if rng.random() < 0.5:
            cv2.circle(img, (x, y), r, col, -1)
        else:
            cv2.rectangle(img, (x, y), (x + r, y + int(rng.integers(3, 18))), col, -1)
    return img


def render(points_cam: np.ndarray, uv: np.ndarray, faces: np.ndarray, tex: np.ndarray, camera: CameraInfo,
           size_m: tuple[float, float], background_m: float | None = 2.5) -> tuple[np.ndarray, np.ndarray]:
    """Render a textured mesh.

    points_cam : (P, 3) vertices in the camera frame; uv : (P, 2) material coords in metres
    size_m : (width, height) of the material rectangle the texture spans
    background_m : depth of a fronto-parallel grey wall behind, or None for no background
    returns rgb (H, W, 3) uint8 and depth (H, W) float32 metres (0 = nothing)
    """
    h, w = camera.height, camera.width
    K = camera.K
    depth = np.full((h, w), np.inf)
    tu = np.zeros((h, w))
    tv = np.zeros((h, w))
    z = points_cam[:, 2]
    px = np.column_stack([K[0, 0] * points_cam[:, 0] / z + K[0, 2], K[1, 1] * points_cam[:, 1] / z + K[1, 2]])
    for f in faces:
        p = px[f]
        x0, y0 = np.floor(p.min(axis=0)).astype(int)
        x1, y1 = np.ceil(p.max(axis=0)).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
        if x1 < x0 or y1 < y0:
            continue
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        a, b, c = p
        det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        if abs(det) < 1e-12:
            continue
        l1 = ((xs - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (ys - a[1])) / det
        l2 = ((b[0] - a[0]) * (ys - a[1]) - (xs - a[0]) * (b[1] - a[1])) / det
        l0 = 1 - l1 - l2
        inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        if not inside.any():
            continue
        # Perspective-correct interpolation: interpolate 1/z and attributes / z.
        iz = l0 / z[f[0]] + l1 / z[f[1]] + l2 / z[f[2]]
        zz = 1.0 / iz
        sub = depth[y0 : y1 + 1, x0 : x1 + 1]
        closer = inside & (zz < sub)
        if not closer.any():
            continue
        wu = (l0 * uv[f[0], 0] / z[f[0]] + l1 * uv[f[1], 0] / z[f[1]] + l2 * uv[f[2], 0] / z[f[2]]) * zz
        wv = (l0 * uv[f[0], 1] / z[f[0]] + l1 * uv[f[1], 1] / z[f[1]] + l2 * uv[f[2], 1] / z[f[2]]) * zz
        sub[closer] = zz[closer]
        tu[y0 : y1 + 1, x0 : x1 + 1][closer] = wu[closer]
        tv[y0 : y1 + 1, x0 : x1 + 1][closer] = wv[closer]
    hit = np.isfinite(depth)
    ts = tex.shape[0]
    ti = np.clip((tv / size_m[1] * (ts - 1)).astype(int), 0, ts - 1)
    tj = np.clip((tu / size_m[0] * (ts - 1)).astype(int), 0, ts - 1)
    rgb = np.full((h, w, 3), 90, np.uint8)
    rgb[hit] = tex[ti[hit], tj[hit]]
    out = np.where(hit, depth, 0.0).astype(np.float32)
    if background_m is not None:
        out[~hit] = background_m
    return rgb, out


def frame_of(points_cam, uv, faces, tex, camera, size_m, t=0.0, seq=0, noise_m: float = 0.0,
             rng: np.random.Generator | None = None, background_m: float | None = 2.5) -> RGBDFrame:
    rgb, depth = render(points_cam, uv, faces, tex, camera, size_m, background_m)
    if noise_m > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        valid = depth > 0
        depth = depth + (rng.normal(0, noise_m, depth.shape) * valid).astype(np.float32)
    return RGBDFrame(rgb, depth, camera, t, seq)


def plane_points(uv: np.ndarray, centre: np.ndarray, size_m) -> np.ndarray:
    """Fronto-parallel sheet centred at ``centre`` (camera frame): material x -> +x, y -> +y."""
    p = np.column_stack([uv[:, 0] - size_m[0] / 2, uv[:, 1] - size_m[1] / 2, np.zeros(len(uv))])
    return p + centre


def bent_points(uv: np.ndarray, centre: np.ndarray, size_m, radius_m: float) -> np.ndarray:
    """The sheet bent around a vertical axis (a cylinder of ``radius_m``), middle nearest the camera;
    lengths along the material are kept (isometric bend)."""
    s = uv[:, 0] - size_m[0] / 2
    ang = s / radius_m
    x = radius_m * np.sin(ang)
    zz = radius_m * (1 - np.cos(ang))
    return np.column_stack([x, uv[:, 1] - size_m[1] / 2, zz]) + centre
