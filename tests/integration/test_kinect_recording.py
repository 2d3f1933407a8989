"""The Azure Kinect source through the real SDK: short recordings written here with the SDK's
own recorder (libk4arecord, through tests/k4a_writer.py: colour in each of the four formats,
depth, timestamps and a calibration with known intrinsics and a known colour-depth baseline),
played back through ``KinectSource(recording=...)`` and ``publish_frames kinect --recording``:
every frame in order, the recorded timestamps, depth in metres moved into the colour camera
by the SDK, the intrinsics and distortion of the calibration.

The SDK runs in its own environment with NumPy 1 and on a private Xvfb display
(tests/k4a_sdk.py); it is built on first use (about ten seconds with pip) and cached. Where
it cannot be built or Xvfb is missing the tests are skipped, except in CI (``CI`` set), where
that is a failure."""

import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from ipc.messages import RGBDFrame
from ipc.transport import Subscriber
from tests.k4a_sdk import Unavailable, sdk_python, x_display
from tests.k4a_writer import Lens, raw_calibration

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
N, FPS = 10, 30
W, H = 1280, 720  # 720p colour
DEPTH_W, DEPTH_H = 320, 288  # NFOV 2x2 binned depth
COLOUR = Lens(fx=600.0, fy=600.0, cx=639.5, cy=359.5, distortion=(0.02, -0.01, 0.001, -0.0005, 0.003, 0.01, -0.005, 0.002))
DEPTH = Lens(fx=250.0, fy=250.0, cx=159.5, cy=143.5)
BASELINE_M = 0.05  # the colour camera sits 5 cm to the right of the depth camera
NEAR_MM, FAR_MM = 1000, 2000  # the left half of the depth image is a wall at 1 m (1 mm further each frame), the right at 2 m
BLIND_ROWS = 30  # the depth image's top rows measure nothing


def depth_mm(k):
    depth = np.full((DEPTH_H, DEPTH_W), NEAR_MM + k, np.uint16)
    depth[:, DEPTH_W // 2:] = FAR_MM
    depth[:BLIND_ROWS] = 0
    return depth


def rgb(k):
    """Frame k's colour: red 20 k, green a ramp along the columns, blue along the rows."""
    image = np.empty((H, W, 3), np.uint8)
    image[..., 0] = 20 * k
    image[..., 1] = (np.arange(W) // 6)[None, :]
    image[..., 2] = (np.arange(H) // 3)[:, None]
    return image


def timestamp_us(k):
    return 5_000_000 + round(1e6 * k / FPS)


@pytest.fixture(scope="module")
def sdk():
    """(the SDK environment's python, an environment for its subprocesses with an X display)."""
    try:
        python = sdk_python()
        with x_display() as display:
            yield python, {**os.environ, "PYTHONPATH": str(REPO), "DISPLAY": display}
    except Unavailable as e:
        if os.environ.get("CI"):
            pytest.fail(f"Azure Kinect SDK: {e}")
        pytest.skip(f"Azure Kinect SDK: {e}")


def write(sdk, path, colour_format="BGRA32", colour=True, depth=True, calibration=True):
    """A recording of the scene: a depth-only capture (as the recorder's first often is), then N frames."""
    python, env = sdk
    frames = {"timestamps_us": np.array([timestamp_us(k) for k in range(-1, N)]),
              "has_rgb": np.arange(-1, N) >= 0}
    if colour:
        frames["rgb"] = np.stack([rgb(max(k, 0)) for k in range(-1, N)])
    if depth:
        frames["depth_mm"] = np.stack([depth_mm(max(k, 0)) for k in range(-1, N)])
    np.savez(path.with_suffix(".npz"), **frames)
    spec = {"path": str(path), "frames": str(path.with_suffix(".npz")), "colour_format": colour_format,
            "colour_resolution": "720P" if colour else "OFF", "depth_mode": "NFOV_2X2BINNED" if depth else "OFF",
            "fps": FPS, "calibration": raw_calibration(COLOUR, "720P", DEPTH, "NFOV_2X2BINNED",
                                                       t_colour_depth_m=(-BASELINE_M, 0.0, 0.0)) if calibration else None}
    path.with_suffix(".json").write_text(json.dumps(spec))
    subprocess.run([str(python), "-m", "tests.k4a_writer", str(path.with_suffix(".json"))], cwd=REPO, env=env,
                   check=True, timeout=300)
    return path


def play(sdk, path, passes=1, env=None, back_to_back=0):
    """What KinectSource(recording=path) yields in the SDK environment: the npz's arrays, or
    {"error": message}."""
    python, sdk_env = sdk
    out = path.with_name(path.stem + "-played.npz")
    proc = subprocess.run([str(python), "-m", "tests.k4a_play", str(path), str(out), "--passes", str(passes),
                           "--back-to-back", str(back_to_back)],
                          cwd=REPO, env=env or sdk_env, capture_output=True, text=True, timeout=300)
    if proc.returncode == 3:
        return json.loads([line for line in proc.stdout.splitlines() if line.startswith('{"error"')][-1])
    assert proc.returncode == 0, proc.stderr[-2000:]
    with np.load(out) as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="module")
def recordings(sdk, tmp_path_factory):
    folder = tmp_path_factory.mktemp("kinect")
    return {fmt: write(sdk, folder / f"sheet-{fmt.lower()}.mkv", fmt) for fmt in ("BGRA32", "MJPG", "NV12", "YUY2")}


def test_a_recording_plays_back_in_order_timed_and_with_depth_in_the_colour_camera(sdk, recordings):
    got = play(sdk, recordings["BGRA32"], passes=2)
    assert str(got["name"]) == "kinect:sheet-bgra32.mkv" and float(got["depth_scale"]) == 1000.0
    assert str(got["colour_format"]) == "COLOR_BGRA32"
    # The calibration's intrinsics and distortion, as the SDK derives them for 720p from the raw blob.
    assert got["size"].tolist() == [W, H]
    np.testing.assert_allclose(got["K"], [[COLOUR.fx, 0, COLOUR.cx], [0, COLOUR.fy, COLOUR.cy], [0, 0, 1]], atol=1e-3)
    np.testing.assert_allclose(got["D"], COLOUR.distortion, atol=1e-6)
    # Every frame once per pass, in order, at its recorded time; the depth-only capture skipped.
    assert got["pass_index"].tolist() == [0] * N + [1] * N
    assert got["seq"].tolist() == list(range(N)) * 2
    np.testing.assert_allclose(got["timestamp_s"], [timestamp_us(k) / 1e6 for k in range(N)] * 2, atol=1e-6)
    for i, k in enumerate(list(range(N)) * 2):
        np.testing.assert_array_equal(got["rgb"][i], rgb(k))
        depth = got["depth_m"][i]
        near, far = (NEAR_MM + k) / 1000, FAR_MM / 1000
        row = depth[360]  # the principal row; near the principal point the lens distortion moves less than 0.01 px
        # In the depth camera the walls meet at the principal point (x = 0). Seen from the colour
        # camera 5 cm to its right they move left by fx * 5 cm / z: the near wall's edge by
        # 30 px (to about column 608), the far wall's by 15 px (from about column 626); between
        # them the colour camera sees what the depth camera could not: no measurement.
        assert row[300] == pytest.approx(near, abs=1e-6) and row[600] == pytest.approx(near, abs=1e-6)
        assert np.all(row[612:623] == 0.0), row[604:630]
        assert row[630] == pytest.approx(far, abs=1e-6) and row[900] == pytest.approx(far, abs=1e-6)
        assert row[150] == 0.0  # left of the depth camera's field of view
        assert depth[60, 400] == 0.0 and depth[120, 400] == pytest.approx(near, abs=1e-6)  # the blind top rows


def test_transformations_straight_after_each_other_are_all_right(sdk, recordings):
    # The SDK's transformation thread drops some of the calls made straight after the previous
    # one (with Mesa's software OpenGL up to four in ten), and DepthToColour redoes those.
    # Whether a call is dropped depends on timing: this shows that every output is right.
    got = play(sdk, recordings["BGRA32"], back_to_back=200)
    rows, frames = got["back_to_back_row"], got["back_to_back_frame"]
    assert rows.shape == (200, W) and sorted(set(frames.tolist())) == list(range(N))
    near = (NEAR_MM + frames) / 1000
    np.testing.assert_allclose(rows[:, 300], near, atol=1e-6)
    np.testing.assert_allclose(rows[:, 600], near, atol=1e-6)
    assert np.all(rows[:, 612:623] == 0.0) and np.all(rows[:, 630] == FAR_MM / 1000)


@pytest.mark.parametrize("fmt", ["MJPG", "NV12", "YUY2"])
def test_compressed_and_subsampled_colour_is_decoded_to_rgb(sdk, recordings, fmt):
    got = play(sdk, recordings[fmt])
    assert str(got["colour_format"]) == f"COLOR_{fmt}" and got["seq"].tolist() == list(range(N))
    for k in range(N):
        error = np.abs(got["rgb"][k].astype(int) - rgb(k).astype(int))
        assert error.mean() < 2.0 and np.percentile(error, 99) <= 6, (k, error.mean(), error.max())
        assert got["depth_m"][k][360, 300] == pytest.approx((NEAR_MM + k) / 1000, abs=1e-6)


def test_the_command_line_publishes_a_recording(sdk, recordings):
    # Three passes: a subscriber that joins late (a loaded machine) still sees every frame of
    # the recording, each pass continuing seq and time (perception.sources.publish_frames).
    python, env = sdk
    passes = 3
    proc = subprocess.Popen([str(python), "-m", "launch_scripts.publish_frames", "kinect", "--recording",
                             str(recordings["BGRA32"]), "--endpoint", "tcp://127.0.0.1:*", "--print-endpoints",
                             "--start-delay-s", "1.0", "--heartbeat-period-s", "0.1", "--loop",
                             "--max-frames", str(passes * N),
                             "--pacing", "rate", "--rate-hz", "10"],  # slow enough that the subscriber takes every frame
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = next((line for line in proc.stdout if line.startswith("{")), None)
        assert line is not None, proc.stderr.read()
        frames = []
        with Subscriber(json.loads(line)["frames"], accept=(RGBDFrame,)) as sub:
            deadline = time.monotonic() + 60
            while len({f.seq % N for f in frames}) < N and time.monotonic() < deadline:
                frame = sub.recv_latest(timeout_s=5.0)
                if frame is not None:
                    frames.append(frame)
            assert sub.last_heartbeat is not None and sub.last_heartbeat.source == "kinect:sheet-bgra32.mkv"
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    seqs = [f.seq for f in frames]
    assert seqs == sorted(set(seqs)) and seqs[-1] < passes * N and {s % N for s in seqs} == set(range(N))
    period_s = (timestamp_us(N - 1) - timestamp_us(0)) / 1e6 / (N - 1)
    for f in frames:
        k, n = f.seq % N, f.seq // N
        assert f.timestamp_s == pytest.approx(timestamp_us(k) / 1e6 + n * (N * period_s), abs=1e-6)
        np.testing.assert_array_equal(f.rgb, rgb(k))
        assert f.depth_m[360, 300] == pytest.approx((NEAR_MM + k) / 1000, abs=1e-6) and f.depth_m[360, 615] == 0.0
        assert f.camera.fx == pytest.approx(COLOUR.fx, abs=1e-3)


def test_recordings_that_cannot_play_are_named(sdk, tmp_path):
    (tmp_path / "notes.mkv").write_text("not a recording")
    assert play(sdk, tmp_path / "notes.mkv") == {
        "error": f"Kinect: {tmp_path / 'notes.mkv'} is not an Azure Kinect recording (the SDK cannot open it)"}
    assert play(sdk, write(sdk, tmp_path / "depth-only.mkv", colour=False))["error"].endswith(
        "depth-only.mkv has no colour track")
    assert play(sdk, write(sdk, tmp_path / "colour-only.mkv", depth=False))["error"].endswith(
        "colour-only.mkv has no depth track")
    assert play(sdk, write(sdk, tmp_path / "uncalibrated.mkv", calibration=False))["error"].endswith(
        "uncalibrated.mkv holds no device calibration (its calibration.json attachment)")


def test_without_an_x_display_the_source_says_what_it_needs(sdk, recordings):
    env = {k: v for k, v in sdk[1].items() if k != "DISPLAY"}
    error = play(sdk, recordings["BGRA32"], env=env)["error"]
    assert error.startswith("Kinect: the SDK cannot transform depth into the colour camera") and "Xvfb" in error
