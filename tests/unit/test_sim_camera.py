"""Virtual camera: intrinsics agree with PyBullet's matrices and with what is drawn."""

import numpy as np
import pytest

from ipc.messages import CameraInfo
from perception.geometry import (
    boundary_vertices,
    check_transform,
    look_at,
    transform_points,
)
from sim.camera import VirtualCamera
from sim.cloth_mesh import rectangle_cloth
from sim.opengl import depth_from_zbuffer, projection_matrix, view_matrix
from sim.physics import ClothMaterial, ClothPhysics
from sim.scenes import kinect_camera

pybullet = pytest.importorskip("pybullet")


def test_projection_matrix_equals_pybullet_fov_matrix():
    # the camera whose image the TinyRenderer draws with a symmetric frustum: cx = W / 2 and,
    # under its row sampling (sim.opengl's docstring), cy = H / 2 - 1
    f = 0.5 * 480 / np.tan(np.radians(25.0))
    cam = CameraInfo(640, 480, np.array([[f, 0.0, 320.0], [0.0, f, 239.0], [0.0, 0.0, 1.0]]))
    ours = projection_matrix(cam, 0.1, 8.0)
    theirs = pybullet.computeProjectionMatrixFOV(50.0, 640 / 480, 0.1, 8.0)
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_view_matrix_equals_pybullet_look_at():
    eye, target = [0.3, -1.2, 1.4], [0.0, 0.1, 1.0]
    np.testing.assert_allclose(view_matrix(look_at(eye, target)),
                               pybullet.computeViewMatrix(eye, target, [0, 0, 1]), atol=1e-6)


def test_look_at_is_an_optical_frame():
    T = look_at([0, -1, 1], [0, 0, 1])
    # the camera looks along +y world; image x is world +x, image y is world -z
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(transform_points(T, [[0, 0, 1.0]]), [[0, 0, 1]], atol=1e-12)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match=r"T with shape \(4, 4\), got \(3, 3\)"):
        check_transform("T", np.eye(3))


def test_depth_from_zbuffer_inverts_the_opengl_depth():
    near, far = 0.1, 8.0
    z = np.array([[0.5, 1.0, 3.0]])
    zb = (far * near / z - far) / (near - far)
    np.testing.assert_allclose(depth_from_zbuffer(zb, near, far), z, rtol=1e-6)
    assert depth_from_zbuffer(np.ones((1, 1)), near, far)[0, 0] == 0


@pytest.mark.parametrize("cx, cy", [(32.0, 23.0), (27.3, 20.6)])
def test_pybullet_draws_edges_where_K_projects_them(cx, cy):
    """A box edge at sub-pixel image position u first covers column ceil(u), also off-centre.

    The box is 1 mm thick, so its side faces shift the edge by < 0.03 px here."""
    cam = CameraInfo(64, 48, np.array([[60.0, 0, cx], [0, 60.0, cy], [0, 0, 1]]))
    camera = VirtualCamera(cam, look_at([0, 0, 0], [0, 1, 0]))
    with ClothPhysics() as physics:
        box = physics.add_box([1.0, 0.0005, 1.0], [10.0, 10.0, 10.0])
        for edge in (12.3, 30.4, 30.6, 51.7):
            # the box's left edge at image column `edge`, at 1 m depth
            x = (edge - cx) / 60.0
            physics.pybullet.resetBasePositionAndOrientation(box, [x + 1.0, 1.0005, 0.0], [0, 0, 0, 1],
                                                             physicsClientId=physics.client)
            ids = camera.render_rigid(physics).body_ids
            assert np.argmax(ids[24] == box) == int(np.ceil(edge))
        for edge in (10.3, 20.6, 35.2):
            y = (edge - cy) / 60.0  # the box's top edge at image row `edge`
            physics.pybullet.resetBasePositionAndOrientation(box, [0.0, 1.0005, -y - 1.0], [0, 0, 0, 1],
                                                             physicsClientId=physics.client)
            ids = camera.render_rigid(physics).body_ids
            assert np.argmax(ids[:, 32] == box) == int(np.ceil(edge))


@pytest.fixture(scope="module")
def hanging():
    """A 0.6 x 0.45 m cloth hanging from two corners in front of a wall, rendered at 640x480."""
    mesh = rectangle_cloth(0.6, 0.45, spacing_m=0.025)
    verts = mesh.layout_points([-0.3, 0.0, 1.4], right=[1, 0, 0], down=[0, 0, -1])
    physics = ClothPhysics()
    physics.add_box([2.0, 0.02, 1.5], [0.0, 0.6, 1.5], rgba=(0.8, 0.8, 0.7, 1))
    physics.add_cloth(mesh, verts, ClothMaterial())
    for corner in ("top_left", "top_right"):
        at = verts[mesh.landmarks[corner]]
        physics.add_gripper(at).close_on(physics.nodes_near(at, 0.03))
    physics.advance(0.5)
    camera = VirtualCamera(kinect_camera(640, 480), look_at([0.2, -1.2, 1.4], [0.0, 0.0, 1.15]))
    texture = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    yield physics, camera, texture
    physics.close()


def test_projected_cloth_vertex_lands_on_its_depth(hanging):
    physics, camera, texture = hanging
    image = camera.render(physics, texture)
    pts = camera.world_to_camera(physics.cloth_vertices())
    uvw = pts @ camera.camera.K.T
    col = np.rint(uvw[:, 0] / uvw[:, 2]).astype(int)
    row = np.rint(uvw[:, 1] / uvw[:, 2]).astype(int)
    assert np.all((col >= 0) & (col < 640) & (row >= 0) & (row < 480))
    # boundary vertices may round to a pixel just off the cloth; interior ones may not
    interior = np.setdiff1d(np.arange(len(pts)), boundary_vertices(physics.cloth_mesh.faces))
    cloth = image.body_ids[row, col] == physics.cloth_id
    assert cloth[interior].all(), "a hanging cloth facing the camera sees all its vertices"
    diff = np.abs(image.depth_m[row, col] - pts[:, 2])[interior]
    assert np.median(diff) < 0.001 and np.percentile(diff, 95) < 0.003


def test_our_cloth_raster_matches_pybullet_tinyrenderer(hanging):
    """PyBullet draws the soft body itself when it is made visible: same outline, same depth."""
    physics, camera, texture = hanging
    ours = camera.render(physics, texture)
    p = physics.pybullet
    p.changeVisualShape(physics.cloth_id, -1, rgbaColor=[1, 1, 1, 1], physicsClientId=physics.client)
    try:
        theirs = camera.render_rigid(physics)
    finally:
        p.changeVisualShape(physics.cloth_id, -1, rgbaColor=[1, 1, 1, 0], physicsClientId=physics.client)
    a = ours.body_ids == physics.cloth_id
    b = theirs.body_ids == physics.cloth_id
    assert (a & b).sum() / (a | b).sum() > 0.97
    both = a & b
    assert np.median(np.abs(ours.depth_m[both] - theirs.depth_m[both])) < 0.001


def test_background_is_cached_until_a_rigid_body_moves(hanging):
    physics, camera, texture = hanging
    first = camera.render(physics, texture)
    again = camera.render(physics, texture)
    assert np.array_equal(first.rgb, again.rgb) and np.array_equal(first.depth_m, again.depth_m)
    cached = camera._background
    box = physics.add_box([0.1, 0.1, 0.1], [0.6, 0.3, 1.0], rgba=(1, 0, 0, 1))
    try:
        moved = camera.render(physics, texture)
        assert camera._background is not cached
        assert (moved.body_ids == box).sum() > 100
    finally:
        physics.pybullet.removeBody(box, physicsClientId=physics.client)


def test_camera_rejects_distortion():
    cam = CameraInfo(64, 48, np.array([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]]), D=np.array([0.1, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="pinhole"):
        VirtualCamera(cam, np.eye(4))
