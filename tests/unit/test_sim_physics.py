"""PyBullet cloth physics: stretch while hanging, grippers and their force sensors, material maths."""

import numpy as np
import pytest

from sim.cloth_mesh import edge_strain, rectangle_cloth, tshirt_cloth
from sim.grasp_execution import pull_apart
from sim.laundry.unfold import TautSensor, UnfoldConfig
from sim.physics import ClothMaterial, ClothPhysics, slerp

pytest.importorskip("pybullet")

# Mean edge strain allowed while hanging. PyBullet users report cloth stretching to
# 1.4-2x its length; the default material measures ~0.8 % (poster by its corners).
MEAN_STRAIN_BOUND = 0.02


def _hang(mesh, corners, seconds):
    physics = ClothPhysics()
    verts = mesh.layout_points([-0.3, 0.0, 1.5], right=[1, 0, 0], down=[0, 0, -1])
    physics.add_cloth(mesh, verts, ClothMaterial())
    grippers = []
    for name in corners:
        at = verts[mesh.landmarks[name]]
        gripper = physics.add_gripper(at)
        gripper.close_on(physics.nodes_near(at, 0.03))
        grippers.append(gripper)
    physics.advance(seconds)
    return physics, grippers


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["poster", "tshirt"])
def test_hanging_cloth_barely_stretches_and_settles(kind):
    if kind == "poster":
        mesh, corners = rectangle_cloth(0.6, 0.45, spacing_m=0.025), ("top_left", "top_right")
    else:
        mesh, corners = tshirt_cloth(spacing_m=0.03), ("left_shoulder", "right_shoulder")
    physics, _ = _hang(mesh, corners, 1.0)
    with physics:
        before = physics.cloth_vertices()
        physics.advance(0.1)
        after = physics.cloth_vertices()
        strain = edge_strain(after, mesh.edges(), mesh.rest_lengths())
        assert np.all(np.isfinite(after))
        assert strain.mean() < MEAN_STRAIN_BOUND
        assert np.percentile(strain, 95) < 0.06
        assert np.abs(after - before).max() < 0.005, "still swinging after 1 s"
        # it hangs: the lowest point is about one cloth height below the grippers
        assert 1.5 - after[:, 2].min() == pytest.approx(mesh.size_m[1], rel=0.1)


def _hang_by_one_corner():
    mesh = rectangle_cloth(0.4, 0.3, spacing_m=0.03)
    physics, _ = _hang(mesh, ("top_left",), 1.5)
    return physics


def _largest_move(physics, seconds):
    before = physics.cloth_vertices()
    physics.advance(seconds)
    return np.abs(physics.cloth_vertices() - before).max()


@pytest.mark.slow
def test_settle_to_rest_stops_a_cloth_that_would_swing_on():
    with _hang_by_one_corner() as physics:  # without air drag, it still swings
        physics.advance(1.5)
        assert _largest_move(physics, 0.1) > 0.01
    with _hang_by_one_corner() as physics:
        z_held = physics.grippers[0].position[2]
        assert physics.settle_to_rest(1.5) > 0
        assert physics.time_s == pytest.approx(3.0)
        assert _largest_move(physics, 0.1) < 0.001
        assert _largest_move(physics, 0.5) < 0.001  # at rest, not between two swings
        # it rests hanging down from the corner, as far as its diagonal reaches
        assert z_held - physics.cloth_vertices()[:, 2].min() == pytest.approx(0.5, rel=0.1)


def test_stop_cloth_stops_every_node():
    with _hang_by_one_corner() as physics:
        assert _largest_move(physics, 1 / 240) > 0.002  # swinging: millimetres a step
        physics.stop_cloth()
        assert _largest_move(physics, 1 / 240) < 0.0005  # from rest, one step of gravity and springs
        with pytest.raises(ValueError, match="non-negative duration"):
            physics.settle_to_rest(-1.0)
    with ClothPhysics() as empty, pytest.raises(ValueError, match="no cloth"):
        empty.stop_cloth()


def test_loaded_nodes_keep_the_mesh_order():
    mesh = rectangle_cloth(0.2, 0.1, spacing_m=0.05)
    verts = mesh.layout_points([0.0, 0.0, 1.0], right=[0, 1, 0], down=[0, 0, -1])
    with ClothPhysics() as physics:
        physics.add_cloth(mesh, verts, ClothMaterial())
        np.testing.assert_allclose(physics.cloth_vertices(), verts, atol=1e-6)
        with pytest.raises(ValueError, match="already has a cloth"):
            physics.add_cloth(mesh, verts, ClothMaterial())


def test_gripper_carries_turns_and_releases_the_cloth():
    mesh = rectangle_cloth(0.3, 0.2, spacing_m=0.025)
    physics, (gripper,) = _hang(mesh, ("top_left",), 0.2)
    with physics:
        held = gripper.held_nodes
        assert len(held) == 3 and gripper.is_closed  # the corner and its two neighbours within 3 cm
        offsets = physics.cloth_vertices()[held] - gripper.position
        # move 20 cm sideways and turn 90 degrees about z
        quat = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
        gripper.move_to(gripper.position + [0.2, 0.0, 0.0], quat)
        physics.advance(0.25)
        np.testing.assert_allclose(gripper.position, [-0.1, 0.0, 1.5], atol=1e-9)
        rot_z90 = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
        np.testing.assert_allclose(physics.cloth_vertices()[held], gripper.position + offsets @ rot_z90.T, atol=1e-3)
        gripper.open()
        assert not gripper.is_closed and gripper.held_nodes.size == 0
        z_before = physics.cloth_vertices()[:, 2].mean()
        physics.advance(0.2)
        assert physics.cloth_vertices()[:, 2].mean() < z_before - 0.1, "released cloth falls"
        with pytest.raises(ValueError, match=r"node ids outside \[0, 117\)"):
            gripper.close_on([500])
        with pytest.raises(ValueError, match="at least one node"):
            gripper.close_on([])
        with pytest.raises(ValueError, match="unit quaternion"):
            gripper.move_to([0, 0, 1], [0, 0, 0, 2])


def test_gripper_close_on_lifts_cloth_from_the_floor():
    """Issue 5's use: a gripper closes on nodes of a lying cloth and lifts them."""
    mesh = rectangle_cloth(0.3, 0.2, spacing_m=0.025)
    verts = mesh.layout_points([0.0, 0.0, 0.02], right=[1, 0, 0], down=[0, 1, 0])
    with ClothPhysics() as physics:
        physics.add_box([1.0, 1.0, 0.01], [0.0, 0.0, -0.01])
        physics.add_cloth(mesh, verts, ClothMaterial())
        physics.advance(0.3)
        corner = physics.cloth_vertices()[mesh.landmarks["bottom_right"]]
        assert corner[2] < 0.03, "lies on the floor"
        gripper = physics.add_gripper(corner)
        gripper.close_on(physics.nodes_near(corner, 0.03))
        gripper.move_to(corner + [0.0, 0.0, 0.2])  # less than the 0.36 m diagonal
        physics.advance(0.5)
        v = physics.cloth_vertices()
        assert v[mesh.landmarks["bottom_right"], 2] == pytest.approx(corner[2] + 0.2, abs=0.01)
        assert v[mesh.landmarks["top_left"], 2] < 0.03, "the far corner still rests on the floor"
        assert edge_strain(v, mesh.edges(), mesh.rest_lengths()).mean() < MEAN_STRAIN_BOUND


def test_rigid_signature_changes_when_a_box_moves():
    with ClothPhysics() as physics:
        box = physics.add_box([0.1, 0.1, 0.1], [0.0, 0.0, 1.0])
        physics.add_gripper([0.0, 0.0, 2.0])  # invisible: not part of the picture
        before = physics.rigid_pose_signature()
        assert len(before) == 1
        physics.grippers[0].move_to([0.5, 0.0, 2.0])
        physics.advance(0.05)
        assert physics.rigid_pose_signature() == before
        physics.pybullet.resetBasePositionAndOrientation(box, [0.1, 0, 1], [0, 0, 0, 1], physicsClientId=physics.client)
        moved = physics.rigid_pose_signature()
        assert moved != before
        visible = physics.add_gripper([0.0, 0.0, 1.5], visual_half_extents_m=[0.02, 0.02, 0.05])
        with_gripper = physics.rigid_pose_signature()
        assert len(with_gripper) == 2
        visible.move_to([0.0, 0.1, 1.5])
        physics.advance(0.05)
        after = physics.rigid_pose_signature()
        assert after[0] == with_gripper[0] and after[1] != with_gripper[1], "a visible gripper is scenery"


def test_material_derives_mass_and_springs_from_the_mesh():
    mesh = rectangle_cloth(0.5, 0.4, spacing_m=0.05)
    material = ClothMaterial(mass_per_area_kg_m2=0.2, stiffness_number=1.5, damping_number=2.0)
    assert material.total_mass_kg(mesh) == pytest.approx(0.2 * 0.5 * 0.4)
    node_mass = 0.04 / mesh.n_vertices
    assert material.spring_stiffness(mesh, 0.01) == pytest.approx(node_mass * 150.0**2)
    assert material.damping(mesh, 0.01) == pytest.approx(node_mass / 0.01 * 2.0)


def test_slerp_halfway_about_z():
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    q1 = np.array([0.0, 0.0, 1.0, 0.0])  # 180 degrees about z
    np.testing.assert_allclose(slerp(q0, q1, 0.5), [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(slerp(q0, -q0, 0.3), q0, atol=1e-12)


def test_set_timestep_steps_finer_from_then_on():
    with ClothPhysics(timestep_s=1.0 / 240.0) as physics:
        physics.add_box([0.1, 0.1, 0.1], [0.0, 0.0, 0.0])
        calls = []
        real_step = physics.pybullet.stepSimulation
        physics.pybullet.stepSimulation = lambda **kw: calls.append(kw) or real_step(**kw)
        try:
            physics.advance(0.1)
            physics.set_timestep(1.0 / 480.0)
            physics.advance(0.1)
        finally:
            physics.pybullet.stepSimulation = real_step
        assert len(calls) == 24 + 48 and physics.time_s == pytest.approx(0.2)
        engine = physics.pybullet.getPhysicsEngineParameters(physicsClientId=physics.client)
        assert engine["fixedTimeStep"] == pytest.approx(1.0 / 480.0)
        with pytest.raises(ValueError, match="set_timestep: expected 0 < timestep_s <= 0.02, got 0"):
            physics.set_timestep(0)


def test_physics_checks_arguments():
    with pytest.raises(ValueError, match="timestep_s"):
        ClothPhysics(timestep_s=0.1)
    with ClothPhysics() as physics:
        with pytest.raises(ValueError, match="no cloth"):
            physics.cloth_vertices()
        with pytest.raises(ValueError, match=r"half_extents_m with shape \(3,\), got \(2,\)"):
            physics.add_box([1.0, 1.0], [0, 0, 0])
        mesh = rectangle_cloth(0.2, 0.1, spacing_m=0.05)
        with pytest.raises(ValueError, match=r"vertices_world of shape \(15, 3\), got \(3, 3\)"):
            physics.add_cloth(mesh, np.zeros((3, 3)), ClothMaterial())


@pytest.mark.slow
def test_wrist_force_reads_the_weight_of_a_cloth_hanging_at_rest():
    mesh = rectangle_cloth(0.4, 0.3, spacing_m=0.03)
    material = ClothMaterial()
    physics, (gripper,) = _hang(mesh, ("top_left",), 1.0)
    with physics:
        assert physics.add_gripper([0.0, 0.0, 1.0]).cloth_force_n().tolist() == [0.0, 0.0, 0.0]  # holds nothing
        physics.settle_to_rest(3.0)
        physics.advance(0.5)
        force = gripper.cloth_force_n()
        weight = material.total_mass_kg(mesh) * 9.81
        # at rest the cloth pulls straight down with all its weight: a sensor that missed the
        # bending springs would read ~11 % less, one that missed the held nodes' own weight less again
        assert force[2] == pytest.approx(-weight, rel=0.02)
        assert np.linalg.norm(force[:2]) < 0.02 * weight


class _Stepper:
    """The two things ``pull_apart`` needs of a scene: its frame rate and one frame of physics."""

    fps = 30

    def __init__(self, physics):
        self.physics = physics

    def step(self):
        self.physics.advance(1.0 / self.fps)


@pytest.mark.slow
def test_pulling_apart_until_taut_stops_once_the_edge_is_straight():
    mesh = rectangle_cloth(0.45, 0.35, spacing_m=0.025)
    material = ClothMaterial()  # _hang's
    physics, (first, second) = _hang(mesh, ("top_left", "top_right"), 0.5)
    config = UnfoldConfig()
    with physics:
        weight = material.total_mass_kg(mesh) * 9.81
        first.move_to(first.position + [0.12, 0.0, 0.0])  # together, the edge sagging between them
        second.move_to(second.position - [0.12, 0.0, 0.0])
        physics.advance(1.0)
        physics.settle_to_rest(2.0)
        frames = []
        sensor = TautSensor(weight, config)
        stopped = pull_apart(_Stepper(physics), first, second, config.pull_speed_m_s, 0.7,
                             lambda: sensor(first.cloth_force_n(), second.cloth_force_n(), first.position,
                                            second.position),
                             lambda: frames.append(1))
        apart = np.linalg.norm(second.position - first.position)
        held_apart = np.linalg.norm(mesh.uv_m[mesh.landmarks["top_left"]] - mesh.uv_m[mesh.landmarks["top_right"]])
        assert stopped and len(frames) > 10
        assert 0.9 * held_apart <= apart <= 1.1 * held_apart
        assert first.position[2] == pytest.approx(1.5) and second.position[2] == pytest.approx(1.5)
        # without the sensor the grippers go on to the limit
        assert not pull_apart(_Stepper(physics), first, second, 0.3, 0.6, lambda: False)
        assert np.linalg.norm(second.position - first.position) == pytest.approx(0.6)
