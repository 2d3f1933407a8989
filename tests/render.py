"""Rendered RGB-D frames of textured sheets whose true shape is known, for tests.

Tests build surfaces whose true shape is known exactly (a plane, a bent sheet), render
them through a pinhole camera and check that the tracker recovers them.
"""

from __future__ import annotations

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from sim.raster import Shading, rasterise_mesh


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
    """Render a textured mesh with the simulation's rasteriser, lit from the camera.

    points_cam : (P, 3) vertices in the camera frame; uv : (P, 2) material coords in metres
    size_m : (width, height) of the material rectangle the texture spans
    background_m : depth of a fronto-parallel grey wall behind, or None for no background
    returns rgb (H, W, 3) uint8 and depth (H, W) float32 metres (0 = nothing)
    """
    st = np.column_stack([uv[:, 0] / size_m[0], 1.0 - uv[:, 1] / size_m[1]])  # OBJ: t up
    out = rasterise_mesh(points_cam, faces, st, tex, camera, Shading(light_dir_cam=np.array([0.0, 0.0, -1.0])))
    rgb = np.where(out.mask[..., None], out.rgb, np.uint8(90))
    depth = out.depth_m.copy()
    if background_m is not None:
        depth[~out.mask] = background_m
    return rgb, depth


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


def with_occluder(frame: RGBDFrame, region: np.ndarray, depth_m: float, rng: np.random.Generator,
                  known: bool = False, shadow_px: int = 0) -> RGBDFrame:
    """``frame`` with an object in front of it covering ``region`` (H, W) bool at ``depth_m``.

    The object has a texture of its own (features on it must not bind to the sheet);
    ``known`` also hands its mask to the tracker as ``RGBDFrame.occluder_mask``. The pixels
    within ``shadow_px`` of it lose their depth, as a depth sensor's do beside a discontinuity.
    """
    import cv2

    rgb, depth = frame.rgb.copy(), frame.depth_m.copy()
    blobs = cv2.GaussianBlur(rng.integers(0, 256, rgb.shape, dtype=np.uint8), (0, 0), 4)
    rgb[region] = cv2.normalize(blobs, None, 40, 230, cv2.NORM_MINMAX)[region]
    if shadow_px > 0:
        grown = cv2.dilate(region.astype(np.uint8), np.ones((2 * shadow_px + 1,) * 2, np.uint8)).astype(bool)
        depth[grown & ~region] = 0.0
    depth[region] = depth_m
    return RGBDFrame(rgb, depth, frame.camera, frame.timestamp_s, frame.seq, occluder_mask=region if known else None)


def write_sheet_recording(folder, camera: CameraInfo, n_frames: int, step_m: float, size_m=(0.6, 0.45)) -> None:
    """A converted recording in ``folder``: a textured sheet 1.3 m away drifting ``step_m`` to
    the right each frame, with its true footprint as each frame's reference mask."""
    from perception.geometry import project
    from perception.raster import faces_mask
    from perception.recordings import write_reference_masks
    from perception.sequence import SequenceWriter, open_sequence

    uv, faces = grid_surface(*size_m, 21, 16)
    tex = texture(np.random.default_rng(3))
    footprints = {}
    with SequenceWriter(folder, camera, depth_scale=1000.0) as w:
        for k in range(n_frames):
            pts = plane_points(uv, np.array([step_m * k, 0, 1.3]), size_m)
            w.write(frame_of(pts, uv, faces, tex, camera, size_m, t=k / 30, seq=k))
            footprints[k] = faces_mask(project(pts, camera.K), faces, (camera.height, camera.width))
    write_reference_masks(open_sequence(folder), footprints, {k: "true footprint" for k in footprints})
