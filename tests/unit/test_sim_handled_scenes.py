"""Scenes of a cloth being handled: drawn occluders, their masks, twins, grasps, determinism."""

import numpy as np
import pytest

from perception.geometry import transform_points
from sim.cloth_mesh import edge_strain
from sim.raster import Shading
from sim.scenes import (
    HANDLED_FRAMES,
    HANDLED_SCENES,
    MORE_HANDLED_SCENES,
    PAPER_SCENES,
    SCENES,
    gripper_corner_move_spec,
    kinect_camera,
    make_scene,
    occluder_close_spec,
    occluder_near_camera_spec,
    occluder_plain_spec,
    occluder_sweep_spec,
    table_lift_spec,
)
from sim.solids import rasterise_solid

W, H = 160, 120
SPECS = {"occluder_sweep": occluder_sweep_spec, "gripper_corner_move": gripper_corner_move_spec,
         "table_lift": table_lift_spec}


def test_registry_holds_the_handled_scenes_beside_the_paper_scenes():
    handled = set(HANDLED_SCENES) | set(MORE_HANDLED_SCENES)
    assert set(PAPER_SCENES) | handled == set(SCENES) and not set(PAPER_SCENES) & handled
    assert set(SPECS) == set(HANDLED_SCENES)


@pytest.mark.parametrize("name", HANDLED_SCENES)
def test_specs_are_drawn_from_the_seed_and_vary_with_it(name):
    camera = kinect_camera(W, H)

    def spec(seed):
        return SPECS[name](np.random.default_rng(seed), camera)

    a, b, other = spec(7), spec(7), spec(8)
    np.testing.assert_array_equal(a.cloth_vertices_world, b.cloth_vertices_world)
    assert a.texture_rgb.tobytes() == b.texture_rgb.tobytes() and a.n_frames == b.n_frames
    t = 0.5 * a.n_frames / 30
    np.testing.assert_array_equal(a.occluders(t).points, b.occluders(t).points)
    assert not np.array_equal(a.occluders(t).points, other.occluders(t).points)
    assert a.cloth.size_m != other.cloth.size_m
    for seed in range(12):
        s = spec(seed)
        assert HANDLED_FRAMES[0] <= s.n_frames <= HANDLED_FRAMES[1]
        assert s.occluders is not None and len(s.occluders(0.0).faces) > 0


def test_sweeping_occluders_are_arm_sized_and_cross_the_cloth_in_front_of_it():
    camera = kinect_camera(W, H)
    speeds = []
    for seed in range(12):
        spec = occluder_sweep_spec(np.random.default_rng(seed), camera)
        duration = (spec.n_frames - 1) / 30
        first, last = spec.occluders(0.0), spec.occluders(duration)
        centred = first.points - first.points.mean(axis=0)
        axes = np.linalg.svd(centred, full_matrices=False)[2]
        extents = np.ptp(centred @ axes.T, axis=0)  # along its principal axes, longest first
        assert 0.5 - 1e-6 <= extents[0] <= 0.8 + 0.12 and 0.06 - 1e-6 <= extents[1] <= 0.12 + 1e-6
        speeds.append(np.linalg.norm(last.points.mean(axis=0) - first.points.mean(axis=0)) / duration)
        # 20-40 cm in front of the cloth (its back, at most 6 cm behind its middle)
        assert 0.2 - 0.06 <= -first.points[:, 1].max() and -first.points[:, 1].min() <= 0.4 + 0.06
        # it starts on one side of the cloth and ends on the other, as the camera sees them
        T_cam_world = np.linalg.inv(spec.T_world_cam)
        cloth = transform_points(T_cam_world, spec.cloth_vertices_world)
        x_cloth = cloth[:, 0] / cloth[:, 2]
        sides = []
        for mesh in (first, last):
            p = transform_points(T_cam_world, mesh.points)
            x = p[:, 0] / p[:, 2]
            sides.append(-1 if x.max() < x_cloth.min() else 1 if x.min() > x_cloth.max() else 0)
        assert sorted(sides) == [-1, 1], f"seed {seed}: the occluder is seen over the cloth at its start or end"
    assert 0.35 - 1e-6 <= min(speeds) and max(speeds) <= 1.0 + 1e-6


def test_the_close_sweep_moves_the_same_cloth_with_its_occluder_just_in_front():
    """The same cloth and motion as the far sweep, the occluder 1-11 cm in front of the cloth;
    ``occluder_plain`` is that sweep again on a cloth of one colour."""
    camera = kinect_camera(W, H)
    for seed in range(12):
        far = occluder_sweep_spec(np.random.default_rng(seed), camera)
        close = occluder_close_spec(np.random.default_rng(seed), camera)
        plain = occluder_plain_spec(np.random.default_rng(seed), camera)
        assert close.name == "occluder_close" and plain.name == "occluder_plain"
        np.testing.assert_array_equal(close.cloth_vertices_world, far.cloth_vertices_world)
        back = -close.occluders(0.0).points[:, 1].max()  # its back, in front of the cloth's rest plane
        assert 0.01 <= back <= 0.08 + 0.03 + 1e-6, f"seed {seed}: back {back:.3f} m in front of the cloth"
        np.testing.assert_array_equal(plain.cloth_vertices_world, close.cloth_vertices_world)
        np.testing.assert_array_equal(plain.occluders(0.5).points, close.occluders(0.5).points)
        assert np.ptp(plain.texture_rgb.reshape(-1, 3), axis=0).max() == 0, "one colour"
        assert np.ptp(close.texture_rgb.reshape(-1, 3), axis=0).max() > 0


def test_the_near_camera_ball_is_too_near_to_measure_and_stops_over_the_cloth():
    """``occluder_near_camera``: the sweep's cloth and motion; a ball inside the simulated
    sensor's minimum range, beside the cloth in view at first and last, over it between."""
    from sim.noise import DepthNoiseModel

    camera = kinect_camera(W, H)
    for seed in range(12):
        far = occluder_sweep_spec(np.random.default_rng(seed), camera)
        near = occluder_near_camera_spec(np.random.default_rng(seed), camera)
        assert near.name == "occluder_near_camera"
        np.testing.assert_array_equal(near.cloth_vertices_world, far.cloth_vertices_world)
        T_cam_world = np.linalg.inv(near.T_world_cam)
        cloth = transform_points(T_cam_world, near.cloth_vertices_world)
        cloth_u = cloth[:, 0] / cloth[:, 2]
        shown = [(k / 30, near.occluders(k / 30)) for k in range(near.n_frames)]
        balls = [(t, transform_points(T_cam_world, b.points)) for t, b in shown if b is not None]
        assert balls and all(p[:, 2].max() < DepthNoiseModel().min_range_m for _, p in balls), f"seed {seed}"
        u = [p[:, 0] / p[:, 2] for _, p in balls]
        for x in (u[0], u[-1]):
            assert x.max() < cloth_u.min() or x.min() > cloth_u.max(), f"seed {seed}: comes in and goes out beside it"
        middle = u[len(u) // 2]
        assert cloth_u.min() < middle.mean() < cloth_u.max(), f"seed {seed}: stops over the cloth"


@pytest.mark.slow
@pytest.mark.parametrize("name", HANDLED_SCENES)
def test_every_frame_of_the_script_draws_its_occluder(name):
    camera = kinect_camera(320, 240)
    shading = Shading(light_dir_cam=np.array([0.0, 0.0, -1.0]))
    for seed in range(2):
        spec = SPECS[name](np.random.default_rng(seed), camera)
        T_cam_world = np.linalg.inv(spec.T_world_cam)
        seen = [rasterise_solid(spec.occluders(k / 30).transformed(T_cam_world), camera, shading).mask.sum()
                for k in range(spec.n_frames)]
        assert np.mean(np.array(seen) > 0) > 0.5, f"seed {seed}: the occluder is in view in most frames"


@pytest.mark.slow
def test_same_seed_gives_the_same_frames_and_masks():
    with make_scene("occluder_sweep", seed=3, width=W, height=H, known_occluders=True) as scene:
        first = [(f.rgb.copy(), f.depth_m.copy(), f.occluder_mask.copy()) for f in scene.frames(3)]
        scene.reset(seed=3)
        again = [(f.rgb, f.depth_m, f.occluder_mask) for f in scene.frames(3)]
        for a, b in zip(first, again):
            assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b))
        scene.reset(seed=4)
        assert next(scene.frames(1)).rgb.tobytes() != first[0][0].tobytes()


def _first_frame_over_the_cloth(scene, twin):
    for _ in range(scene.n_frames):
        a, b = scene.render(), twin.render()
        if (scene.occluder_mask() & twin.cloth_mask()).sum() > 20:
            return a, b
        scene.step()
        twin.step()
    raise AssertionError("the occluder never passed in front of the cloth")


@pytest.mark.slow
def test_the_occluder_is_drawn_in_front_of_the_cloth_and_its_mask_is_exact():
    with make_scene("occluder_sweep", seed=1, noise=False, width=W, height=H, known_occluders=True) as scene, \
            make_scene("occluder_sweep", seed=1, noise=False, width=W, height=H, occluders=False) as twin:
        seen, clear = _first_frame_over_the_cloth(scene, twin)
        mask = scene.occluder_mask()
        np.testing.assert_array_equal(seen.occluder_mask, mask)
        assert clear.occluder_mask is None and not twin.occluder_mask().any()
        # the images differ exactly where the occluder is seen: z-buffered against cloth and room
        np.testing.assert_array_equal(seen.depth_m != clear.depth_m, mask)
        changed = np.any(seen.rgb != clear.rgb, axis=2)
        assert not changed[~mask].any() and changed[mask].mean() > 0.95
        over_cloth = mask & twin.cloth_mask()
        gap = clear.depth_m[over_cloth] - seen.depth_m[over_cloth]
        assert gap.min() > 0.1, "20-40 cm in front of the cloth (along the optical axis)"
        # and where its mesh projects, at its depth
        points = scene.virtual_camera.world_to_camera(scene.occluder_mesh_world().points)
        K = scene.camera.K
        u = K[0, 0] * points[:, 0] / points[:, 2] + K[0, 2]
        v = K[1, 1] * points[:, 1] / points[:, 2] + K[1, 2]
        rows, cols = np.nonzero(mask)
        assert cols.min() >= np.floor(u.min()) and cols.max() <= np.ceil(u.max())
        assert rows.min() >= max(np.floor(v.min()), 0) and rows.max() <= min(np.ceil(v.max()), H - 1)
        assert points[:, 2].min() - 1e-4 <= seen.depth_m[mask].min() and seen.depth_m[mask].max() <= points[:, 2].max() + 1e-4
        assert not scene.cloth_mask()[mask].any()


@pytest.mark.slow
def test_gripper_grasps_the_corner_and_carries_it_and_its_twin_moves_alike():
    with make_scene("gripper_corner_move", seed=3, noise=False, width=W, height=H) as scene, \
            make_scene("gripper_corner_move", seed=3, noise=False, width=W, height=H, occluders=False) as twin:
        event = scene.spec.grasp_events[0]
        grasp_frame = round(event.time_s * 30)
        corner0 = scene.cloth_vertices_world()[event.vertex]
        for _ in range(grasp_frame):
            scene.step()
            twin.step()
            np.testing.assert_array_equal(scene.cloth_vertices_cam(), twin.cloth_vertices_cam())
        scene.render()
        mask = scene.occluder_mask()
        assert mask.any()
        K = scene.camera.K
        corner_cam = scene.cloth_vertices_cam()[event.vertex]
        col, row = (K @ corner_cam)[:2] / corner_cam[2]
        rows, cols = np.nonzero(mask)
        assert np.hypot(cols - col, rows - row).min() < 3, "the fingers are at the corner"
        offset = scene.cloth_vertices_world()[event.vertex] - scene.physics.grippers[event.gripper].position
        for _ in range(scene.n_frames - 1 - grasp_frame):
            scene.step()
            now = scene.cloth_vertices_world()[event.vertex] - scene.physics.grippers[event.gripper].position
            assert np.linalg.norm(now - offset) < 0.005, "the corner moves with the gripper"
            assert edge_strain(scene.cloth_vertices_world(), scene.spec.cloth.edges(),
                               scene.spec.cloth.rest_lengths()).mean() < 0.03
        moved = np.linalg.norm(scene.cloth_vertices_world()[event.vertex] - corner0)
        assert moved > 0.15, "lifted and carried sideways"


@pytest.mark.slow
def test_table_lift_lifts_a_flat_cloth_by_its_corner_until_it_hangs():
    with make_scene("table_lift", seed=2, noise=False, width=W, height=H, occluders=False) as scene:
        table = scene.spec.boxes[1]
        top = table.position[2] + table.half_extents_m[2]
        v0 = scene.cloth_vertices_world()
        assert np.ptp(v0[:, 2]) < 0.003 and 0 < v0[:, 2].min() - top < 0.01, "lying flat on the table"
        corner = scene.spec.grasp_events[0].vertex
        width, height = scene.spec.cloth.size_m
        heights = []
        for _ in range(scene.n_frames - 1):
            scene.step()
            v = scene.cloth_vertices_world()
            over = (np.abs(v[:, 0]) < table.half_extents_m[0]) & (np.abs(v[:, 1]) < table.half_extents_m[1])
            assert v[over, 2].min() > top, "no node sinks into the table"
            heights.append(v[corner, 2])
            grips = scene.robot_grips()
            if scene.time_s < scene.spec.grasp_events[0].time_s - 1e-9:
                assert grips == {}, "nothing held before the gripper closes"
            else:  # the robot knows where its fingers are: at the corner it lifts, seen by the camera
                assert list(grips) == [0]
                assert np.linalg.norm(grips[0] - scene.cloth_vertices_cam()[corner]) < 0.03
        speed = np.max(np.diff(heights)) * 30
        assert 0.3 - 0.02 <= speed <= 0.5 + 0.02, "lifted at robot speed"
        assert v[corner, 2] - top > np.hypot(width, height), "lifted by more than its diagonal"
        assert v[:, 2].min() - top > 0.02, "it hangs clear of the table"


@pytest.mark.slow
def test_the_empty_workspace_is_the_view_without_cloth_or_occluder_and_leaves_the_frames_alone():
    with make_scene("table_lift", seed=1, width=W, height=H) as scene, \
            make_scene("table_lift", seed=1, width=W, height=H) as same:
        scene.render_empty()
        np.testing.assert_array_equal(scene.render().rgb, same.render().rgb)  # its noise has its own stream
    with make_scene("table_lift", seed=1, noise=False, width=W, height=H) as scene:
        empty = scene.render_empty()
        frame = scene.render()
        cloth = scene.cloth_mask()
        assert cloth.sum() > 20
        # where the cloth lies the empty view sees the table further away; elsewhere the same surfaces
        far = np.nan_to_num(empty.depth_m - frame.depth_m)
        assert np.median(far[cloth]) > 0.003
        assert np.median(np.abs(far[~cloth & ~scene.occluder_mask()])) < 0.003
        assert empty.occluder_mask is None and empty.held_vertices is None
