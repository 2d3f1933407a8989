"""The RealSense source through the real pyrealsense2: a short recording written here with the
SDK's own software device and recorder (colour, depth, intrinsics, extrinsics, depth units),
played back through ``RealSenseSource(recording=...)``: every frame, in order, depth aligned
to colour by the SDK, depth in the recorded units, the recorded timestamps.

Skipped where pyrealsense2 cannot be imported (it needs the system's libusb-1.0, which
.ci/run installs), except in CI (``CI`` set), where a missing SDK is a failure."""

import os
import time

import numpy as np
import pytest

from perception.sources import RealSenseSource, SourceError

if os.environ.get("CI"):
    import pyrealsense2 as rs
else:
    rs = pytest.importorskip("pyrealsense2", reason="pyrealsense2 (and libusb-1.0) not installed")

pytestmark = pytest.mark.timeout(120)

W, H, FPS, N = 64, 48, 30, 10
F_PX = 50.0  # both cameras' focal length, pixels
BASELINE_M = 0.05  # the colour camera sits 5 cm to the right of the depth camera
DEPTH_UNIT_M = 1e-4  # not the usual millimetre, so that a source assuming it would fail
NEAR_M, FAR_M = 1.0, 2.0  # the left half of the depth image is a wall at 1 m, the right half at 2 m


def intrinsics():
    i = rs.intrinsics()
    i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = W, H, F_PX, F_PX, W / 2, H / 2
    i.model, i.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    return i


def stream(kind, uid, fmt, bpp):
    s = rs.video_stream()
    s.type, s.index, s.uid, s.width, s.height, s.fps, s.bpp, s.fmt = kind, 0, uid, W, H, FPS, bpp, fmt
    s.intrinsics = intrinsics()
    return s


def depth_units(k):
    """Frame k's raw depth: near wall on the left (1 mm further each frame), far on the right."""
    depth = np.full((H, W), round((NEAR_M + 0.001 * k) / DEPTH_UNIT_M), np.uint16)
    depth[:, W // 2:] = round(FAR_M / DEPTH_UNIT_M)
    return depth


def timestamp_ms(k):
    return 5000.0 + 1000.0 * k / FPS


@pytest.fixture(scope="module", params=["two sensors", "one sensor"])
def recording(tmp_path_factory, request):
    """A recording of N frames; with "one sensor" both streams come from one sensor, as on a
    D405, whose recordings the playback must open once for both."""
    path = tmp_path_factory.mktemp("realsense") / "sheet.db3"
    device = rs.software_device()
    one = request.param == "one sensor"
    depth_sensor = device.add_sensor("Stereo Module" if one else "Depth")
    colour_sensor = depth_sensor if one else device.add_sensor("Color")
    depth_profile = depth_sensor.add_video_stream(stream(rs.stream.depth, 0, rs.format.z16, 2))
    colour_profile = colour_sensor.add_video_stream(stream(rs.stream.color, 1, rs.format.rgb8, 3))
    depth_sensor.add_read_only_option(rs.option.depth_units, DEPTH_UNIT_M)
    extrinsics = rs.extrinsics()
    extrinsics.rotation, extrinsics.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [BASELINE_M, 0, 0]
    depth_profile.register_extrinsics_to(colour_profile, extrinsics)
    device.create_matcher(rs.matchers.default)
    recorder = rs.recorder(str(path), device)
    if one:
        depth_sensor.open([depth_profile, colour_profile])
        depth_sensor.start(lambda f: None)
    else:
        depth_sensor.open(depth_profile)
        colour_sensor.open(colour_profile)
        depth_sensor.start(lambda f: None)
        colour_sensor.start(lambda f: None)
    for k in range(N):
        colour = np.zeros((H, W, 3), np.uint8)
        colour[..., 0], colour[..., 1] = k, np.arange(W, dtype=np.uint8)
        for sensor, profile, data, bpp in ((depth_sensor, depth_profile, depth_units(k), 2),
                                           (colour_sensor, colour_profile, colour, 3)):
            frame = rs.software_video_frame()
            frame.pixels, frame.stride, frame.bpp = data.tobytes(), W * bpp, bpp
            frame.timestamp, frame.domain, frame.frame_number = timestamp_ms(k), rs.timestamp_domain.hardware_clock, k
            frame.profile = profile.as_video_stream_profile()
            sensor.on_video_frame(frame)
        time.sleep(1.0 / FPS)
    for sensor in (depth_sensor,) if one else (depth_sensor, colour_sensor):
        sensor.stop()
        sensor.close()
    del recorder  # closes the file
    return path


def test_a_recording_plays_back_aligned_scaled_and_timed(recording):
    with RealSenseSource(recording=recording) as source:
        assert source.name == "realsense:sheet.db3"
        assert source.depth_scale == pytest.approx(1.0 / DEPTH_UNIT_M, rel=1e-6)
        assert source.camera.width == W and source.camera.fx == pytest.approx(F_PX) and source.camera.D.size == 0
        for _ in range(2):  # every pass starts from the beginning: a finite source that can loop
            frames = list(source.frames())
            assert [f.seq for f in frames] == list(range(N))
            for k, f in enumerate(frames):
                assert f.timestamp_s == pytest.approx(timestamp_ms(k) / 1000.0)
                assert f.rgb.shape == (H, W, 3) and np.all(f.rgb[..., 0] == k) and np.all(f.rgb[0, :, 1] == np.arange(W))
                near = NEAR_M + 0.001 * k  # this frame's depth, paired with this frame's colour
                row = f.depth_m[H // 2]
                assert row[10] == pytest.approx(near, abs=1e-5) and row[W - 5] == pytest.approx(FAR_M, abs=1e-5)
                # Aligned to the colour camera 5 cm to the right, the near wall's edge moves
                # F_PX * 5 cm / 1 m = 2.5 px right (over the far wall, which moves 1.25 px),
                # and nothing is seen at the left border.
                assert row[W // 2 + 1] == pytest.approx(near, abs=1e-5), row[W // 2 - 2: W // 2 + 4]
                assert row[W // 2 + 3] == pytest.approx(FAR_M, abs=1e-5)
                assert row[0] == 0.0


def test_bad_recordings_are_named(tmp_path):
    with pytest.raises(SourceError, match=r"expected a recording ending in \.db3 or \.bag"):
        RealSenseSource(recording=tmp_path / "x.mp4")
    with pytest.raises(SourceError, match="not found"):
        RealSenseSource(recording=tmp_path / "x.db3")
    (tmp_path / "broken.bag").write_bytes(b"#ROSBAG V2.0\n")
    with pytest.raises(SourceError, match=r"RealSense: cannot play .*broken.bag"):
        RealSenseSource(recording=tmp_path / "broken.bag")
