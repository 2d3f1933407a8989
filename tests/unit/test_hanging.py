"""Which material point a cloth hanging from one point has lowest, and where (perception.hanging)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perception.hanging import HangingCue, farthest_vertex, lowest_point, lowest_tip
from tests.unit.test_grasp_hanging import camera_looking_at, hanging_triangle, to_cam


def grid_mesh(cells: set[tuple[int, int]], spacing: float = 0.05):
    """Vertices (N, 3) and faces (F, 3) of unit squares ``cells`` (i, j) of a grid, two triangles each."""
    corners = sorted({(i + di, j + dj) for i, j in cells for di in (0, 1) for dj in (0, 1)})
    index = {c: k for k, c in enumerate(corners)}
    faces = []
    for i, j in cells:
        a, b, c, d = index[i, j], index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]
        faces += [(a, b, c), (a, c, d)]
    vertices = np.array([(i * spacing, j * spacing, 0.0) for i, j in corners])
    return vertices, np.array(faces, np.int32), index


def test_the_farthest_vertex_is_farthest_along_the_cloth_not_through_the_air():
    # a U: two 1 x 6 arms joined by a 5 x 1 bottom; held at the top of the left arm, the
    # top of the right arm is farthest along the cloth (6 + 5 + 6 cells) although the
    # bottom right corner is farther in a straight line
    cells = {(0, j) for j in range(6)} | {(4, j) for j in range(6)} | {(i, 0) for i in range(5)}
    vertices, faces, index = grid_mesh(cells)
    held = index[0, 6]
    far, reach = farthest_vertex(vertices, faces, held)
    assert far in (index[4, 6], index[5, 6])
    straight = np.linalg.norm(vertices - vertices[held], axis=1)
    assert int(np.argmax(straight)) == index[5, 0]  # what a straight-line distance would have picked
    assert reach > 1.5 * straight.max()


def test_the_farthest_vertex_of_a_towel_held_by_a_corner_is_the_opposite_corner():
    vertices, faces, index = grid_mesh({(i, j) for i in range(8) for j in range(6)})
    assert farthest_vertex(vertices, faces, index[0, 0])[0] == index[8, 6]
    assert farthest_vertex(vertices, faces, index[8, 0])[0] == index[0, 6]


@pytest.mark.parametrize("held", [-1, 99, 2.0, True])
def test_a_held_vertex_outside_the_mesh_is_refused(held):
    vertices, faces, _ = grid_mesh({(0, 0)})
    with pytest.raises(ValueError, match="held_vertex"):
        farthest_vertex(vertices, faces, held)


def test_a_held_vertex_on_no_face_is_refused():
    vertices, faces, _ = grid_mesh({(0, 0)})
    vertices = np.vstack([vertices, [[1.0, 1.0, 0.0]]])  # a stray vertex
    with pytest.raises(ValueError, match="joined to no other"):
        farthest_vertex(vertices, faces, len(vertices) - 1)


TIP = np.array([0.1, 0.2, 1.0])
UP = np.array([0.0, 0.0, 1.0])


def camera():
    return camera_looking_at(np.array([0.0, -1.5, 1.9]), (0.1, 0.2, 1.15))


def towel(cells: int = 6):
    return grid_mesh({(i, j) for i in range(cells) for j in range(cells)})


def test_the_tip_of_a_hanging_cloth_is_its_lowest_point_less_stray_points_below_it():
    T = camera()
    up_cam = T[:3, :3].T @ UP
    points = np.concatenate([hanging_triangle(tuple(TIP)), [[0.1, 0.2, 0.5], [0.3, 0.2, 0.7]]])
    tip = lowest_tip(to_cam(T, points), up_cam)
    assert np.linalg.norm(T[:3, :3] @ tip + T[:3, 3] - TIP) < 0.012  # the tip, less than the band above it
    np.testing.assert_allclose(lowest_point(to_cam(T, points), up_cam), to_cam(T, TIP[None])[0], atol=1e-9)
    assert lowest_tip(to_cam(T, points)[:10], up_cam) is None  # too little seen
    assert lowest_tip(np.zeros((0, 3)), up_cam) is None
    specks = to_cam(T, TIP + 0.05 * np.arange(30)[:, None] * [1.0, 0.0, 0.0])  # 5 cm apart: no cloth
    assert lowest_tip(specks, up_cam) is None


def carried(cue, T, lift_per_frame, frames, tip=TIP, drop=0.5):
    """Show ``cue`` the hanging triangle and its gripper ``drop`` m above the tip, moved up
    ``lift_per_frame`` m a frame; returns the cue's answers."""
    answers = []
    for k in range(frames):
        shift = np.array([0.0, 0.0, lift_per_frame * k])
        grip = to_cam(T, (tip + shift + [0.0, 0.0, drop])[None])[0]
        answers.append(cue.update(to_cam(T, hanging_triangle(tuple(tip + shift))), grip))
    return answers


def lifted_cue(T, vertices, faces, held):
    """A cue that has seen the cloth's tip on a table 1 cm below it, then clear of it."""
    cue = HangingCue(vertices, faces, held, T, support_height_m=TIP[2] - 0.01)
    assert carried(cue, T, 0.0, 1) == [None]  # on the table
    return cue


def test_once_the_cloth_hangs_at_rest_its_farthest_material_point_is_placed_at_its_tip():
    T = camera()
    vertices, faces, index = towel()  # 0.3 m square: 0.42 m from corner to corner
    cue = lifted_cue(T, vertices, faces, index[0, 0])
    answers = carried(cue, T, 0.0, 4, tip=TIP + [0.0, 0.0, 0.3])  # lifted 30 cm
    assert answers[:2] == [None] * 2  # not yet known to be still
    vertex, point = answers[3]
    assert vertex == index[6, 6] and cue.reach_m == pytest.approx(0.3 * np.sqrt(2), rel=0.2)
    assert np.linalg.norm(T[:3, :3] @ point + T[:3, 3] - (TIP + [0.0, 0.0, 0.3])) < 0.012
    # carried up at a steady speed it still hangs at rest relative to the gripper
    moving = lifted_cue(T, vertices, faces, index[0, 0])
    assert carried(moving, T, 0.01, 8, tip=TIP + [0.0, 0.0, 0.1])[-1] is not None


def test_a_cloth_on_its_support_falling_held_near_its_lowest_point_or_never_lifted_says_nothing():
    T = camera()
    vertices, faces, index = towel()
    on_table = HangingCue(vertices, faces, index[0, 0], T, support_height_m=TIP[2] - 0.02)  # within 3 cm
    assert carried(on_table, T, 0.0, 8) == [None] * 8
    # the tip moving 3 cm a frame relative to the gripper: falling or swinging
    falling = lifted_cue(T, vertices, faces, index[0, 0])
    answers = []
    for k in range(8):
        tip = TIP + [0.0, 0.0, 0.3 - 0.03 * k]
        answers.append(falling.update(to_cam(T, hanging_triangle(tuple(tip))), to_cam(T, (TIP + [0, 0, 0.8])[None])[0]))
    assert answers == [None] * 8
    # the gripper 5 cm above the lowest point: it holds the cloth near its lowest point
    near_tip = lifted_cue(T, vertices, faces, index[0, 0])
    assert carried(near_tip, T, 0.0, 8, tip=TIP + [0.0, 0.0, 0.3], drop=0.05) == [None] * 8
    # never seen on the table: handed over hanging, not lifted off it by this gripper
    handed = HangingCue(vertices, faces, index[0, 0], T, support_height_m=TIP[2] - 0.5)
    assert carried(handed, T, 0.0, 8) == [None] * 8
    # no support given: any cloth hanging at rest counts
    assert carried(HangingCue(vertices, faces, index[0, 0], T), T, 0.0, 4)[-1] is not None


def test_the_unfold_robot_sends_the_lowest_point_with_its_grip_only_while_one_hand_holds_the_cloth():
    from ipc.messages import CameraInfo, RGBDFrame
    from launch_scripts.trial_runner.unfold import _Tracking

    camera = CameraInfo(width=64, height=48, K=np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]))
    sent = []
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = Rotation.from_rotvec([np.pi, 0.0, 0.0]).as_matrix()  # looking down
    scene = SimpleNamespace(
        T_world_cam=T_world_cam, cloth_vertices_cam=lambda: np.zeros((4, 3)),
        render=lambda: RGBDFrame(rgb=np.zeros((48, 64, 3), np.uint8), depth_m=np.ones((48, 64), np.float32),
                                 camera=camera, seq=len(sent)))
    estimate = SimpleNamespace(vertices=np.zeros((4, 3)), confidence=1.0, lost=False)
    link = SimpleNamespace(estimate_of=lambda frame: sent.append(frame) or estimate)
    tracking = _Tracking(scene, link, {}, {}, {}, reference=scene.render())
    turned = Rotation.from_rotvec([0.0, 0.0, 0.5])  # a wrist turned about the world's vertical
    hand = SimpleNamespace(gripper=SimpleNamespace(position=np.array([0.0, 0.0, -1.0]), quat_xyzw=turned.as_quat()))
    tracking.holds = [(3, hand)]
    shown = []

    def cue(answer):
        return SimpleNamespace(update=lambda points, grip: shown.append(grip) or answer)

    tracking.hanging = cue((7, np.array([0.0, 0.5, 1.2])))
    tracking()
    np.testing.assert_allclose(shown[-1], [0.0, 0.0, 1.0], atol=1e-12)  # the gripper, in the camera frame
    np.testing.assert_array_equal(sent[-1].held_vertices, [3, 7])
    np.testing.assert_allclose(sent[-1].held_points_m, [[0.0, 0.0, 1.0], [0.0, 0.5, 1.2]], atol=1e-12)
    # the gripper's orientation in the camera frame, which looks down the world's vertical:
    # its turn about that vertical is a turn the other way about the camera's axis; none for
    # the point seen lowest
    R_cam_gripper = Rotation.from_quat(sent[-1].held_quats_xyzw[0]).as_matrix()
    np.testing.assert_allclose(R_cam_gripper, np.diag([1.0, -1.0, -1.0]) @ turned.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(Rotation.from_matrix(R_cam_gripper @ np.diag([1.0, -1.0, -1.0])).as_rotvec(),
                               [0.0, 0.0, -0.5], atol=1e-12)
    assert np.isnan(sent[-1].held_quats_xyzw[1]).all()
    assert tracking.lowest_sent == 1
    tracking.hanging = cue(None)  # not hanging at rest yet
    tracking()
    np.testing.assert_array_equal(sent[-1].held_vertices, [3])
    tracking.hanging = cue((7, np.array([0.0, 0.5, 1.2])))
    tracking.holds.append((7, hand))  # both hands hold: the cloth no longer hangs from one point
    tracking()
    np.testing.assert_array_equal(sent[-1].held_vertices, [3, 7])
    assert len(sent[-1].held_points_m) == 2 and len(shown) == 2  # not asked with two hands on the cloth
    assert tracking.lowest_sent == 1
