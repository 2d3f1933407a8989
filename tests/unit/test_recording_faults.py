"""Faults put into recorded frames (perception.recording_faults), and benchmarks/real_faults.py
on a small recording made here (a textured sheet drifting in front of the camera, its true
footprint as the reference mask; the cut shows a second recording, a wall)."""

import dataclasses
import json

import numpy as np
import pytest

from ipc.messages import CameraInfo, RGBDFrame
from perception.recording_faults import ARM_RGB, bar_in_front, cut_to, depth_holes, no_depth
from perception.sequence import SequenceWriter
from tests.benchmark_scripts import load_benchmark
from tests.render import frame_of, grid_surface, plane_points, texture, write_sheet_recording

bench = load_benchmark("real_faults")

CAM = CameraInfo.from_fov(320, 240, np.deg2rad(45))
BOX = (60, 180, 100, 220)  # y0, y1, x0, x1


def _frame(seq=0, depth_m=1.0):
    rng = np.random.default_rng(seq)
    rgb = rng.integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8)
    depth = np.full((CAM.height, CAM.width), depth_m, np.float32)
    depth[:, :50] = 0.0  # a strip the sensor did not measure
    return RGBDFrame(rgb, depth, CAM, timestamp_s=seq / 30, seq=seq)


@pytest.mark.parametrize("progress", [0.0, 0.5, 1.0])
def test_a_bar_sweeps_across_the_box_in_front_of_it(progress):
    frame = _frame()
    out, bar = bar_in_front(frame, BOX, progress, 20, 0.25)
    cols = np.flatnonzero(bar.any(axis=0))
    y0, y1, x0, x1 = BOX
    if progress == 0.0:
        assert cols.max() < x0  # waiting on the left
    elif progress == 1.0:
        assert cols.min() >= x1  # gone on the right
    else:
        assert len(cols) == 20 and x0 < cols.mean() < x1
    rows = np.flatnonzero(bar.any(axis=1))
    assert rows.min() == 0 and rows.max() == y1 + (y1 - y0) // 5 - 1  # from the top to below the box
    np.testing.assert_allclose(out.depth_m[bar], 1.0 - 0.25)  # 25 cm in front of the box's surface
    np.testing.assert_array_equal(out.depth_m[~bar], frame.depth_m[~bar])
    np.testing.assert_array_equal(out.rgb[~bar], frame.rgb[~bar])
    middle = out.rgb[0, int(cols.mean())]
    assert np.abs(middle.astype(int) - ARM_RGB).max() <= 2  # the arm's colour, brightest in its middle
    assert out.seq == frame.seq and out.camera is frame.camera


def test_a_bar_outside_the_image_or_over_no_depth_changes_nothing():
    frame = _frame()
    out, bar = bar_in_front(frame, (0, 240, 0, 40), 0.0, 30, 0.25)  # left of the image
    assert out is frame and not bar.any()
    out, bar = bar_in_front(frame, (0, 240, 0, 50), 0.5, 30, 0.25)  # the box has no depth
    assert out is frame and not bar.any()
    with pytest.raises(ValueError, match="box"):
        bar_in_front(frame, (0, 300, 0, 50), 0.5, 30, 0.25)
    with pytest.raises(ValueError, match="progress"):
        bar_in_front(frame, BOX, 1.5, 30, 0.25)
    with pytest.raises(ValueError, match="gap_m"):
        bar_in_front(frame, BOX, 0.5, 30, 0.0)


def test_depth_holes_take_about_the_fraction_asked_inside_the_box_only():
    frame = _frame()
    out = depth_holes(frame, BOX, 0.3, np.random.default_rng(0))
    y0, y1, x0, x1 = BOX
    missing = out.depth_m[y0:y1, x0:x1] == 0
    assert 0.3 <= missing.mean() < 0.45
    outside = np.ones(frame.depth_m.shape, bool)
    outside[y0:y1, x0:x1] = False
    np.testing.assert_array_equal(out.depth_m[outside], frame.depth_m[outside])
    np.testing.assert_array_equal(out.rgb, frame.rgb)
    again = depth_holes(frame, BOX, 0.3, np.random.default_rng(0))
    np.testing.assert_array_equal(again.depth_m, out.depth_m)  # the seed decides the places
    assert depth_holes(frame, BOX, 0.0, np.random.default_rng(0)).depth_m[y0:y1, x0:x1].min() > 0


def test_no_depth_and_a_cut_keep_the_frames_time_and_camera():
    frame, other = _frame(3, 1.0), _frame(9, 2.0)
    empty = no_depth(frame)
    assert not empty.depth_m.any() and empty.seq == 3
    np.testing.assert_array_equal(empty.rgb, frame.rgb)
    cut = cut_to(dataclasses.replace(frame, occluder_mask=np.ones(frame.depth_m.shape, bool)), other)
    np.testing.assert_array_equal(cut.rgb, other.rgb)
    np.testing.assert_array_equal(cut.depth_m, other.depth_m)
    assert (cut.seq, cut.timestamp_s, cut.camera) == (3, frame.timestamp_s, CAM) and cut.occluder_mask is None
    small_cam = CameraInfo.from_fov(160, 120, np.deg2rad(45))
    small = RGBDFrame(np.zeros((120, 160, 3), np.uint8), np.full((120, 160), 2.0, np.float32), small_cam)
    resized = cut_to(frame, small)
    assert resized.depth_m.shape == (240, 320) and resized.camera == CAM and np.all(resized.depth_m == 2.0)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    write_sheet_recording(root / "sheet", CAM, 16, 0.004)
    wall_uv, wall_faces = grid_surface(3.0, 2.4, 4, 4)
    with SequenceWriter(root / "wall", CAM, depth_scale=1000.0) as w:
        for k in range(2):
            pts = plane_points(wall_uv, np.array([0.0, 0, 2.2]), (3.0, 2.4))
            w.write(frame_of(pts, wall_uv, wall_faces, texture(np.random.default_rng(9)), CAM, (3.0, 2.4),
                             t=k / 30, seq=k, background_m=None))
    return root


def test_the_benchmark_scores_each_fault_against_the_clean_run(data, tmp_path, capsys):
    out = tmp_path / "summary.json"
    assert bench.main(["--data", str(data), "--recording", "sheet", "--preset", "realtime",
                       "--scenario", "bar, known", "cut", "dropped", "--json", str(out), "--pictures", str(tmp_path),
                       "-q"]) == 0
    report = json.loads(out.read_text())
    assert report["cut_from"] == "wall" and report["window"] == [4, 10]
    runs = report["results"]["realtime"]
    cut = runs["cut"]
    # the six frames of the wall cannot be the sheet: each is wrong, and flagged lost at once
    assert cut["wrong"] == 6 and cut["wrong_not_lost_after_3"] == 0 and cut["wrong_confident"] == 0
    assert cut["deviation_after_mm"] is not None and cut["deviation_after_mm"] < 10.0  # back with the sheet
    known = runs["bar, known"]
    assert known["frames"] == 16 and known["wrong"] == 0 and known["deviation_max_mm"] < 10.0
    assert known["coverage_during_min"] > 0.8  # of the sheet in sight beside the bar
    assert runs["dropped"]["frames"] == 8
    assert (tmp_path / "real_faults_sheet_realtime.png").is_file()
    assert "| realtime | cut |" in capsys.readouterr().out


def test_a_recording_without_a_first_mask_or_missing_exits_2(data, tmp_path, capsys):
    assert bench.main(["--data", str(data), "--recording", "wall", "-q"]) == 2
    assert bench.main(["--data", str(data), "--recording", "none", "-q"]) == 2
    printed = capsys.readouterr().out
    assert "no reference mask" in printed and "no recording 'none'" in printed
