"""The cloth rasteriser (pure NumPy), against a slow reference and known geometry."""

import numpy as np
import pytest

from ipc.messages import CameraInfo
from perception.geometry import vertex_normals
from sim import _reference
from sim.cloth_mesh import rectangle_cloth
from sim.raster import Shading, rasterise_mesh

CAM = CameraInfo(width=80, height=60, K=np.array([[70.0, 0, 39.5], [0, 70.0, 29.5], [0, 0, 1]]))
LIGHT = Shading(light_dir_cam=np.array([0.0, 0.0, -1.0]), ambient=0.5, diffuse=0.5, specular=0.0)


def _sheet(z=1.0, bend=0.0, width=0.6, height=0.4):
    """A sheet facing the camera, centred on the optical axis, optionally bent about y."""
    mesh = rectangle_cloth(width, height, spacing_m=0.05)
    x = mesh.uv_m[:, 0] - width / 2
    y = mesh.uv_m[:, 1] - height / 2
    return mesh, np.c_[x, y, z + bend * x**2]


def test_fronto_parallel_sheet_depth_and_extent():
    mesh, pts = _sheet(z=1.0)
    tex = np.full((8, 8, 3), 200, np.uint8)
    r = rasterise_mesh(pts, mesh.faces, mesh.texture_coords(), tex, CAM, LIGHT)
    assert r.rgb.shape == (60, 80, 3) and r.depth_m.shape == (60, 80) and r.mask.dtype == bool
    np.testing.assert_allclose(r.depth_m[r.mask], 1.0, atol=1e-6)
    # covered columns: |u - cx| <= fx * 0.3 / 1.0 = 21 px
    cols = np.nonzero(r.mask.any(axis=0))[0]
    assert cols.min() == int(np.ceil(39.5 - 21)) and cols.max() == int(np.floor(39.5 + 21))
    # lit head-on: ambient + diffuse = 1, colour unchanged
    assert np.all(r.rgb[r.mask] == 200)


def test_a_sliver_between_pixel_centres_draws_nothing():
    # pixels (u, v) at z = 1: a thin triangle along v = u + 0.25..0.3, which no pixel centre
    # (integer u and v) lies in, though its bounding box holds many
    uv = np.array([[10.3, 10.6], [20.3, 20.6], [20.35, 20.6]])
    pts = np.c_[(uv - [39.5, 29.5]) / 70.0, np.ones(3)]
    tex = np.full((8, 8, 3), 200, np.uint8)
    r = rasterise_mesh(pts, np.array([[0, 1, 2]]), np.full((3, 2), 0.5), tex, CAM, LIGHT)
    assert not r.mask.any() and not r.depth_m.any()


def test_matches_the_reference_rasteriser():
    mesh, pts = _sheet(z=1.0, bend=1.5)
    rot = np.array([[np.cos(0.5), 0, np.sin(0.5)], [0, 1, 0], [-np.sin(0.5), 0, np.cos(0.5)]])
    pts = (pts - [0, 0, 1.0]) @ rot.T + [0.05, 0.0, 1.1]
    r = rasterise_mesh(pts, mesh.faces, mesh.texture_coords(), np.zeros((4, 4, 3), np.uint8), CAM, LIGHT)
    ref = _reference.rasterise_depth(pts, mesh.faces, CAM.K, CAM.width, CAM.height)
    assert np.array_equal(r.mask, ref > 0)
    np.testing.assert_allclose(r.depth_m[r.mask], ref[r.mask], atol=1e-6)


def test_projected_vertex_lands_on_its_depth():
    mesh, pts = _sheet(z=1.2, bend=0.3)
    r = rasterise_mesh(pts, mesh.faces, mesh.texture_coords(), np.zeros((4, 4, 3), np.uint8), CAM, LIGHT)
    uvw = pts @ CAM.K.T
    u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
    col, row = np.rint(u).astype(int), np.rint(v).astype(int)
    inside = (col >= 0) & (col < 80) & (row >= 0) & (row < 60) & r.mask[row.clip(0, 59), col.clip(0, 79)]
    assert inside.sum() > 50
    # the pixel centre is within half a pixel (9 mm here) of the vertex, on a surface
    # sloping at most 0.18: depth agrees to 2 mm
    np.testing.assert_allclose(r.depth_m[row[inside], col[inside]], pts[inside, 2], atol=0.002)


def test_texture_lands_where_its_coordinates_say():
    mesh, pts = _sheet(z=1.0)
    tex = np.zeros((40, 60, 3), np.uint8)
    tex[:20, :30] = (255, 0, 0)  # top-left quarter of the cloth is red
    r = rasterise_mesh(pts, mesh.faces, mesh.texture_coords(), tex, CAM, LIGHT)
    # camera y is down, so the cloth's top-left is the image's top-left
    # the sheet covers rows 16-43 and columns 19-60
    assert tuple(r.rgb[20, 25]) == (255, 0, 0)
    assert tuple(r.rgb[40, 55]) == (0, 0, 0)
    assert tuple(r.rgb[20, 55]) == (0, 0, 0)


def test_nearer_surface_wins_and_both_sides_are_drawn():
    mesh, near = _sheet(z=1.0)
    _, far = _sheet(z=1.5)
    both = np.concatenate([far, near])
    faces = np.concatenate([mesh.faces, mesh.faces + len(far)])
    tc = np.concatenate([mesh.texture_coords()] * 2)
    r = rasterise_mesh(both, faces, tc, np.full((4, 4, 3), 100, np.uint8), CAM, LIGHT)
    assert r.depth_m[30, 40] == pytest.approx(1.0)
    flipped = rasterise_mesh(near, mesh.faces[:, ::-1], mesh.texture_coords(), np.full((4, 4, 3), 100, np.uint8), CAM, LIGHT)
    assert np.array_equal(flipped.mask, r.mask & (r.depth_m < 1.2))


def test_vertex_normals_of_a_flat_sheet():
    mesh, pts = _sheet()
    n = vertex_normals(pts, mesh.faces)
    # faces are counter-clockwise seen from the front (the camera side, -z)
    np.testing.assert_allclose(n, np.tile([0.0, 0.0, -1.0], (len(pts), 1)), atol=1e-12)


def test_input_shapes_are_checked():
    mesh, pts = _sheet()
    with pytest.raises(ValueError, match=r"points_cam of shape \(V, 3\), got \(117, 2\)"):
        rasterise_mesh(pts[:, :2], mesh.faces, mesh.texture_coords(), np.zeros((4, 4, 3), np.uint8), CAM, LIGHT)
    with pytest.raises(ValueError, match=r"tex_coords of shape \(117, 2\)"):
        rasterise_mesh(pts, mesh.faces, mesh.texture_coords()[:5], np.zeros((4, 4, 3), np.uint8), CAM, LIGHT)
