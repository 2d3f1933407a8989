"""Scoring runs on handled scenes (sim.evaluation.handled), on constructed recordings with known answers."""

import numpy as np
import pytest

from ipc.messages import CameraInfo, MeshEstimate, RGBDFrame
from sim.cloth_mesh import rectangle_cloth
from sim.evaluation import SceneRecording
from sim.evaluation.handled import CONFIDENT, HOLD_REACH_M, WRONG_MM, _holding, cloth_hidden_fraction, score_run
from sim.ground_truth import hidden_behind_occluder

W, H = 100, 80
CAMERA = CameraInfo(width=W, height=H, K=np.array([[100.0, 0.0, 49.5], [0.0, 100.0, 39.5], [0.0, 0.0, 1.0]]))
T = 4


def _recording():
    """A flat 0.6 x 0.4 m cloth 1.5 m away, sliding right 1 cm a frame; an occluder at 1 m
    over image columns 40-59 in frames 1 and 2 only."""
    mesh = rectangle_cloth(0.6, 0.4, spacing_m=0.05)
    flat = np.c_[mesh.uv_m - [0.3, 0.2], np.full(mesh.n_vertices, 1.5)]
    gt = np.stack([flat + [0.01 * t, 0.0, 0.0] for t in range(T)])
    frames = [RGBDFrame(rgb=np.zeros((H, W, 3), np.uint8), depth_m=np.ones((H, W), np.float32), camera=CAMERA,
                        timestamp_s=t / 30, seq=t) for t in range(T)]
    masks, depths = [], []
    for t in range(T):
        m = np.zeros((H, W), bool)
        if t in (1, 2):
            m[:, 40:60] = True
        masks.append(m)
        depths.append(np.where(m, 1.0, 0.0).astype(np.float32))
    rec = SceneRecording("constructed", 0, False, frames, gt, mesh.faces, [np.ones((H, W), bool)] * T, masks, depths)
    return rec, mesh


def _estimate(vertices, mesh, confidence=1.0, lost=False, visible=None):
    canonical = np.c_[mesh.uv_m, np.zeros(mesh.n_vertices)]
    return MeshEstimate(vertices=vertices, faces=mesh.faces.astype(np.int32), boundary=np.zeros(0, np.int32),
                        canonical=canonical, confidence=confidence, lost=lost, timing_ms=5.0, visible=visible)


def test_a_perfect_estimate_scores_zero_and_keeps_the_hidden_area():
    rec, mesh = _recording()
    score = score_run(rec, [_estimate(v, mesh) for v in rec.gt_vertices])
    assert max(e.max() for e in score.errors_mm) < 1e-9
    for t in range(T):
        np.testing.assert_array_equal(score.hidden[t], hidden_behind_occluder(rec.gt_vertices[t], rec.occluder_masks[t],
                                                                             rec.occluder_depths[t], CAMERA.K))
    assert score.hidden[1].sum() > 10 and not score.hidden[0].any() and not score.hidden[3].any()
    np.testing.assert_allclose(score.area_ratio[[1, 2]], 1.0)
    assert np.isnan(score.area_ratio[[0, 3]]).all()
    summary = score.summary()
    assert summary["mean_mm"] < 1e-6 and summary["occluded_area_ratio"] == pytest.approx(1.0)
    assert summary["wrong_frames"] == 0 and summary["lost_frames"] == 0 and summary["frames_with_hidden_vertices"] == 2
    np.testing.assert_allclose(cloth_hidden_fraction(rec), [h.mean() for h in score.hidden])


def test_a_squeezed_hidden_part_shows_in_the_area_ratio():
    rec, mesh = _recording()
    estimates = []
    for t, v in enumerate(rec.gt_vertices):
        v = v.copy()
        if t == 1:
            hidden = hidden_behind_occluder(v, rec.occluder_masks[1], rec.occluder_depths[1], CAMERA.K)
            middle = v[hidden, 0].mean()
            v[hidden, 0] = middle + 0.5 * (v[hidden, 0] - middle)  # squeezed to half its width
        estimates.append(_estimate(v, mesh))
    score = score_run(rec, estimates)
    assert score.area_ratio[1] == pytest.approx(0.5) and score.area_ratio[2] == pytest.approx(1.0)
    summary = score.summary()
    assert summary["occluded_area_ratio_worst"] == pytest.approx(0.5)
    assert 0.6 < summary["occluded_area_ratio"] < 0.9, "weighted by the hidden area of frames 1 and 2"


def test_confident_wrong_frames_and_lost_flags_are_counted():
    rec, mesh = _recording()
    off = np.array([0.0, 0.0, (WRONG_MM + 10) / 1000])  # every vertex 40 mm behind its material point
    runs = {
        "confident": [_estimate(v + (off if t else 0), mesh, confidence=CONFIDENT) for t, v in enumerate(rec.gt_vertices)],
        "doubtful": [_estimate(v + (off if t else 0), mesh, confidence=0.3, lost=t == 3)
                     for t, v in enumerate(rec.gt_vertices)],
    }
    confident = score_run(rec, runs["confident"]).summary()
    assert confident["wrong_frames"] == 3 and confident["wrong_confident_frames"] == 3
    doubtful = score_run(rec, runs["doubtful"]).summary()
    assert doubtful["wrong_frames"] == 3 and doubtful["wrong_confident_frames"] == 0 and doubtful["lost_frames"] == 1
    assert doubtful["mean_mm"] == pytest.approx((WRONG_MM + 10) * 3 / 4)
    even = score_run(rec, runs["doubtful"]).summary(np.arange(0, T, 2))
    assert even["frames"] == 2 and even["mean_mm"] == pytest.approx((WRONG_MM + 10) / 2)


def test_a_wrong_estimate_not_flagged_lost_within_three_frames_is_counted_from_the_fourth():
    from sim.evaluation.handled import LOST_WITHIN, HandledScore

    # frames: right, then wrong for 6 frames (flagged lost from the 5th of them), right, wrong again for 4
    wrong = [0, 1, 1, 1, 1, 1, 1, 0, 1, 1, 1, 1]
    lost = [0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0]
    n = len(wrong)
    score = HandledScore(errors_mm=[np.full(5, (WRONG_MM + 10) if w else 1.0) for w in wrong],
                         hidden=[np.zeros(5, bool)] * n, area_ratio=np.full(n, np.nan), hidden_area_m2=np.zeros(n),
                         mesh_area_m2=np.ones(n), confidence=np.full(n, 0.9), lost=np.array(lost, bool),
                         timing_ms=np.ones(n), shown_hidden=np.full(n, -1))
    assert LOST_WITHIN == 3
    # the 4th wrong frame of the first run (index 4) is the only one not flagged in time there;
    # in the second run the 4th wrong frame (index 11)
    np.testing.assert_array_equal(np.flatnonzero(score.wrong_unflagged_late()), [4, 11])
    summary = score.summary()
    assert summary["wrong_unflagged_late_frames"] == 2 and summary["wrong_confident_frames"] == 10
    assert score.summary(np.arange(0, 8))["wrong_unflagged_late_frames"] == 1


def test_a_rebuilt_mesh_is_bound_again_where_it_changes():
    rec, mesh = _recording()
    small = rectangle_cloth(0.3, 0.2, spacing_m=0.05)
    small_flat = np.c_[small.uv_m - [0.15, 0.1], np.full(small.n_vertices, 1.5)]
    estimates = [_estimate(rec.gt_vertices[0], mesh), _estimate(rec.gt_vertices[1] + [0, 0, 0.1], mesh)]
    estimates += [_estimate(small_flat + [0.01 * t, 0.0, 0.0], small) for t in (2, 3)]  # re-acquired, on the cloth
    score = score_run(rec, estimates)
    assert [len(e) for e in score.errors_mm] == [mesh.n_vertices] * 2 + [small.n_vertices] * 2
    assert score.errors_mm[1].mean() == pytest.approx(100.0)
    assert score.errors_mm[2].max() < 1e-6 and score.errors_mm[3].max() < 1e-6
    np.testing.assert_array_equal(score.new_mesh, [False, False, True, False])  # counted where it was built
    assert score.summary()["new_meshes"] == 1 and score.series()["new_mesh_frames"] == [2]
    # a mesh re-registered with the same canonical mesh keeps its material points
    same = [_estimate(rec.gt_vertices[0], mesh)] + [_estimate(v + [0.0, 0.0, 0.05], mesh) for v in rec.gt_vertices[1:]]
    assert all(e.mean() == pytest.approx(50.0) for e in score_run(rec, same).errors_mm[1:])
    assert score_run(rec, same).summary()["new_meshes"] == 0


def test_hidden_vertices_the_tracker_calls_visible_are_counted():
    rec, mesh = _recording()
    score = score_run(rec, [_estimate(v, mesh, visible=np.ones(mesh.n_vertices, bool)) for v in rec.gt_vertices])
    np.testing.assert_array_equal(score.shown_hidden, [h.sum() for h in score.hidden])
    assert score.summary()["hidden_shown_visible"] == pytest.approx(1.0)
    assert score_run(rec, [_estimate(v, mesh) for v in rec.gt_vertices]).summary()["hidden_shown_visible"] is None


def test_every_keeps_every_other_frame_with_its_truth():
    rec, _ = _recording()
    half = rec.every(2)
    assert [f.seq for f in half.frames] == [0, 2] and half.frame_step == 2
    np.testing.assert_array_equal(half.gt_vertices, rec.gt_vertices[::2])
    assert half.occluder_masks[1] is rec.occluder_masks[2]
    known = half.known_occluder_frames()
    np.testing.assert_array_equal(known[1].occluder_mask, rec.occluder_masks[2])
    assert half.frames[1].occluder_mask is None
    with pytest.raises(ValueError, match="positive integer step"):
        rec.every(0)


def test_a_closing_gripper_holds_the_vertex_nearest_to_it_until_it_opens():
    rec, mesh = _recording()
    previous = _estimate(rec.gt_vertices[0], mesh)
    near = int(np.argmin(np.linalg.norm(rec.gt_vertices[0] - [0.1, 0.05, 1.5], axis=1)))
    held: dict = {}
    assert _holding(rec.frames[0], {}, held, previous).held_vertices is None, "nothing held before a grasp"
    point = np.array([0.1, 0.05, 1.5]) + 0.004
    frame = _holding(rec.frames[1], {2: point}, held, previous)
    assert held == {2: near}
    np.testing.assert_array_equal(frame.held_vertices, [near])
    np.testing.assert_allclose(frame.held_points_m, [point])
    # later frames keep the bound vertex wherever the gripper goes, beside a second gripper
    moved = _estimate(rec.gt_vertices[0] + [0.3, 0.0, 0.0], mesh)
    other = moved.vertices[0]  # bound on the latest estimate, not on the first
    frame = _holding(rec.frames[2], {2: point + [0.0, 0.2, 0.0], 0: other}, held, moved)
    np.testing.assert_array_equal(frame.held_vertices, [0, near])
    assert frame.held_vertices.dtype == np.int32
    assert _holding(rec.frames[3], {}, held, moved).held_vertices is None and held == {}, "opened: released"


def test_a_gripper_with_no_vertex_between_its_fingers_holds_none_until_one_comes():
    """A mesh built anew on a hanging cloth often ends short of the corner in the fingers:
    its nearest vertex, centimetres away, is not what the gripper holds."""
    rec, mesh = _recording()
    previous = _estimate(rec.gt_vertices[0], mesh)
    nearest = int(np.argmin(np.linalg.norm(rec.gt_vertices[0] - [0.1, 0.05, 1.5], axis=1)))
    point = rec.gt_vertices[0][nearest] + [0.0, 0.0, -(HOLD_REACH_M + 0.01)]  # in front of the cloth
    held: dict = {}
    frame = _holding(rec.frames[1], {0: point}, held, previous)
    assert frame.held_vertices is None and held == {}
    closer = _estimate(rec.gt_vertices[0] + [0.0, 0.0, -HOLD_REACH_M], mesh)
    frame = _holding(rec.frames[2], {0: point}, held, closer)
    np.testing.assert_array_equal(frame.held_vertices, [nearest])
