"""Converting public recordings (perception.recordings, launch_scripts.convert_recording) on tiny
samples written here in each source format: exact frames, units, intrinsics and ground truth."""

import json
import re
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from launch_scripts.convert_recording import main
from perception.recordings import (
    FLOW_FILE,
    KINECT_V1_K,
    MASKS_INDEX,
    RecordingError,
    carry_mask,
    read_groundtruth_flow,
    read_recording,
    read_reference_masks,
)
from perception.sequence import open_sequence

H, W = 480, 640


def _colour(k: int) -> np.ndarray:
    rng = np.random.default_rng(k)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)  # BGR as written to disk


def _depth_mm(k: int) -> np.ndarray:
    depth = np.zeros((H, W), np.uint16)
    depth[150:260, 120 + 5 * k:480 + 5 * k] = 530 + 3 * k  # a bar at about half a metre
    depth[250:280, 100:160] = 601  # a hand behind it
    return depth


def write_deformable_tracking(root, n=3, skip_depth=None):
    (root / "Frames").mkdir(parents=True)
    (root / "depthMatrices").mkdir()
    for k in range(n):
        cv2.imwrite(str(root / "Frames" / f"{k:04d}.png"), _colour(k))
        if k != skip_depth:
            fs = cv2.FileStorage(str(root / "depthMatrices" / f"{k:04d}.yml"), cv2.FILE_STORAGE_WRITE)
            fs.write("depth", _depth_mm(k))
            fs.release()
    return root


def _write_flow(path, flow: np.ndarray) -> None:
    """DeepDeform binary flow: uint32 width, height, channels, then float32 (C, H, W)."""
    h, w, c = flow.shape
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(np.array([w, h, c], "<u4").tobytes() + flow.transpose(2, 0, 1).astype("<f4").tobytes())


SHIFT_PX = (30, 10)
SHIFT_M = np.array([0.02, 0.005, -0.01], np.float32)


def write_deepdeform(seq, numbers=(0, 5)):
    for sub in ("color", "depth", "mask"):
        (seq / sub).mkdir(parents=True, exist_ok=True)
    for k, n in enumerate(numbers):
        cv2.imwrite(str(seq / "color" / f"{n:06d}.png"), _colour(k))
        cv2.imwrite(str(seq / "depth" / f"{n:06d}.png"), (_depth_mm(k).astype(np.uint32) * 3).astype(np.uint16))
    (seq / "intrinsics.txt").write_text("575.5 0 323.2 0\n0 577.5 236.4 0\n0 0 1 0\n0 0 0 1\n")
    mask = np.zeros((H, W), np.uint16)
    mask[150:260, 200:400] = 65535
    cv2.imwrite(str(seq / "mask" / f"{numbers[0]:06d}_shirt.png"), mask)
    scene = np.full((H, W, 3), -np.inf, np.float32)
    scene[mask > 0] = SHIFT_M
    optical = np.full((H, W, 2), -np.inf, np.float32)
    optical[mask > 0] = SHIFT_PX
    name = f"shirt_{numbers[0]:06d}_{numbers[1]:06d}"
    _write_flow(seq / "scene_flow" / f"{name}.sflow", scene)
    _write_flow(seq / "optical_flow" / f"{name}.oflow", optical)
    return mask > 0


def test_deformable_tracking_frames_units_and_intrinsics(tmp_path):
    src = write_deformable_tracking(tmp_path / "src")
    out = tmp_path / "foam"
    assert main(["deformable_tracking", str(src), str(out), "-q"]) == 0
    seq = open_sequence(out)
    assert len(seq) == 3 and seq.depth_scale == 1000.0
    np.testing.assert_array_equal(seq.camera.K, KINECT_V1_K)
    np.testing.assert_allclose(seq.timestamps, np.arange(3) / 30.0, atol=1e-6)
    for k in range(3):
        frame = seq.frame(k)
        np.testing.assert_array_equal(frame.rgb, cv2.cvtColor(_colour(k), cv2.COLOR_BGR2RGB))
        np.testing.assert_array_equal(np.rint(frame.depth_m * 1000).astype(np.uint16), _depth_mm(k))
    assert 0.529 < seq.frame(0).depth_m[200, 300] < 0.531  # millimetres read as metres
    info = json.loads((out / "recording.json").read_text())
    assert info["format"] == "deformable_tracking" and info["frame_numbers"] == [0, 1, 2]
    assert not (out / FLOW_FILE).exists() and read_reference_masks(seq) == {}


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_reads_a_git_directory_at_head(tmp_path):
    work = write_deformable_tracking(tmp_path / "repo", n=2)
    git = ["git", "-C", str(work), "-c", "user.name=t", "-c", "user.email=t@example.org"]
    subprocess.run(git[:3] + ["init", "-q"], check=True)
    subprocess.run(git + ["add", "."], check=True)
    subprocess.run(git + ["commit", "-qm", "frames"], check=True)
    bare = tmp_path / "repo.git"
    shutil.move(str(work / ".git"), str(bare))  # only the git directory is left, as fetch leaves it
    shutil.rmtree(work)
    out = tmp_path / "seq"
    assert main(["deformable_tracking", str(bare), str(out), "-q"]) == 0
    seq = open_sequence(out)
    assert len(seq) == 2
    np.testing.assert_array_equal(np.rint(seq.frame(1).depth_m * 1000).astype(np.uint16), _depth_mm(1))
    assert len(json.loads((out / "recording.json").read_text())["commit"]) == 40


def test_deepdeform_flow_masks_and_intrinsics(tmp_path):
    mask = write_deepdeform(tmp_path / "data" / "train" / "seq001")
    out = tmp_path / "shirt"
    assert main(["deepdeform", str(tmp_path / "data"), str(out), "-q"]) == 0  # the one sequence is found
    seq = open_sequence(out)
    np.testing.assert_allclose(seq.camera.K, [[575.5, 0, 323.2], [0, 577.5, 236.4], [0, 0, 1]])
    np.testing.assert_allclose(seq.timestamps, [0.0, 5 / 30.0], atol=1e-6)
    np.testing.assert_allclose(seq.frame(1).depth_m[200, 300], 3 * 533 / 1000.0, atol=1e-6)
    (pair,) = read_groundtruth_flow(seq)
    assert (pair.source, pair.target) == (0, 1)
    np.testing.assert_array_equal(pair.scene_flow_m[mask], np.broadcast_to(SHIFT_M, (mask.sum(), 3)))
    assert np.isnan(pair.scene_flow_m[~mask]).all() and np.isnan(pair.optical_flow_px[~mask]).all()
    masks = read_reference_masks(seq)
    np.testing.assert_array_equal(masks[0], mask)
    shifted = np.roll(np.roll(mask, SHIFT_PX[1], axis=0), SHIFT_PX[0], axis=1)
    np.testing.assert_array_equal(masks[1], shifted)  # carried by the optical flow
    kinds = json.loads((out / MASKS_INDEX).read_text())
    assert kinds["0.000000.png"] == "annotated" and kinds["0.166667.png"].startswith("derived")


def test_carry_mask_closes_the_gaps_of_a_stretch():
    mask = np.zeros((60, 80), bool)
    mask[10:30, 10:30] = True
    rows, cols = np.mgrid[0:60, 0:80]
    flow = np.stack([0.5 * (cols - 10), np.zeros_like(cols)], axis=2).astype(np.float32)  # stretch x by 1.5
    carried = carry_mask(mask, flow)
    assert carried[10:30, 10:39].all()  # no holes where the pixels spread apart
    assert not carried[:, 41:].any() and not carried[35:].any()


def test_several_deepdeform_sequences_need_a_choice(tmp_path, capsys):
    write_deepdeform(tmp_path / "d" / "train" / "seq001")
    write_deepdeform(tmp_path / "d" / "test" / "seq002")
    assert main(["deepdeform", str(tmp_path / "d"), str(tmp_path / "o"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds 2 DeepDeform sequences" in err and "--sequence" in err and "\n" not in err
    assert main(["deepdeform", str(tmp_path / "d"), str(tmp_path / "o"), "-q", "--sequence", "test/seq002"]) == 0
    assert json.loads((tmp_path / "o" / "recording.json").read_text())["sequence"] == "test/seq002"


@pytest.mark.parametrize("spoil, message", [
    ("missing_depth", "frame 1 has no depth image"),
    ("float_depth", "expected a single-channel uint16 depth matrix"),
    ("no_source", "no such file or directory"),
    ("wrong_size", "expected 640x480"),
])
def test_bad_deformable_tracking_input_is_one_line_exit_2(tmp_path, capsys, spoil, message):
    src = tmp_path / "src"
    if spoil == "missing_depth":
        write_deformable_tracking(src, skip_depth=1)
    elif spoil == "float_depth":
        write_deformable_tracking(src)
        fs = cv2.FileStorage(str(src / "depthMatrices" / "0002.yml"), cv2.FILE_STORAGE_WRITE)
        fs.write("depth", np.zeros((H, W), np.float32))
        fs.release()
    elif spoil == "wrong_size":
        write_deformable_tracking(src)
        cv2.imwrite(str(src / "Frames" / "0000.png"), np.zeros((240, 320, 3), np.uint8))
    assert main(["deformable_tracking", str(src), str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_truncated_flow_is_named(tmp_path):
    write_deepdeform(tmp_path / "seq")
    sflow = next((tmp_path / "seq" / "scene_flow").iterdir())
    sflow.write_bytes(sflow.read_bytes()[:-4])
    with pytest.raises(RecordingError, match=r"shirt_000000_000005\.sflow: expected \d+ bytes"):
        read_recording("deepdeform", tmp_path / "seq")


def test_refuses_to_overwrite_and_unknown_formats(tmp_path, capsys):
    src = write_deformable_tracking(tmp_path / "src", n=1)
    assert main(["deformable_tracking", str(src), str(tmp_path / "out"), "-q"]) == 0
    assert main(["deformable_tracking", str(src), str(tmp_path / "out"), "-q"]) == 2
    assert "already holds a sequence" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main(["vicon", str(src), str(tmp_path / "o2")])
    assert stop.value.code == 2
    assert main(["deformable_tracking", str(src), str(tmp_path / "o3"), "--sequence", "x", "-q"]) == 2


def write_rgbd_tracking(folder, n=2, kind=5, truncate=False):
    """agpetit/RGBDTracking's image folder: img1NNNNNN.png, depthfileNNNNNN.txt (int32 type,
    width, height, float32 metres, NaN unknown) and the authors' segmentation imgseg1NNNNNN.png."""
    folder.mkdir(parents=True)
    for k in range(n):
        cv2.imwrite(str(folder / f"img1{k:06d}.png"), _colour(k)[:240, :320])
        metres = _depth_mm(k)[:240, :320].astype(np.float32) / 1000.0
        metres[metres == 0] = np.nan
        data = np.array([kind, 320, 240], "<i4").tobytes() + metres.astype("<f4").tobytes()
        (folder / f"depthfile{k:06d}.txt").write_bytes(data[:-8] if truncate else data)
        seg = np.zeros((240, 320, 4), np.uint8)
        seg[150:200, 130 + 10 * k:200] = 3  # the authors' masks are 4-channel, small non-zero values
        cv2.imwrite(str(folder / f"imgseg1{k:06d}.png"), seg)


def test_rgbd_tracking_float_depth_intrinsics_and_first_mask(tmp_path):
    write_rgbd_tracking(tmp_path / "repo" / "examples" / "images" / "imagesInteraction")
    out = tmp_path / "seq"
    assert main(["rgbd_tracking", str(tmp_path / "repo"), str(out), "-q"]) == 0
    seq = open_sequence(out)
    assert len(seq) == 2 and seq.depth_scale == 1000.0
    np.testing.assert_array_equal(seq.camera.K, [[275.0, 0.0, 160.0], [0.0, 275.0, 120.0], [0.0, 0.0, 1.0]])
    for k in range(2):
        frame = seq.frame(k)
        np.testing.assert_array_equal(frame.rgb, cv2.cvtColor(_colour(k)[:240, :320], cv2.COLOR_BGR2RGB))
        np.testing.assert_array_equal(np.rint(frame.depth_m * 1000).astype(np.uint16), _depth_mm(k)[:240, :320])
    masks = read_reference_masks(seq)
    assert list(masks) == [0] and masks[0].sum() == 50 * 70  # frame 0's only: later ones hold the hand too


@pytest.mark.parametrize("spoil,message", [
    ("kind", "expected OpenCV type 5 (float32), got 6"),
    ("truncated", "expected 320x240 float32 values, got 76798"),
])
def test_bad_rgbd_tracking_depth_is_named(tmp_path, spoil, message):
    write_rgbd_tracking(tmp_path / "src", kind=6 if spoil == "kind" else 5, truncate=spoil == "truncated")
    recording = read_recording("rgbd_tracking", tmp_path / "src")
    with pytest.raises(RecordingError, match=r"depthfile000000\.txt: " + re.escape(message)):
        recording.frames[0].load()
