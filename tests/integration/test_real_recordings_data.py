"""The converted public recordings, where they have been made (see README, "Real recordings").

They live outside the repository, under $CLOTHKIT_DATA (default /work/data); each test skips
when its recording is absent.
"""

import json

import numpy as np
import pytest

from perception.geometry import backproject, project
from perception.recordings import KINECT_V1_K, data_root, read_groundtruth_flow, read_reference_masks
from perception.sequence import open_sequence
from tests.benchmark_scripts import load_benchmark


def recording(name):
    path = data_root() / name
    if not (path / "rgb.txt").is_file():
        pytest.skip(f"{path} not converted (python -m launch_scripts.convert_recording ...)")
    return open_sequence(path)


def test_foam_tube_has_its_frames_and_a_reference_mask_each():
    seq = recording("foam_tube")
    assert len(seq) == 80 and (seq.camera.width, seq.camera.height) == (640, 480)
    np.testing.assert_array_equal(seq.camera.K, KINECT_V1_K)
    masks = read_reference_masks(seq)
    if not masks:
        pytest.skip("no reference masks yet (python -m launch_scripts.reference_masks)")
    assert sorted(masks) == list(range(80))
    for i in (0, 40, 79):
        frame = seq.frame(i)
        z = frame.depth_m[masks[i]]
        assert 0.4 < np.median(z) < 0.7 and (z > 0).mean() > 0.95  # the tube, half a metre away, measured
        # a 5 cm tube about 35 cm long at ~0.55 m: roughly 10000 to 20000 pixels
        assert 8000 < masks[i].sum() < 22000


@pytest.mark.parametrize("preset", ["default", "realtime"])
def test_foam_tube_on_default_options_meets_issue_11s_target_in_every_frame(tmp_path, preset):
    """The projected mesh covers at least 80 % of the tube and at least 90 % of its vertices
    lie on it, in every one of the 80 frames, none lost. Its worst frame covers 0.82 of the
    tube: a change of how the colour model halves an image (``perception.colour_model``) once
    took it to 0.79 in three frames unseen, while this recording was absent."""
    if not read_reference_masks(recording("foam_tube")):
        pytest.skip("no reference masks yet (python -m launch_scripts.reference_masks)")
    out = tmp_path / "real.json"
    assert load_benchmark("real_recordings").main(["--data", str(data_root()), "--recording", "foam_tube", "--preset", preset,
                                               "--json", str(out), "--pictures", str(tmp_path), "--quiet"]) == 0
    run = json.loads(out.read_text())["recordings"]["foam_tube"]["runs"][preset]["summary"]
    assert run["frames_meeting_target"] == run["frames"] == 80 and run["lost_frames"] == 0, run


def test_deepdeform_shirt_flow_conventions_agree():
    seq = recording("deepdeform_shirt_seq258")
    (pair,) = read_groundtruth_flow(seq)
    frame = seq.frame(pair.source)
    known = np.isfinite(pair.scene_flow_m).all(axis=2) & (frame.depth_m > 0)
    rows, cols = np.nonzero(known)
    pixels = np.stack([cols, rows], axis=1).astype(float)
    moved = backproject(pixels, frame.depth_m[rows, cols], seq.camera.K) + pair.scene_flow_m[rows, cols]
    # scene flow (metres, camera frame) and optical flow (pixels) describe the same motion
    gap = np.linalg.norm(project(moved, seq.camera.K) - (pixels + pair.optical_flow_px[rows, cols]), axis=1)
    assert np.median(gap) < 1.0
    assert np.median(np.linalg.norm(pair.optical_flow_px[rows, cols], axis=1)) > 80  # the large motion
    info = json.loads((seq.path / "recording.json").read_text())
    assert info["format"] == "deepdeform" and info["frame_numbers"] == [0, 110]


def test_foam_tube_faults_a_robot_meets_are_survived_or_flagged(tmp_path):
    """benchmarks/real_faults.py on the foam tube, realtime preset: the faults the tracker
    handles stay handled (a cut to another recording flagged lost at once and left behind, missing
    depth and half the frame rate within 10 mm of the clean run, an object 2 cm in front whose
    mask is known within 6 mm on average and 12 at worst, and the same object unannounced, found
    by its hue, doing no harm)."""
    recording("deepdeform_shirt_seq017")  # the scene the cut shows
    if not read_reference_masks(recording("foam_tube")):
        pytest.skip("no reference masks yet (python -m launch_scripts.reference_masks)")
    bench = load_benchmark("real_faults")
    out = tmp_path / "summary.json"
    assert bench.main(["--data", str(data_root()), "--recording", "foam_tube", "--cut-from", "deepdeform_shirt_seq017",
                       "--preset", "realtime", "--scenario", "cut", "depth holes", "dropped", "bar close, known", "bar close",
                       "--json", str(out), "--pictures", str(tmp_path), "-q"]) == 0
    runs = json.loads(out.read_text())["results"]["realtime"]
    assert runs["cut"]["wrong"] == 6 and runs["cut"]["wrong_not_lost_after_3"] == 0
    assert runs["cut"]["wrong_confident"] == 0 and runs["cut"]["deviation_after_mm"] < 10.0
    for name in ("depth holes", "dropped"):
        assert runs[name]["wrong"] == 0 and runs[name]["deviation_max_mm"] < 10.0, (name, runs[name])
    # The worst frame behind the bar moves by millimetres with how the hidden part is carried
    # (9.3, 10.8 and 9.7 mm in three variants of docs/results.md, "the hidden part of a cloth
    # turns with the part seen"); its mean stays under 5 mm.
    known = runs["bar close, known"]
    assert known["wrong"] == 0 and known["deviation_during_mm"] < 6.0 and known["deviation_max_mm"] < 12.0, known
    close = runs["bar close"]  # before it was found by its hue: 11.5 mm, 8 frames wrong, a new mesh
    assert close["wrong"] == 0 and not close["new_mesh"] and close["deviation_during_mm"] < 6.0, close
