"""Drawn rigid bodies (sim.solids) and the robot's gripper and arm (sim.robot_drawing): pure NumPy."""

import numpy as np
import pytest

from ipc.messages import CameraInfo
from sim.raster import Shading, rasterise_mesh
from sim.robot_drawing import GripperLook, elbow_position
from sim.solids import SolidMesh, box, capsule, cylinder, merge, rasterise_solid, sphere

CAMERA = CameraInfo(width=160, height=120, K=np.array([[150.0, 0.0, 79.5], [0.0, 150.0, 59.5], [0.0, 0.0, 1.0]]))
SHADING = Shading(light_dir_cam=np.array([0.0, 0.0, -1.0]), ambient=0.5, diffuse=0.5, specular=0.0)


def _outward(mesh: SolidMesh, centre) -> np.ndarray:
    """(F,) dot products of each face's normal with the direction from ``centre`` to the face."""
    p, f = mesh.points, mesh.faces
    normal = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    return np.einsum("ij,ij->i", normal, p[f].mean(axis=1) - centre)


@pytest.mark.parametrize("mesh, centre", [
    (box((0.1, 0.2, 0.3), (200, 0, 0)), (0.0, 0.0, 0.0)),
    (cylinder((0.1, 0.0, 0.0), (0.1, 0.5, 0.2), 0.05, (0, 200, 0)), (0.1, 0.25, 0.1)),
    (sphere((0.0, 1.0, 0.0), 0.2, (0, 0, 200)), (0.0, 1.0, 0.0)),
])
def test_meshes_are_wound_outwards(mesh, centre):
    # rasterise_solid culls faces turned away from the camera: that needs outward winding
    assert np.all(_outward(mesh, np.asarray(centre)) > 0)


def test_shapes_have_their_size():
    b = box((0.1, 0.2, 0.3), (1, 2, 3))
    np.testing.assert_allclose(np.abs(b.points).max(axis=0), [0.1, 0.2, 0.3])
    assert b.points.shape == (24, 3) and b.faces.shape == (12, 3)
    c = cylinder((0, 0, 0), (0, 0, 0.4), 0.05, (1, 2, 3))
    np.testing.assert_allclose(np.hypot(c.points[:, 0], c.points[:, 1]).max(), 0.05)
    assert c.points[:, 2].min() == 0.0 and c.points[:, 2].max() == pytest.approx(0.4)
    s = sphere((1, 2, 3), 0.25, (1, 2, 3))
    np.testing.assert_allclose(np.linalg.norm(s.points - [1, 2, 3], axis=1), 0.25)
    m = merge([b, c])
    assert len(m.points) == len(b.points) + len(c.points) and m.faces.max() == len(m.points) - 1
    np.testing.assert_array_equal(m.colours[0], [1, 2, 3])


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="3 positive half extents"):
        box((0.1, -0.2, 0.3), (1, 2, 3))
    with pytest.raises(ValueError, match="start and end coincide"):
        cylinder((0, 0, 1), (0, 0, 1), 0.1, (1, 2, 3))
    with pytest.raises(ValueError, match="colour: expected 3 numbers"):
        sphere((0, 0, 1), 0.1, (1, 2))
    with pytest.raises(ValueError, match=r"SolidMesh.faces with vertex ids in \[0, "):
        SolidMesh(np.zeros((3, 3)), np.array([[0, 1, 3]]), np.zeros((3, 3)))


def test_a_box_facing_the_camera_is_drawn_where_and_as_deep_as_it_is():
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, 1.0)  # on the optical axis: its sides face away from the camera
    drawn = rasterise_solid(box((0.05, 0.04, 0.02), (200, 100, 50), T), CAMERA, SHADING)
    rows, cols = np.nonzero(drawn.mask)
    # the front face spans x -0.05..0.05, y -0.04..0.04 at z = 0.98
    u = 150 * np.array([-0.05, 0.05]) / 0.98 + 79.5
    v = 150 * np.array([-0.04, 0.04]) / 0.98 + 59.5
    assert cols.min() == np.ceil(u[0]) and cols.max() == np.floor(u[1])
    assert rows.min() == np.ceil(v[0]) and rows.max() == np.floor(v[1])
    np.testing.assert_allclose(drawn.depth_m[drawn.mask], 0.98, atol=1e-6)
    # light straight from the camera on a face towards it: ambient + diffuse = 1, the colour itself
    np.testing.assert_array_equal(np.unique(drawn.rgb[drawn.mask], axis=0), [[200, 100, 50]])
    assert not drawn.rgb[~drawn.mask].any() and not drawn.depth_m[~drawn.mask].any()


def test_cropped_and_culled_drawing_equals_the_full_frame_rasteriser():
    mesh = merge([capsule((-0.2, 0.1, 1.2), (0.15, -0.1, 0.9), 0.05, (230, 180, 140)),
                  box((0.05, 0.05, 0.05), (40, 40, 40))
                  .transformed(np.array([[1, 0, 0, 0.0], [0, 1, 0, 0.05], [0, 0, 1, 1.0], [0, 0, 0, 1]]))])
    fast = rasterise_solid(mesh, CAMERA, SHADING)
    palette, index = np.unique(mesh.colours, axis=0, return_inverse=True)
    texture = np.repeat(np.repeat(palette[None], 4, axis=0), 4, axis=1)
    tex = np.column_stack([(index.reshape(-1) + 0.5) / len(palette), np.full(len(mesh.points), 0.5)])
    full = rasterise_mesh(mesh.points, mesh.faces, tex, np.ascontiguousarray(texture), CAMERA, SHADING)
    assert fast.mask.sum() > 500
    assert (fast.mask != full.mask).sum() <= 2  # pixel centres exactly on a shared edge may go either way
    both = fast.mask & full.mask
    np.testing.assert_allclose(fast.depth_m[both], full.depth_m[both], atol=1e-6)


def test_nothing_in_view_draws_nothing():
    behind = sphere((0.0, 0.0, -1.0), 0.1, (1, 2, 3))
    assert not rasterise_solid(behind, CAMERA, SHADING).mask.any()
    aside = sphere((5.0, 0.0, 1.0), 0.1, (1, 2, 3))
    assert not rasterise_solid(aside, CAMERA, SHADING).mask.any()
    # a speck between four pixel centres (u = v = 10.5): faces in view, but no pixel centre covered
    speck = sphere(((10.5 - 79.5) / 150, (10.5 - 59.5) / 150, 1.0), 1e-4, (1, 2, 3))
    assert not rasterise_solid(speck, CAMERA, SHADING).mask.any()


def test_elbow_keeps_the_link_lengths_and_bends_up():
    wrist, shoulder = np.array([0.0, 0.0, 1.0]), np.array([0.5, 0.2, 1.1])
    elbow = elbow_position(wrist, shoulder, 0.3, 0.35)
    assert np.linalg.norm(elbow - wrist) == pytest.approx(0.3)
    assert np.linalg.norm(shoulder - elbow) == pytest.approx(0.35)
    line = wrist + (elbow - wrist) @ (shoulder - wrist) / np.sum((shoulder - wrist) ** 2) * (shoulder - wrist)
    assert elbow[2] > line[2] + 0.05, "the elbow is above the line from wrist to shoulder"
    far = elbow_position(wrist, wrist + [2.0, 0.0, 0.0], 0.3, 0.35)
    np.testing.assert_allclose(far, wrist + [0.3, 0.0, 0.0], atol=1e-12)
    with pytest.raises(ValueError, match="positive link lengths"):
        elbow_position(wrist, shoulder, 0.0, 0.35)


def test_gripper_fingers_open_and_close_about_the_fingertip_centre():
    look = GripperLook(max_opening_m=0.08, finger_thickness_m=0.01, finger_length_m=0.05)
    for opening in (0.08, 0.02):
        hand = look.hand(opening)
        fingers = hand.points[np.all(hand.colours == look.finger_rgb, axis=1)]
        assert np.abs(fingers[:, 0]).min() == pytest.approx(opening / 2)
        assert fingers[:, 2].max() == pytest.approx(0.0) and fingers[:, 2].min() == pytest.approx(-0.05)
    assert look.hand(0.08).points[:, 2].max() == pytest.approx(0.0), "nothing reaches past the fingertips"


def test_gripper_and_arm_are_posed_in_the_world_and_reach_the_shoulder():
    look = GripperLook()
    R = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # approaching straight down
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, (0.2, 0.1, 0.8)
    shoulder = np.array([0.6, 0.1, 1.3])
    mesh = look.mesh(T, 0.05, shoulder)
    assert mesh.points[:, 2].min() == pytest.approx(0.8), "the fingertips are the lowest points"
    np.testing.assert_allclose(look.wrist_end(T), [0.2, 0.1, 0.8 + look.finger_length_m + look.palm_depth_m
                                                   + look.wrist_length_m])
    assert np.linalg.norm(mesh.points - shoulder, axis=1).min() < 1e-9, "the upper arm ends at the shoulder"
    with pytest.raises(ValueError, match="GripperLook.arm_radius_m: expected a positive number"):
        GripperLook(arm_radius_m=0.0)
