"""The offline tracking command, python -m perception.track: EST.npz, its options, one-line errors."""

import subprocess
import sys

import cv2
import numpy as np
import pytest

from ipc.messages import CameraInfo
from launch_scripts.track import main
from perception.sequence import SequenceWriter
from tests.render import frame_of, grid_surface, plane_points, texture

CAM = CameraInfo.from_fov(320, 240, np.deg2rad(45))
SIZE = (0.6, 0.45)
UV, FACES = grid_surface(*SIZE, 21, 16)
SHIFT = np.array([0.01, 0.0, 0.01])


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq") / "SEQ"
    tex = texture(np.random.default_rng(3))
    with SequenceWriter(root, CAM) as w:
        for k in range(4):
            pts = plane_points(UV, np.array([0, 0, 1.3]) + k * SHIFT, SIZE)
            w.write(frame_of(pts, UV, FACES, tex, CAM, SIZE, t=1.0 + k / 30, seq=k))
    return root


def test_writes_every_key_of_the_contract(seq, tmp_path):
    out = tmp_path / "est.npz"
    assert main([str(seq), "--output", str(out), "--quiet", "--overlay-dir", str(tmp_path / "ov"),
                 "--ply-dir", str(tmp_path / "ply")]) == 0
    est = np.load(out)
    T, N = 4, est["canonical"].shape[0]
    assert est["vertices"].shape == (T, N, 3) and est["vertices"].dtype == np.float32
    assert est["faces"].shape[1] == 3 and est["faces"].max() < N
    assert est["boundary"].ndim == 1 and est["boundary"].max() < N
    assert est["canonical"].dtype == np.float32
    np.testing.assert_allclose(est["timestamps"], 1.0 + np.arange(4) / 30, atol=1e-6)
    assert est["timing_ms"].shape == (T,) and np.all(est["timing_ms"] > 0)
    assert est["confidence"].shape == (T,) and est["lost"].dtype == bool and not est["lost"].any()
    assert est["visible"].shape == (T, N) and est["visible"].dtype == bool and est["visible"].mean() > 0.95
    # the sheet moved by SHIFT each frame: the estimate follows
    moved = est["vertices"][3] - est["vertices"][0]
    np.testing.assert_allclose(moved.mean(axis=0), 3 * SHIFT, atol=0.003)
    assert len(list((tmp_path / "ov").glob("*.png"))) == T
    assert (tmp_path / "ply" / "000003.ply").read_text().startswith("ply")


def test_occluder_masks_hide_the_vertices_under_them(seq, tmp_path):
    masks = tmp_path / "occluders"
    masks.mkdir()
    band = np.zeros((CAM.height, CAM.width), np.uint8)
    band[:, 150:190] = 255
    depth_names = sorted(p.name for p in (seq / "depth").iterdir())
    for name in depth_names[1:]:  # none for the first frame: nothing known there
        cv2.imwrite(str(masks / name), band)
    out = tmp_path / "est.npz"
    assert main([str(seq), "--output", str(out), "--quiet", "--occluder-masks", str(masks)]) == 0
    est = np.load(out)
    uv = est["vertices"][2][:, :2] / est["vertices"][2][:, 2:] * CAM.fx + [CAM.cx, CAM.cy]
    under = (uv[:, 0] > 152) & (uv[:, 0] < 188)
    assert under.sum() > 5 and not est["visible"][2][under].any() and est["visible"][2][~under].mean() > 0.9
    assert est["visible"][0].all()
    cv2.imwrite(str(masks / depth_names[0]), np.zeros((5, 5), np.uint8))
    assert main([str(seq), "--output", str(out), "--quiet", "--occluder-masks", str(masks)]) == 2


def test_init_mask_is_used(seq, tmp_path):
    mask = np.zeros((240, 320), np.uint8)
    mask[100:140, 130:190] = 255  # only part of the sheet: a smaller mesh
    cv2.imwrite(str(tmp_path / "m.png"), mask)
    full, part = tmp_path / "full.npz", tmp_path / "part.npz"
    assert main([str(seq), "-o", str(full), "-q", "--max-frames", "1"]) == 0
    assert main([str(seq), "-o", str(part), "-q", "--max-frames", "1", "--init-mask", str(tmp_path / "m.png")]) == 0
    assert np.load(part)["vertices"].shape[1] < 0.5 * np.load(full)["vertices"].shape[1]


@pytest.mark.parametrize("case,message", [
    ("missing", "no such"),
    ("mask_missing", "init mask"),
    ("mask_empty", "empty"),
    ("mask_size", "differs from the frames"),
    ("mask_unreadable", "not a readable image"),
])
def test_bad_input_exits_2_with_one_line(seq, tmp_path, capsys, case, message):
    args = [str(seq), "-o", str(tmp_path / "e.npz"), "-q"]
    if case == "missing":
        args[0] = str(tmp_path / "nowhere")
    elif case == "mask_missing":
        args += ["--init-mask", str(tmp_path / "nope.png")]
    elif case == "mask_empty":
        cv2.imwrite(str(tmp_path / "z.png"), np.zeros((240, 320), np.uint8))
        args += ["--init-mask", str(tmp_path / "z.png")]
    elif case == "mask_size":
        cv2.imwrite(str(tmp_path / "s.png"), np.full((10, 10), 255, np.uint8))
        args += ["--init-mask", str(tmp_path / "s.png")]
    else:
        (tmp_path / "bad.png").write_bytes(b"not a png")
        args += ["--init-mask", str(tmp_path / "bad.png")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and message in err.lower() and "\n" not in err


@pytest.mark.parametrize("option, value, message", [
    ("--spacing-m", "5", "--spacing-m: expected a value in 0 or [0.005, 1], got 5"),  # hours of work, before
    ("--spacing-m", "0.0001", "--spacing-m: expected a value in 0 or [0.005, 1], got 0.0001"),
    ("--max-frames", "0", "--max-frames"),
    ("--output", "FILE/est.npz", "--output"),  # a folder that is a file: said before any frame is tracked
])
def test_an_option_out_of_range_is_refused_in_one_line(seq, tmp_path, capsys, option, value, message):
    (tmp_path / "FILE").write_text("a file")
    args = [str(seq), "-q", "-o", str(tmp_path / "e.npz"), option, value.replace("FILE", str(tmp_path / "FILE"))]
    if option == "--max-frames":  # refused by the parser
        with pytest.raises(SystemExit) as stop:
            main(args)
        assert stop.value.code == 2
    else:
        assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err


def test_the_output_is_written_under_the_name_given(seq, tmp_path):
    assert main([str(seq), "-o", str(tmp_path / "est"), "-q", "--max-frames", "2"]) == 0
    assert (tmp_path / "est").is_file() and not (tmp_path / "est.npz").exists()
    assert np.load(tmp_path / "est")["vertices"].shape[0] == 2


def test_a_new_mesh_laid_when_the_object_was_found_again_is_kept_beside_the_first():
    from types import SimpleNamespace

    from launch_scripts.track import estimate_arrays

    def estimate(canonical, faces, shift, seen=True):
        n = len(canonical)
        return SimpleNamespace(vertices=canonical + shift, faces=faces, boundary=np.arange(3), canonical=canonical,
                               visible=np.full(n, seen), timing_ms=5.0, confidence=0.9, lost=False)

    first, second = np.random.default_rng(0).random((6, 3)), np.random.default_rng(1).random((4, 3))
    f6, f4 = np.array([[0, 1, 2], [3, 4, 5]]), np.array([[0, 1, 2], [1, 2, 3]])
    estimates = [estimate(first, f6, 0.0), estimate(first, f6, 0.1), estimate(second, f4, 0.0), estimate(second, f4, 0.2)]
    est = estimate_arrays(estimates, [0.0, 1.0, 2.0, 3.0])
    assert est["mesh"].tolist() == [0, 0, 1, 1]
    # the contract's keys are the first mesh's: its material points while it was tracked, NaN after
    assert est["vertices"].shape == (4, 6, 3) and est["canonical"].shape == (6, 3) and est["faces"].shape == (2, 3)
    np.testing.assert_allclose(est["vertices"][1], first + 0.1, atol=1e-6)
    assert np.isnan(est["vertices"][2:]).all() and not est["visible"][2:].any() and est["visible"][:2].all()
    # the new mesh under mesh1_, NaN before it was laid
    assert est["mesh1_vertices"].shape == (4, 4, 3) and est["mesh1_faces"].tolist() == f4.tolist()
    np.testing.assert_allclose(est["mesh1_vertices"][3], second + 0.2, atol=1e-6)
    assert np.isnan(est["mesh1_vertices"][:2]).all() and est["mesh1_visible"][2:].all()
    assert est["timestamps"].tolist() == [0.0, 1.0, 2.0, 3.0] and "mesh2_vertices" not in est


def test_command_line_has_no_traceback_for_user_mistakes(tmp_path):
    r = subprocess.run([sys.executable, "-m", "perception.track", str(tmp_path), "--output", str(tmp_path / "x.npz")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and r.stderr.strip().count("\n") == 0
