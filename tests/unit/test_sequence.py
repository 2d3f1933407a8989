"""perception.sequence: the recorded-sequence folder, read and written."""

import json

import cv2
import numpy as np
import pytest

from ipc.messages import CameraInfo, RGBDFrame
from perception.sequence import (
    Sequence,
    SequenceError,
    SequenceWriter,
    associate,
    open_sequence,
    read_intrinsics,
    write_intrinsics,
)

W, H = 32, 24
K = np.array([[30.0, 0.0, 15.5], [0.0, 31.0, 11.5], [0.0, 0.0, 1.0]])
CAMERA = CameraInfo(W, H, K)


def _frame(i, t):
    rng = np.random.default_rng(i)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 4.0, (H, W)).astype(np.float32)
    depth[0, :4] = 0.0  # missing
    depth[1, 0] = np.nan  # missing too
    return RGBDFrame(rgb=rgb, depth_m=depth, camera=CAMERA, timestamp_s=t, seq=i)


def _write(path, n=3, groundtruth=True, depth_scale=5000.0):
    frames = [_frame(i, 100.0 + i / 30) for i in range(n)]
    gt = None
    if groundtruth:
        gt = {"vertices": np.random.default_rng(0).normal(size=(n, 4, 3)), "faces": np.array([[0, 1, 2], [1, 3, 2]]),
              "uv": np.zeros((4, 2))}
    with SequenceWriter(path, CAMERA, depth_scale=depth_scale) as writer:
        for f in frames:
            writer.write(f)
        writer.close(groundtruth=gt)
    return frames


def test_round_trip(tmp_path):
    frames = _write(tmp_path / "seq")
    seq = open_sequence(tmp_path / "seq")
    assert isinstance(seq, Sequence) and len(seq) == 3
    np.testing.assert_allclose(seq.camera.K, K)
    assert seq.depth_scale == 5000.0
    np.testing.assert_allclose(seq.timestamps, [f.timestamp_s for f in frames], atol=1e-6)
    for original, read in zip(frames, seq):
        assert np.array_equal(read.rgb, original.rgb), "colour comes back in RGB order"
        expected = np.nan_to_num(original.depth_m)
        assert np.abs(read.depth_m - expected).max() <= 0.5 / 5000 + 1e-7
        assert (read.depth_m == 0).sum() == 5
    assert seq.frame(1).seq == 1
    gt = seq.groundtruth
    assert gt["vertices"].dtype == np.float32 and gt["vertices"].shape == (3, 4, 3)
    assert gt["faces"].tolist() == [[0, 1, 2], [1, 3, 2]]
    with pytest.raises(IndexError, match="out of range for a sequence of 3 frames"):
        seq.frame(3)


def test_files_follow_the_folder_contract(tmp_path):
    _write(tmp_path / "seq", n=2, depth_scale=1000.0)
    root = tmp_path / "seq"
    lines = [ln for ln in (root / "rgb.txt").read_text().splitlines() if not ln.startswith("#")]
    assert lines == ["100.000000 rgb/100.000000.png", "100.033333 rgb/100.033333.png"]
    data = json.loads((root / "camera_intrinsic.json").read_text())
    assert data["width"] == W and data["height"] == H and data["depth_scale"] == 1000.0
    assert data["intrinsic_matrix"] == [30.0, 0.0, 0.0, 0.0, 31.0, 0.0, 15.5, 11.5, 1.0]  # column-major
    depth = cv2.imread(str(root / "depth" / "100.000000.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and depth.shape == (H, W)
    assert open_sequence(root).groundtruth is not None
    assert (root / "groundtruth_mesh.npz").exists()


def test_without_groundtruth(tmp_path):
    _write(tmp_path / "seq", groundtruth=False)
    assert open_sequence(tmp_path / "seq").groundtruth is None


def test_intrinsics_are_column_major_and_say_when_they_give_no_scale(tmp_path):
    path = tmp_path / "camera_intrinsic.json"
    path.write_text(json.dumps({"width": 640, "height": 480,
                                "intrinsic_matrix": [525.0, 0, 0, 0, 526.0, 0, 319.5, 239.5, 1]}))
    camera, scale = read_intrinsics(path)
    np.testing.assert_allclose(camera.K, [[525, 0, 319.5], [0, 526, 239.5], [0, 0, 1]])
    assert scale is None
    write_intrinsics(path, camera, 1000.0)
    again, scale = read_intrinsics(path)
    np.testing.assert_allclose(again.K, camera.K)
    assert scale == 1000.0


def test_association_follows_tum_rule():
    rgb = np.array([0.00, 0.033, 0.066, 0.100, 0.500])
    depth = np.array([0.010, 0.030, 0.040, 0.090, 0.200])
    pairs = associate(rgb, depth)
    # 0.033 takes 0.030 (closest), 0.000 takes 0.010, 0.066 has nothing left within 0.02 s
    # (0.040 is 0.026 away), 0.100 takes 0.090; 0.500 has no partner
    assert pairs.tolist() == [[0, 0], [1, 1], [3, 3]]
    assert associate(np.array([0.0]), np.array([0.02])).size == 0, "0.02 s apart is not 'within'"
    assert associate(rgb[::-1], depth).tolist() == [[4, 0], [3, 1], [1, 3]]


def test_frames_pair_by_nearest_timestamp(tmp_path):
    _write(tmp_path / "seq", n=3)
    root = tmp_path / "seq"
    # shift the depth timestamps by 5 ms and drop the colour list's middle image
    lines = (root / "depth.txt").read_text().splitlines()
    shifted = [ln if ln.startswith("#") else f"{float(ln.split()[0]) + 0.005:.6f} {ln.split()[1]}" for ln in lines]
    (root / "depth.txt").write_text("\n".join(shifted) + "\n")
    rgb_lines = [ln for ln in (root / "rgb.txt").read_text().splitlines() if not ln.startswith("#")]
    (root / "rgb.txt").write_text("\n".join([rgb_lines[0], rgb_lines[2]]) + "\n")
    (root / "groundtruth_mesh.npz").unlink()
    seq = open_sequence(root)
    assert len(seq) == 2
    assert seq.depth_files[1].name == "100.066667.png"
    assert seq.frame(1).timestamp_s == pytest.approx(100.0 + 2 / 30)


def _broken(tmp_path, edit):
    _write(tmp_path / "seq")
    root = tmp_path / "seq"
    edit(root)
    with pytest.raises(SequenceError) as exc:
        open_sequence(root)
    message = str(exc.value)
    assert "\n" not in message
    return message


def _set_json(root, **changes):
    path = root / "camera_intrinsic.json"
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("edit, expected", [
    (lambda r: (r / "rgb.txt").unlink(), r"rgb\.txt: file not found"),
    (lambda r: (r / "depth.txt").unlink(), r"depth\.txt: file not found"),
    (lambda r: (r / "camera_intrinsic.json").unlink(), r"camera_intrinsic\.json: file not found"),
    (lambda r: (r / "camera_intrinsic.json").write_text("{width: 3"), r"camera_intrinsic\.json: not valid JSON"),
    (lambda r: _set_json(r, intrinsic_matrix=[30, 0, 15.5, 0, 31, 11.5, 0, 0, 1]), r"looks row-major"),
    (lambda r: _set_json(r, intrinsic_matrix=[30, 0, 0, 31]), r"intrinsic_matrix must be a list of 9 numbers, got 4"),
    (lambda r: _set_json(r, width=0), r"width and height must be positive integers"),
    (lambda r: _set_json(r, depth_scale=-1), r"depth_scale must be positive"),
    (lambda r: _set_json(r, width=64), r"100\.000000\.png: image is 32x24, but camera_intrinsic\.json says 64x24"),
    (lambda r: (r / "rgb" / "100.000000.png").write_bytes(b"not a png"), r"rgb/100\.000000\.png: unreadable image"),
    (lambda r: (r / "rgb" / "100.033333.png").unlink(), r"rgb\.txt: listed image rgb/100\.033333\.png does not exist"),
    (lambda r: cv2.imwrite(str(r / "depth" / "100.000000.png"), np.zeros((H, W), np.uint8)),
     r"expected a 16-bit single-channel depth image, got uint8"),
    (lambda r: (r / "rgb.txt").write_text("# nothing\n"), r"rgb\.txt: lists no images"),
    (lambda r: (r / "rgb.txt").write_text("100.0 a.png extra\n"), r"rgb\.txt:1: expected 'timestamp path'"),
    (lambda r: (r / "rgb.txt").write_text("soon rgb/100.000000.png\n"), r"rgb\.txt:1: timestamp 'soon' is not a number"),
    (lambda r: (r / "rgb.txt").write_text("5.0 rgb/100.000000.png\n"), r"no rgb/depth pairs within 0\.02 s"),
    (lambda r: np.savez(r / "groundtruth_mesh.npz", vertices=np.zeros((2, 4, 3)), faces=np.zeros((1, 3), int),
                        uv=np.zeros((4, 2))), r"groundtruth_mesh\.npz: vertices has 2 frames, the sequence has 3"),
    (lambda r: np.savez(r / "groundtruth_mesh.npz", vertices=np.zeros((3, 4, 3))), r"missing key 'faces'"),
])
def test_every_bad_input_has_its_message(tmp_path, edit, expected):
    import re
    assert re.search(expected, _broken(tmp_path, edit))


def test_missing_folder(tmp_path):
    with pytest.raises(SequenceError, match="no such directory"):
        open_sequence(tmp_path / "nothing")
    (tmp_path / "file").write_text("")
    with pytest.raises(SequenceError, match="not a directory"):
        open_sequence(tmp_path / "file")


def test_unreadable_later_frame_fails_when_read(tmp_path):
    _write(tmp_path / "seq")
    (tmp_path / "seq" / "depth" / "100.066667.png").write_bytes(b"broken")
    seq = open_sequence(tmp_path / "seq")
    with pytest.raises(SequenceError, match=r"depth/100\.066667\.png: unreadable image"):
        seq.frame(2)


def test_writer_checks_its_input(tmp_path):
    writer = SequenceWriter(tmp_path / "seq", CAMERA)
    writer.write(_frame(0, 1.0))
    with pytest.raises(ValueError, match="timestamps must increase, got 1.000000 after 1.000000"):
        writer.write(_frame(1, 1.0))
    other = CameraInfo(W, H, K * np.array([[2, 1, 1], [1, 1, 1], [1, 1, 1]]))
    frame = RGBDFrame(rgb=np.zeros((H, W, 3), np.uint8), depth_m=np.zeros((H, W), np.float32), camera=other,
                      timestamp_s=2.0)
    with pytest.raises(ValueError, match="camera differs"):
        writer.write(frame)
    with pytest.raises(ValueError, match=r"groundtruth vertices must be \(1, V, 3\)"):
        writer.close(groundtruth={"vertices": np.zeros((2, 4, 3)), "faces": np.zeros((1, 3), int), "uv": np.zeros((4, 2))})
    writer.close()
    with pytest.raises(ValueError, match="already holds a sequence"):
        SequenceWriter(tmp_path / "seq", CAMERA)
    distorted = CameraInfo(W, H, K, D=np.array([0.1, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="cannot hold distortion"):
        SequenceWriter(tmp_path / "other", distorted)


def test_far_depth_becomes_missing(tmp_path):
    frame = _frame(0, 0.0)
    depth = frame.depth_m.copy()
    depth[5, 5] = 20.0  # beyond 65535 / 5000 = 13.1 m
    with SequenceWriter(tmp_path / "seq", CAMERA) as writer:
        writer.write(RGBDFrame(rgb=frame.rgb, depth_m=depth, camera=CAMERA, timestamp_s=0.0))
    assert open_sequence(tmp_path / "seq").frame(0).depth_m[5, 5] == 0


def test_an_aborted_recording_is_not_a_sequence(tmp_path):
    with pytest.raises(RuntimeError), SequenceWriter(tmp_path / "seq", CAMERA) as writer:
        writer.write(_frame(0, 0.0))
        raise RuntimeError("simulation failed")
    with pytest.raises(SequenceError, match="rgb.txt: file not found"):
        open_sequence(tmp_path / "seq")


def test_a_sequence_without_depth_scale_is_read_at_tums_scale_with_a_warning(tmp_path, caplog):
    _write(tmp_path / "seq", depth_scale=1000.0)  # millimetres
    data = json.loads((tmp_path / "seq" / "camera_intrinsic.json").read_text())
    del data["depth_scale"]
    (tmp_path / "seq" / "camera_intrinsic.json").write_text(json.dumps(data))
    with caplog.at_level("WARNING", logger="perception.sequence"):
        seq = open_sequence(tmp_path / "seq")
    assert seq.depth_scale == 5000.0
    raw = cv2.imread(str(seq.depth_files[0]), cv2.IMREAD_UNCHANGED)
    median_mm = float(np.median(raw[raw > 0]))
    warning = " ".join(r.getMessage() for r in caplog.records)
    assert "has no depth_scale: taking TUM's 5000 units per metre" in warning
    assert f"{median_mm / 5000:.2f} m; {median_mm / 1000:.2f} m in millimetres" in warning


def test_lists_and_intrinsics_written_with_a_byte_order_mark_are_read(tmp_path):
    _write(tmp_path / "seq")
    for name in ("rgb.txt", "depth.txt", "camera_intrinsic.json"):
        path = tmp_path / "seq" / name
        path.write_text(path.read_text(), encoding="utf-8-sig")  # as Windows editors save
    assert len(open_sequence(tmp_path / "seq")) == 3


def test_timestamps_too_far_apart_to_be_seconds_are_said(tmp_path, caplog):
    _write(tmp_path / "seq")
    for name in ("rgb.txt", "depth.txt"):  # 100.0, 100.033 ... read as milliseconds since some epoch
        path = tmp_path / "seq" / name
        lines = [ln if ln.startswith("#") else f"{1000 * float(ln.split()[0]):.3f} {ln.split()[1]}"
                 for ln in path.read_text().splitlines()]
        path.write_text("\n".join(lines) + "\n")
    with caplog.at_level("WARNING", logger="perception.sequence"):
        assert len(open_sequence(tmp_path / "seq")) == 3
    assert "frames 33.3 s apart (median): paced by their timestamps, they play that far apart (TUM timestamps are " \
        "seconds; milliseconds would want dividing by 1000)" in caplog.text
    caplog.clear()
    _write(tmp_path / "ok")
    with caplog.at_level("WARNING", logger="perception.sequence"):
        open_sequence(tmp_path / "ok")
    assert not caplog.records
