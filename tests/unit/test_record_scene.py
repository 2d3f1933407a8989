"""python -m launch_scripts.record_scene: writes a sequence that perception.sequence reads back, with ground truth."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from launch_scripts.record_scene import main
from perception.sequence import open_sequence
from sim.scenes import make_scene

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_record_writes_a_readable_sequence_with_ground_truth(tmp_path, capsys):
    pytest.importorskip("pybullet")
    out = tmp_path / "seq"
    assert main(["poster_bend", str(out), "--frames", "3", "--seed", "1", "--width", "64", "--height", "48",
                 "--no-noise", "--quiet"]) == 0
    seq = open_sequence(out)
    assert len(seq) == 3 and seq.camera.width == 64 and seq.depth_scale == 5000
    np.testing.assert_allclose(seq.timestamps, [0.0, 1 / 30, 2 / 30], atol=1e-6)
    gt = seq.groundtruth
    assert gt["vertices"].shape[0] == 3 and gt["vertices"].dtype == np.float32
    assert gt["faces"].shape[1] == 3 and gt["uv"].shape == (gt["vertices"].shape[1], 2)
    # the ground truth is in the camera frame: its vertices project onto measured cloth depth
    frame = seq.frame(2)
    v = gt["vertices"][2].astype(np.float64)
    uvw = v @ seq.camera.K.T
    col = np.rint(uvw[:, 0] / uvw[:, 2]).astype(int)
    row = np.rint(uvw[:, 1] / uvw[:, 2]).astype(int)
    ok = (col >= 0) & (col < 64) & (row >= 0) & (row < 48)
    assert ok.all()
    diff = np.abs(frame.depth_m[row, col] - v[:, 2])
    assert np.median(diff) < 0.01


@pytest.mark.slow
def test_record_writes_occluder_masks_named_as_the_depth_images_and_drops_frames(tmp_path):
    pytest.importorskip("pybullet")
    size = ["--width", "64", "--height", "48", "--seed", "2", "--quiet"]
    assert main(["gripper_corner_move", str(tmp_path / "all"), "--frames", "5", *size]) == 0
    assert main(["gripper_corner_move", str(tmp_path / "half"), "--frames", "5", "--frame-step", "2", *size]) == 0
    with make_scene("gripper_corner_move", seed=2, width=64, height=48) as scene:
        expected = []
        for _ in scene.frames(5):
            expected.append(scene.occluder_mask())
    assert any(m.any() for m in expected), "the gripper is in view"
    for name, step in (("all", 1), ("half", 2)):
        seq = open_sequence(tmp_path / name)
        np.testing.assert_allclose(seq.timestamps, np.arange(0, 5, step) / 30, atol=1e-6)
        assert seq.groundtruth["vertices"].shape[0] == len(seq)
        folder = tmp_path / name / "occluder_masks"
        assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in seq.depth_files)
        for k, depth_file in enumerate(seq.depth_files):
            png = cv2.imread(str(folder / depth_file.name), cv2.IMREAD_UNCHANGED)
            assert png.dtype == np.uint8 and set(np.unique(png)) <= {0, 255}
            np.testing.assert_array_equal(png > 0, expected[k * step])
    assert not (tmp_path / "none").exists()
    assert main(["poster_bend", str(tmp_path / "none"), "--frames", "1", *size]) == 0
    assert not (tmp_path / "none" / "occluder_masks").exists(), "a scene without occluders gets no masks"


@pytest.mark.parametrize("args, message", [
    (["sofa", "OUT"], "unknown scene 'sofa'; expected one of gripper_corner_move, occluder_close, "
                     "occluder_near_camera, occluder_plain, occluder_sweep, poster_bend"),
    (["poster_bend", "OUT", "--frames", "0"], "argument --frames: expected a positive integer, got 0"),
    (["poster_bend", "OUT", "--seed", "x"], "argument --seed: expected a non-negative integer, got 'x'"),
    (["poster_bend", "OUT", "--width", "8"], "image size must be at least 16x16, got 8x480"),
    (["poster_bend"], "the following arguments are required: out_dir"),
])
def test_bad_arguments_give_one_line(tmp_path, capsys, args, message):
    args = [str(tmp_path / "out") if a == "OUT" else a for a in args]
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0]
    assert not (tmp_path / "out").exists()


def test_bad_argument_from_the_shell_has_no_traceback(tmp_path):
    result = subprocess.run([sys.executable, "-m", "launch_scripts.record_scene", "sofa", str(tmp_path / "out")],
                            cwd=REPO, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 2
    assert result.stderr.strip() == ("python -m launch_scripts.record_scene: error: unknown scene 'sofa'; "
                                     "expected one of gripper_corner_move, occluder_close, occluder_near_camera, "
                                     "occluder_plain, occluder_sweep, poster_bend, shirt_chair, shirt_textureless_rotate, "
                                     "table_lift, towel_sway")


def test_refuses_a_non_empty_output_folder(tmp_path):
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(SystemExit) as exc:
        main(["poster_bend", str(tmp_path)])
    assert exc.value.code == 2


def _no_simulation(*args, **kwargs):
    raise AssertionError("simulated before checking the output folder")


@pytest.mark.parametrize("where, reason", [("under_a_file", "Not a directory"), ("/proc/nope", None)])
def test_an_output_folder_that_cannot_be_made_is_one_line_before_simulating(tmp_path, capsys, monkeypatch, where,
                                                                              reason):
    if where == "/proc/nope" and not Path("/proc/self").exists():
        pytest.skip("no /proc")
    (tmp_path / "file").write_text("x")
    out = tmp_path / "file" / "seq" if where == "under_a_file" else Path(where)
    monkeypatch.setattr("launch_scripts.record_scene.make_scene", _no_simulation)
    with pytest.raises(SystemExit) as exc:
        main(["poster_bend", str(out), "--quiet"])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"python -m launch_scripts.record_scene: error: {out}: cannot create "
                                                   "the output folder there (")
    assert reason is None or reason in lines[0]


def test_a_folder_that_fails_half_made_leaves_none_of_its_new_parents(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("launch_scripts.record_scene.make_scene", _no_simulation)
    with pytest.raises(SystemExit):
        main(["poster_bend", str(tmp_path / "new" / ("x" * 300)), "--quiet"])  # a name too long for the disk
    assert "File name too long" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def _interrupted_recording(scene, out_dir, *args, **kwargs):
    (Path(out_dir) / "rgb").mkdir(parents=True)
    (Path(out_dir) / "rgb" / "0.png").write_bytes(b"half")
    raise KeyboardInterrupt


class _Scene:
    n_frames = 3

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_ctrl_c_removes_the_folders_it_made_and_exits_130(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("launch_scripts.record_scene.make_scene", lambda *a, **k: _Scene())
    monkeypatch.setattr("launch_scripts.record_scene.record_sequence", _interrupted_recording)
    assert main(["poster_bend", str(tmp_path / "new" / "seq"), "--quiet"]) == 130
    assert capsys.readouterr().err == "interrupted\n"
    assert list(tmp_path.iterdir()) == [], "the parent it made is gone too"
    (tmp_path / "mine").mkdir()  # existed before the run, empty: kept, emptied again
    assert main(["poster_bend", str(tmp_path / "mine"), "--quiet"]) == 130
    assert (tmp_path / "mine").is_dir() and list((tmp_path / "mine").iterdir()) == []


def test_a_write_error_is_one_line_and_removes_the_folder(tmp_path, capsys, monkeypatch):
    def full_disk(scene, out_dir, *args, **kwargs):
        Path(out_dir, "rgb.txt").write_text("half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("launch_scripts.record_scene.make_scene", lambda *a, **k: _Scene())
    monkeypatch.setattr("launch_scripts.record_scene.record_sequence", full_disk)
    with pytest.raises(SystemExit) as exc:
        main(["poster_bend", str(tmp_path / "seq"), "--quiet"])
    assert exc.value.code == 2
    assert capsys.readouterr().err == (f"python -m launch_scripts.record_scene: error: {tmp_path / 'seq'}: cannot write "
                                       "the sequence ([Errno 28] No space left on device)\n")
    assert not (tmp_path / "seq").exists()
