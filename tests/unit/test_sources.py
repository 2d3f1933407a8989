"""Frame sources and the paced publish loop, without sockets.

RealSense and Azure Kinect are tested through tiny fake SDK modules injected at the
import boundary (``sys.modules``), shaped like pyrealsense2 and pyk4a, so that the
conversion code (units, depth scale, channel order, intrinsics, distortion) runs for real.
"""

import sys
import threading
import types
from enum import IntEnum
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from ipc.messages import CameraInfo, RGBDFrame
from perception.sequence import SequenceWriter
from perception.sources import (
    FrameSource,
    KinectSource,
    Pacing,
    RealSenseSource,
    SequenceSource,
    SourceError,
    publish_frames,
)
from perception.sources._kinect import rgb_from_kinect

CAM = CameraInfo.from_fov(32, 24, 1.0)


def frame(seq, t, value=1.0, cam=CAM):
    rgb = np.full((cam.height, cam.width, 3), seq % 256, np.uint8)
    return RGBDFrame(rgb, np.full((cam.height, cam.width), value, np.float32), cam, t, seq)


class ListSource(FrameSource):
    name = "list"

    def __init__(self, frames):
        self._frames = frames
        self.passes = 0

    def frames(self):
        self.passes += 1
        yield from self._frames


class FakeClock:
    """A monotonic clock that advances only when waited on."""

    def __init__(self):
        self.now = 100.0
        self.waits = []

    def __call__(self):
        return self.now

    def wait(self, seconds):
        self.waits.append(seconds)
        self.now += seconds
        return False


def run(source, clock=None, **kw):
    clock = clock or FakeClock()
    sent = []

    def publish(f):
        sent.append((clock.now, f))

    n = publish_frames(source, publish, clock=clock, wait=clock.wait, **kw)
    assert n == len(sent)
    return sent


# -- pacing and loop ----------------------------------------------------------------------


def test_pacing_is_checked():
    with pytest.raises(ValueError, match="Pacing.mode: expected one of"):
        Pacing("slow")
    with pytest.raises(ValueError, match="Pacing.rate_hz: expected a positive number for mode 'rate', got None"):
        Pacing("rate")
    with pytest.raises(ValueError, match="only for mode 'rate'"):
        Pacing("fast", 10.0)


def test_realtime_pacing_keeps_the_timestamps_spacing():
    stamps = [5.0, 5.1, 5.3, 5.35]
    sent = run(ListSource([frame(i, t) for i, t in enumerate(stamps)]), pacing=Pacing("realtime"))
    times = np.array([t for t, _ in sent])
    np.testing.assert_allclose(times - times[0], np.array(stamps) - stamps[0], atol=1e-9)
    assert [f.seq for _, f in sent] == [0, 1, 2, 3]


def test_rate_and_fast_pacing():
    frames = [frame(i, 0.0) for i in range(4)]  # timestamps are ignored by both
    times = np.array([t for t, _ in run(ListSource(frames), pacing=Pacing("rate", 20.0))])
    np.testing.assert_allclose(np.diff(times), 0.05)
    times = np.array([t for t, _ in run(ListSource(frames), pacing=Pacing("fast"))])
    np.testing.assert_allclose(np.diff(times), 0.0)


def test_a_late_frame_is_sent_at_once_and_never_followed_by_a_burst():
    clock = FakeClock()

    class Slow(ListSource):
        def frames(self):
            for f in self._frames:
                if f.seq == 1:
                    clock.now += 1.0  # the source stalls for a second
                yield f

    sent = run(Slow([frame(i, 0.1 * i) for i in range(4)]), clock=clock, pacing=Pacing("realtime"))
    times = np.array([t for t, _ in sent])
    np.testing.assert_allclose(np.diff(times), [1.0, 0.1, 0.1])


def test_loop_continues_seq_and_time_and_max_frames_stops():
    src = ListSource([frame(i + 10, 2.0 + 0.1 * i) for i in range(3)])
    sent = run(src, pacing=Pacing("realtime"), loop=True, max_frames=7)
    seqs = [f.seq for _, f in sent]
    stamps = np.array([f.timestamp_s for _, f in sent])
    assert seqs == [10, 11, 12, 13, 14, 15, 16]
    np.testing.assert_allclose(stamps, 2.0 + 0.1 * np.arange(7))
    assert src.passes == 3
    assert [f.rgb[0, 0, 0] for _, f in sent][3] == 10  # the fourth frame is the first one again


def test_stop_ends_the_loop_and_a_finite_source_ends_without_loop():
    stop = threading.Event()
    sent = []

    def publish(f):
        sent.append(f)
        if len(sent) == 2:
            stop.set()

    src = ListSource([frame(i, 0.0) for i in range(5)])
    assert publish_frames(src, publish, pacing=Pacing("fast"), loop=True, stop=stop) == 2
    assert len(run(ListSource([frame(0, 0.0), frame(1, 0.1)]), pacing=Pacing("fast"))) == 2
    assert run(ListSource([]), loop=True) == []


# -- sequence and sim ------------------------------------------------------------------------


def test_sequence_source_replays_the_folder_with_its_depth_scale(tmp_path):
    written = [frame(i, 0.5 + i / 30, value=0.8 + 0.1 * i) for i in range(3)]
    with SequenceWriter(tmp_path / "seq", CAM, depth_scale=1000.0) as writer:
        for f in written:
            writer.write(f)
    with SequenceSource(tmp_path / "seq") as src:
        assert len(src) == 3 and src.depth_scale == 1000.0 and src.camera.width == 32
        for _ in range(2):  # each pass starts at the first frame
            got = list(src.frames())
            assert [f.seq for f in got] == [0, 1, 2]
            for f, w in zip(got, written):
                assert f.timestamp_s == pytest.approx(w.timestamp_s, abs=1e-6)
                np.testing.assert_array_equal(f.rgb, w.rgb)
                np.testing.assert_allclose(f.depth_m, w.depth_m, atol=1e-6)
    with pytest.raises(ValueError, match="no such directory"):
        SequenceSource(tmp_path / "missing")


def test_a_sequence_frame_that_cannot_be_read_is_skipped_and_the_stream_goes_on(tmp_path, caplog):
    with SequenceWriter(tmp_path / "seq", CAM, depth_scale=1000.0) as writer:
        for i in range(4):
            writer.write(frame(i, 0.5 + i / 30))
    broken = sorted((tmp_path / "seq" / "depth").iterdir())[1]
    broken.write_bytes(broken.read_bytes()[:40])  # truncated, as a copy cut short leaves it
    with SequenceSource(tmp_path / "seq") as src, caplog.at_level("WARNING"):
        assert [f.seq for f in src.frames()] == [0, 2, 3] and src.skipped == 1
    assert f"frame 1 skipped: {broken}: unreadable image" in caplog.text


@pytest.mark.slow
def test_scene_source_renders_frames_at_30_hz_and_replays_a_pass():
    pytest.importorskip("pybullet")
    from sim.frame_source import SceneSource
    from sim.scenes import make_scene

    with SceneSource(make_scene("poster_bend", seed=2, width=64, height=48), n_frames=2) as src:
        assert src.name == "sim:poster_bend"
        first = list(src.frames())
        assert [f.seq for f in first] == [0, 1]
        assert [f.timestamp_s for f in first] == pytest.approx([0.0, 1 / 30])
        assert first[0].rgb.shape == (48, 64, 3) and src.depth_scale is None
        again = list(src.frames())
        assert again[1].rgb.tobytes() == first[1].rgb.tobytes()
        with pytest.raises(ValueError, match="n_frames"):
            SceneSource(src.scene, n_frames=0)


@pytest.mark.slow
def test_sim_source_sends_the_known_occluder_mask_when_asked():
    pytest.importorskip("pybullet")
    from launch_scripts.publish_frames import build_parser, open_source

    common = ["sim", "--scene", "gripper_corner_move", "--seed", "2", "--width", "64", "--height", "48"]
    with open_source(build_parser().parse_args([*common, "--known-occluders"])) as src:
        assert src.n_frames == src.scene.n_frames >= 60
        frame = next(src.frames())
        assert frame.occluder_mask.shape == (48, 64) and frame.occluder_mask.any()
    with open_source(build_parser().parse_args([*common, "--known-occluders", "--no-occluders"])) as twin:
        clear = next(twin.frames())
        assert not clear.occluder_mask.any()
        assert np.any(clear.rgb[frame.occluder_mask] != frame.rgb[frame.occluder_mask])
    with open_source(build_parser().parse_args(common)) as plain:
        assert next(plain.frames()).occluder_mask is None


# -- optional SDKs ---------------------------------------------------------------------------


def test_a_missing_sdk_names_the_extra_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import raises ModuleNotFoundError
    with pytest.raises(SourceError, match=r"RealSense source needs the Python module 'pyrealsense2', which is not "
                                          r"installed; .*pip install -e '\.\[realsense\]'"):
        RealSenseSource()
    monkeypatch.setitem(sys.modules, "pyk4a", None)
    with pytest.raises(SourceError, match=r"pip install -e '\.\[kinect\]'"):
        KinectSource()


def test_an_sdk_that_is_installed_but_does_not_load_is_not_sent_to_pip(monkeypatch):
    import importlib

    def no_libusb(name, *args):
        raise ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")

    monkeypatch.setattr(importlib, "import_module", no_libusb)
    with pytest.raises(SourceError, match=r"'pyrealsense2', which is installed but does not load \(libusb-1\.0\.so\.0") as e:
        RealSenseSource()
    assert "pip install" not in str(e.value)


class FakeRealSense:
    """A module shaped like pyrealsense2 for one device: colour at W x H, depth natively at
    half that size; ``align`` produces depth at the colour size (as the SDK does)."""

    W, H = 64, 48
    DEPTH_UNIT_M = 0.0001  # a D405's 0.1 mm unit: a scale that must not be assumed

    def __init__(self, colour_format="rgb8", model="brown_conrady", coeffs=(0.1, -0.05, 0.001, 0.002, 0.01)):
        rs = types.ModuleType("pyrealsense2")
        rs.stream = SimpleNamespace(depth="stream.depth", color="stream.color")
        rs.format = SimpleNamespace(**{n: f"format.{n}" for n in ("z16", "rgb8", "bgr8", "rgba8", "bgra8", "yuyv", "y16")})
        rs.distortion = SimpleNamespace(**{n: f"distortion.{n}" for n in (
            "none", "brown_conrady", "modified_brown_conrady", "inverse_brown_conrady", "ftheta", "kannala_brandt4")})
        fake = self
        self.rs, self.enabled, self.aligned_to, self.stopped, self.timeout = rs, [], None, False, False
        self.colour_format = getattr(rs.format, colour_format)
        rng = np.random.default_rng(0)
        self.colour = rng.integers(0, 256, (self.H, self.W, 3), dtype=np.uint8)
        self.aligned_depth = rng.integers(0, 30000, (self.H, self.W), dtype=np.uint16)
        self.aligned_depth[0, 0] = 0  # no measurement
        colour_intr = SimpleNamespace(width=self.W, height=self.H, fx=61.5, fy=61.7, ppx=31.2, ppy=23.9,
                                      model=getattr(rs.distortion, model), coeffs=list(coeffs))
        depth_intr = SimpleNamespace(width=self.W // 2, height=self.H // 2, fx=39.0, fy=39.0, ppx=16.0, ppy=12.0,
                                     model=rs.distortion.brown_conrady, coeffs=[0.0] * 5)

        class Frame:
            def __init__(self, data, fmt, number=0, stamp_ms=0.0):
                self.data, self.fmt, self.number, self.stamp_ms = data, fmt, number, stamp_ms

            def get_data(self):
                return self.data

            def get_profile(self):
                return SimpleNamespace(format=lambda: self.fmt)

            def get_timestamp(self):
                return self.stamp_ms

            def get_frame_number(self):
                return self.number

        class Frameset:
            def __init__(self, colour, depth):
                self.colour, self.depth = colour, depth

            def get_color_frame(self):
                return self.colour

            def get_depth_frame(self):
                return self.depth

        class config:
            def enable_stream(self, stream, width, height, fmt, fps):
                fake.enabled.append((stream, width, height, fmt, fps))

            def enable_device(self, serial):
                fake.enabled.append(("device", serial))

        class pipeline:
            def start(self, cfg):
                sensor = SimpleNamespace(get_depth_scale=lambda: fake.DEPTH_UNIT_M)
                streams = {rs.stream.color: colour_intr, rs.stream.depth: depth_intr}
                return SimpleNamespace(
                    get_device=lambda: SimpleNamespace(first_depth_sensor=lambda: sensor),
                    get_stream=lambda s: SimpleNamespace(as_video_stream_profile=lambda: SimpleNamespace(
                        get_intrinsics=lambda: streams[s])))

            def wait_for_frames(self, timeout_ms):
                if fake.timeout:
                    raise RuntimeError(f"Frame didn't arrive within {timeout_ms}")
                native = np.zeros((fake.H // 2, fake.W // 2), np.uint16)  # unaligned: must not be used
                return Frameset(Frame(fake.colour, fake.colour_format, 42, 1234567.5), Frame(native, rs.format.z16))

            def stop(self):
                fake.stopped = True

        class align:
            def __init__(self, align_to):
                fake.aligned_to = align_to

            def process(self, frames):
                return Frameset(frames.colour, Frame(fake.aligned_depth, rs.format.z16))

        rs.config, rs.pipeline, rs.align = config, pipeline, align


def test_realsense_frames_are_aligned_scaled_and_carry_the_colour_intrinsics(monkeypatch):
    fake = FakeRealSense()
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.rs)
    with RealSenseSource(fake.W, fake.H, 30, serial="123") as src:
        f = next(src.frames())
    assert ("device", "123") in fake.enabled
    assert (fake.rs.stream.depth, 64, 48, fake.rs.format.z16, 30) in fake.enabled
    assert fake.aligned_to == fake.rs.stream.color and fake.stopped
    assert src.depth_scale == pytest.approx(10000.0)  # units per metre on the wire: 1 / the device's unit
    np.testing.assert_allclose(f.depth_m, fake.aligned_depth.astype(np.float64) * 0.0001, rtol=1e-6)
    assert f.depth_m[0, 0] == 0.0
    np.testing.assert_array_equal(f.rgb, fake.colour)
    assert not np.shares_memory(f.rgb, fake.colour)  # copied out of the SDK's buffer
    np.testing.assert_allclose(f.camera.K, [[61.5, 0, 31.2], [0, 61.7, 23.9], [0, 0, 1]], rtol=1e-6)
    np.testing.assert_allclose(f.camera.D, [0.1, -0.05, 0.001, 0.002, 0.01])
    assert f.timestamp_s == pytest.approx(1234.5675) and f.seq == 42


def test_realsense_colour_formats_a_recording_may_hold_become_rgb():
    from perception.sources._realsense import _rgb_of

    rs = FakeRealSense().rs
    rgb = np.random.default_rng(1).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    bgra = np.concatenate([rgb[:, :, ::-1], np.full((4, 6, 1), 255, np.uint8)], axis=2)
    np.testing.assert_array_equal(_rgb_of(bgra, rs.format.bgra8, rs, (4, 6)), rgb)
    np.testing.assert_array_equal(_rgb_of(bgra[:, :, [2, 1, 0, 3]], rs.format.rgba8, rs, (4, 6)), rgb)
    yuyv = np.full((4, 6, 2), 128, np.uint8)  # Y, U and V all 128: mid grey
    yuyv[:, 0::2, 1] = 90  # U under 128 on every other byte pair: a yellower grey, R and G over B
    for data in (yuyv, yuyv.view(np.uint16).reshape(4, 6)):  # as bytes, and as the SDK's one uint16 a pixel
        out = _rgb_of(data, rs.format.yuyv, rs, (4, 6)).astype(int)
        assert out.shape == (4, 6, 3) and np.all(out[..., 0] > out[..., 2] + 30) and np.all(out[..., 1] > out[..., 2])
    with pytest.raises(SourceError, match="colour format format.y16 is not supported"):
        _rgb_of(rgb, rs.format.y16, rs, (4, 6))
    with pytest.raises(SourceError, match=r"expected a \(4, 6, 4\) uint8 colour image in format.bgra8, got \(4, 6, 3\)"):
        _rgb_of(rgb, rs.format.bgra8, rs, (4, 6))


def test_a_realsense_recording_refuses_the_device_options_before_the_sdk_is_needed(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # no SDK: these fail on the arguments alone
    with pytest.raises(ValueError, match=r"a recording has its own size, frame rate and device; got width=1280, "
                                         r"serial='123' with recording='.*a\.db3'"):
        RealSenseSource(1280, serial="123", recording=tmp_path / "a.db3")
    with pytest.raises(SourceError, match=r"pip install -e '\.\[realsense\]'"):  # options fine: now the SDK
        RealSenseSource(recording=tmp_path / "a.db3")


def test_realsense_bgr_is_turned_to_rgb_and_zero_or_foreign_distortion(monkeypatch):
    fake = FakeRealSense(colour_format="bgr8", model="inverse_brown_conrady", coeffs=(0.0,) * 5)
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.rs)
    with RealSenseSource(fake.W, fake.H) as src:
        f = next(src.frames())
        assert src.camera.D.size == 0  # all-zero coefficients: no distortion, whatever the model
        fake.timeout = True
        with pytest.raises(SourceError, match="RealSense: no frames within 5000 ms"):
            next(src.frames())
    np.testing.assert_array_equal(f.rgb, fake.colour[:, :, ::-1])
    fake = FakeRealSense(model="inverse_brown_conrady", coeffs=(0.1, 0, 0, 0, 0))
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.rs)
    with pytest.raises(SourceError, match="distortion model distortion.inverse_brown_conrady .* no OpenCV plumb_bob"):
        RealSenseSource(fake.W, fake.H)
    assert fake.stopped  # the pipeline started in the constructor is stopped again


class FakeKinect:
    """A module shaped like pyk4a for one device with a 720p colour camera."""

    def __init__(self):
        k4a = types.ModuleType("pyk4a")
        fake = self

        class CalibrationType(IntEnum):
            DEPTH = 0
            COLOR = 1

        class K4AException(Exception):
            pass

        class K4ATimeoutException(K4AException):
            pass

        k4a.CalibrationType, k4a.K4AException, k4a.K4ATimeoutException = CalibrationType, K4AException, K4ATimeoutException
        k4a.ColorResolution = SimpleNamespace(RES_720P="RES_720P", RES_1080P="RES_1080P")
        k4a.DepthMode = SimpleNamespace(NFOV_UNBINNED="NFOV_UNBINNED", WFOV_2X2BINNED="WFOV_2X2BINNED")
        k4a.FPS = SimpleNamespace(FPS_5="FPS_5", FPS_15="FPS_15", FPS_30="FPS_30")
        k4a.ImageFormat = SimpleNamespace(COLOR_BGRA32="COLOR_BGRA32", COLOR_MJPG="COLOR_MJPG")
        k4a.Config = lambda **kw: SimpleNamespace(**kw)
        self.k4a, self.config, self.stopped, self.timeout, self.unplugged = k4a, None, False, False, False
        self.K = {CalibrationType.COLOR: [[605.0, 0, 639.5], [0, 604.5, 365.2], [0, 0, 1]],
                  CalibrationType.DEPTH: [[504.0, 0, 320.0], [0, 504.0, 288.0], [0, 0, 1]]}
        self.D = {CalibrationType.COLOR: [0.5, -2.7, 0.0007, -0.0002, 1.5, 0.4, -2.5, 1.4],
                  CalibrationType.DEPTH: [3.1, 2.3, 0.0, 0.0, 0.1, 3.4, 3.3, 0.6]}
        bgra = np.zeros((720, 1280, 4), np.uint8)
        bgra[..., 0], bgra[..., 1], bgra[..., 2], bgra[..., 3] = 10, 20, 30, 255
        bgra[5, 7] = (1, 2, 3, 255)
        depth = np.full((720, 1280), 1500, np.uint16)  # in the colour camera: what the SDK's transformation gives
        depth[0, :] = 0
        raw = np.full((576, 640), 1500, np.uint16)  # in the depth camera
        self.bgra, self.depth_mm = bgra, depth
        self.captures = [SimpleNamespace(color=None, depth=raw, color_timestamp_usec=0),
                         SimpleNamespace(color=bgra, depth=raw, color_timestamp_usec=2_500_000)]
        self.unwritten = 0  # calls that return an unwritten output (as the SDK's transformation thread can)
        self.transform_calls = 0
        rng = np.random.default_rng(0)

        def depth_image_to_color_camera_custom(depth_mm, custom, calibration, thread_safe):
            assert depth_mm is raw and custom.shape == raw.shape and custom.dtype == np.uint16
            fake.transform_calls += 1
            if fake.unwritten:
                fake.unwritten -= 1  # what the memory held: an older output, with an older token
                stale = rng.integers(0, 3000, depth.shape).astype(np.uint16)
                return np.where(stale > 0, custom[0, 0] - 1, 0).astype(np.uint16), stale
            return np.where(depth > 0, custom[0, 0], 0).astype(np.uint16), depth.copy()

        k4a.depth_image_to_color_camera_custom = depth_image_to_color_camera_custom

        class Calibration:
            def get_camera_matrix(self, camera):
                return np.array(fake.K[camera], dtype=float)

            def get_distortion_coefficients(self, camera):
                return np.array(fake.D[camera])

        class PyK4A:
            def __init__(self, config=None, device_id=0):
                fake.config, fake.device_id = config, device_id
                self.calibration = Calibration()

            def start(self):
                pass

            def stop(self):
                fake.stopped = True

            def get_capture(self, timeout=-1):
                if fake.unplugged:
                    raise K4AException("K4A_WAIT_RESULT_FAILED")  # what pyk4a raises for a device that failed
                if fake.timeout or not fake.captures:
                    raise K4ATimeoutException()
                return fake.captures.pop(0)

        k4a.PyK4A = PyK4A


def test_kinect_frames_are_rgb_in_metres_with_the_colour_calibration(monkeypatch):
    fake = FakeKinect()
    monkeypatch.setitem(sys.modules, "pyk4a", fake.k4a)
    with KinectSource("720p", "nfov_unbinned", 30, device_id=1) as src:
        f = next(src.frames())  # the capture without colour is skipped
        with pytest.raises(SourceError, match="Kinect: no capture within 5000 ms"):
            next(src.frames())
        fake.unplugged = True
        with pytest.raises(SourceError, match=r"Kinect: the device stopped delivering captures \(K4A_WAIT_RESULT_FAILED\)"):
            next(src.frames())
    cfg = fake.config
    assert (cfg.color_format, cfg.color_resolution, cfg.depth_mode, cfg.camera_fps, cfg.synchronized_images_only) == \
        ("COLOR_BGRA32", "RES_720P", "NFOV_UNBINNED", "FPS_30", True)
    assert fake.device_id == 1 and fake.stopped and src.depth_scale == 1000.0
    assert f.rgb.shape == (720, 1280, 3) and tuple(f.rgb[0, 0]) == (30, 20, 10) and tuple(f.rgb[5, 7]) == (3, 2, 1)
    assert f.depth_m[1, 0] == pytest.approx(1.5) and f.depth_m[0, 0] == 0.0 and f.depth_m.dtype == np.float32
    assert (f.camera.width, f.camera.height) == (1280, 720)
    np.testing.assert_allclose(f.camera.K, fake.K[fake.k4a.CalibrationType.COLOR])
    np.testing.assert_allclose(f.camera.D, fake.D[fake.k4a.CalibrationType.COLOR])
    assert f.timestamp_s == pytest.approx(2.5) and f.seq == 0


def test_kinect_options_are_checked(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyk4a", FakeKinect().k4a)
    with pytest.raises(ValueError, match="KinectSource.colour_resolution: expected one of 720p, 1080p"):
        KinectSource("4k")
    with pytest.raises(ValueError, match="KinectSource.fps: expected one of 5, 15, 30, got 60"):
        KinectSource(fps=60)


def test_a_kinect_recording_is_checked_before_the_sdk_is_needed(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "pyk4a", None)  # no SDK: these fail on the arguments alone
    with pytest.raises(SourceError, match=r"^Kinect: recording .*missing\.mkv not found$"):
        KinectSource(recording=tmp_path / "missing.mkv")
    with pytest.raises(SourceError, match=r"^Kinect: recording .* is not a file$"):
        KinectSource(recording=tmp_path)
    (tmp_path / "a.mkv").write_bytes(b"")
    with pytest.raises(ValueError, match=r"a recording has its own .*; got colour_resolution='1080p', fps=15 with "
                                         r"recording='.*a\.mkv'"):
        KinectSource("1080p", fps=15, recording=tmp_path / "a.mkv")
    with pytest.raises(ValueError, match="got device_id=1 with"):
        KinectSource(device_id=1, recording=tmp_path / "a.mkv")
    with pytest.raises(SourceError, match=r"pip install -e '\.\[kinect\]'"):  # a good file: now the SDK is needed
        KinectSource(recording=tmp_path / "a.mkv")


def test_a_kinect_recording_is_published_at_its_recorded_pace_by_default():
    from launch_scripts.publish_frames import build_parser, default_pacing

    def pacing(*argv):
        return default_pacing(build_parser().parse_args(argv))

    # The SDK reads a Kinect recording as fast as asked; a RealSense recording plays at its pace.
    assert pacing("kinect", "--recording", "a.mkv") == "realtime" and pacing("kinect") == "fast"
    assert pacing("realsense", "--recording", "a.db3") == "fast" and pacing("sequence", "SEQ") == "realtime"


def test_kinect_redoes_a_transformation_the_sdk_returned_unwritten(monkeypatch):
    fake = FakeKinect()
    fake.unwritten = 2
    capture = fake.captures[1]
    monkeypatch.setitem(sys.modules, "pyk4a", fake.k4a)
    with KinectSource() as src:
        f = next(src.frames())
        np.testing.assert_array_equal(f.depth_m, fake.depth_mm / np.float32(1000))
        assert src.transformations_redone == 2 and fake.transform_calls == 3
        fake.unwritten, fake.captures = 100, [capture]
        with pytest.raises(SourceError, match="returned an unwritten output 8 times in a row"):
            next(src.frames())


def test_kinect_without_a_working_transformation_says_what_it_needs(monkeypatch):
    fake = FakeKinect()
    fake.k4a.depth_image_to_color_camera_custom = lambda *args: None  # what pyk4a returns when the SDK call fails
    monkeypatch.setitem(sys.modules, "pyk4a", fake.k4a)
    monkeypatch.delenv("DISPLAY", raising=False)
    with KinectSource() as src, pytest.raises(SourceError, match=r"cannot transform depth .*DISPLAY is not set: .*Xvfb"):
        next(src.frames())


def kinect_colour(rgb, fmt):
    """An RGB image as the Azure Kinect delivers it in ``fmt`` (OpenCV's encoders)."""
    h, w = rgb.shape[:2]
    if fmt == "COLOR_BGRA32":
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGRA)
    if fmt == "COLOR_MJPG":
        return cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].ravel()
    if fmt == "COLOR_NV12":
        i420 = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420).ravel()
        uv = np.stack([i420[h * w:h * w * 5 // 4], i420[h * w * 5 // 4:]], axis=1).ravel()
        return np.concatenate([i420[:h * w], uv]).reshape(h * 3 // 2, w, 1)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_YUY2)


@pytest.mark.parametrize("fmt, tolerance", [("COLOR_BGRA32", 0), ("COLOR_MJPG", 3), ("COLOR_NV12", 3), ("COLOR_YUY2", 3)])
def test_kinect_colour_formats_become_rgb(fmt, tolerance):
    h, w = 48, 64
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, np.arange(w)[None, :] * 2, np.arange(h)[:, None]
    got = rgb_from_kinect(kinect_colour(rgb, fmt), fmt, (h, w))
    assert got.shape == (h, w, 3) and got.dtype == np.uint8
    assert np.abs(got.astype(int) - rgb).mean() <= tolerance


def test_kinect_colour_that_cannot_be_used_is_named():
    assert rgb_from_kinect(np.frombuffer(b"\xff\xd8 not a jpeg", np.uint8), "COLOR_MJPG", (48, 64)) is None
    with pytest.raises(SourceError, match=r"expected a \(48, 64, 4\) uint8 COLOR_BGRA32 colour image, got \(48, 64, 3\)"):
        rgb_from_kinect(np.zeros((48, 64, 3), np.uint8), "COLOR_BGRA32", (48, 64))
    with pytest.raises(SourceError, match=r"an MJPG colour image decodes to 32x16, expected 64x48"):
        rgb_from_kinect(kinect_colour(np.zeros((16, 32, 3), np.uint8), "COLOR_MJPG"), "COLOR_MJPG", (48, 64))
    with pytest.raises(SourceError, match="colour format CUSTOM16 is not supported"):
        rgb_from_kinect(np.zeros((48, 64), np.uint16), "CUSTOM16", (48, 64))
