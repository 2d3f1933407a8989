"""The one scene interface (sim.scene.Scene): both scene kinds implement it and are frame sources."""

import numpy as np
import pytest

from sim.scene import Scene, check_seed

pytest.importorskip("pybullet")


def small_scenes():
    from sim.laundry import LaundryScene, laundry_spec
    from sim.scenes import kinect_camera, make_scene

    return [make_scene("towel_sway", seed=3, width=64, height=48),
            LaundryScene(laundry_spec(4, camera=kinect_camera(64, 48), state="flat"))]


@pytest.mark.slow
def test_both_scene_kinds_are_scenes_and_replay_their_frames_as_sources():
    from sim.frame_source import SceneSource

    for scene in small_scenes():
        assert isinstance(scene, Scene)
        with SceneSource(scene, n_frames=3) as source:
            first = []
            for frame in source.frames():
                first.append((frame, scene.cloth_vertices_cam(), scene.cloth_mask()))
            assert [f.seq for f, _, _ in first] == [0, 1, 2]
            assert [f.timestamp_s for f, _, _ in first] == pytest.approx([0.0, 1 / 30, 2 / 30])
            assert scene.frame_index == 2 and scene.time_s == pytest.approx(2 / 30)
            frame, truth, mask = first[-1]
            assert truth.shape == (len(scene.uv_m), 3) and scene.faces.shape[1] == 3
            assert mask.shape == (48, 64) and mask.any()
            # a second pass resets the scene: the same frames and ground truth, noise included
            again = list(zip(source.frames(), range(3)))
            assert scene.frame_index == 2
            np.testing.assert_array_equal(again[-1][0].rgb, frame.rgb)
            np.testing.assert_array_equal(again[-1][0].depth_m, frame.depth_m)
            np.testing.assert_array_equal(scene.cloth_vertices_cam(), truth)
        assert scene.physics is None  # the source closed its scene


def test_seeds_are_checked():
    assert check_seed(np.int64(3)) == 3
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="non-negative integer seed"):
            check_seed(bad)
