"""Frames from an Intel RealSense camera, or a recording of one, through pyrealsense2 (extra "realsense").

The depth stream is aligned to the colour stream with ``rs.align(rs.stream.color)``, so
both images share the colour camera's intrinsics, which become the frames' CameraInfo
(with the colour lens distortion). Depth units come from the device's depth sensor
(``get_depth_scale()``: metres per unit, 0.001 on most D400 cameras), never assumed.

A recording (``.db3`` from SDK 2.56 on, ``.bag`` from older ones, as the RealSense Viewer
or ``rs.recorder`` write them) plays back through the SDK's playback device at its recorded
pace, like the camera. Its streams are read sensor by sensor and paired by timestamp (the
SDK's frame syncer, in ``rs.pipeline``, drops the first frames of a recording and pairs a
colour frame with the previous depth frame when it plays faster than recorded); each pair
becomes a frameset for ``rs.align`` as from a camera.
"""

from __future__ import annotations

import datetime
import logging
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.sources._base import FrameSource, SourceError, optional_import, refuse_device_options

log = logging.getLogger(__name__)


def camera_info_from_realsense(intrinsics, rs, frame_id: str = "camera_color_optical_frame") -> CameraInfo:
    """CameraInfo from a pyrealsense2 ``intrinsics`` (width, height, fx, fy, ppx, ppy, model, coeffs).

    Distortion: ``none`` and all-zero coefficients give no D; ``brown_conrady`` is OpenCV's
    plumb_bob (k1 k2 p1 p2 k3) exactly; ``modified_brown_conrady`` applies the tangential
    terms after the radial ones and is taken as plumb_bob, which differs only in products
    of the small tangential and radial terms (logged); ``inverse_brown_conrady`` maps the
    other way (distorted to ideal) and the fish-eye models have no plumb_bob form, so a
    non-zero one raises SourceError.
    """
    coeffs = np.asarray(list(intrinsics.coeffs), dtype=np.float64)
    model = intrinsics.model
    if model == rs.distortion.none or not np.any(coeffs):
        D = np.zeros(0)
    elif model == rs.distortion.brown_conrady:
        D = coeffs[:5]
    elif model == rs.distortion.modified_brown_conrady:
        log.warning("RealSense colour distortion is modified Brown-Conrady %s; used as OpenCV plumb_bob",
                    np.round(coeffs, 6).tolist())
        D = coeffs[:5]
    else:
        raise SourceError(f"RealSense: colour distortion model {model} with coefficients {coeffs.tolist()} "
                          "has no OpenCV plumb_bob equivalent")
    K = np.array([[intrinsics.fx, 0.0, intrinsics.ppx], [0.0, intrinsics.fy, intrinsics.ppy], [0.0, 0.0, 1.0]])
    return CameraInfo(width=int(intrinsics.width), height=int(intrinsics.height), K=K, D=D, frame_id=frame_id)


def _rgb_of(colour: np.ndarray, fmt, rs, shape: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 RGB, a copy, from a colour frame's data in format ``fmt``: rgb8, bgr8,
    rgba8, bgra8 ((H, W, 3 or 4) uint8) or yuyv ((H, W, 2) uint8, or (H, W) uint16 as the
    SDK hands it), as cameras and the RealSense Viewer record them. Raises SourceError for another format or shape."""
    channels = {rs.format.rgb8: 3, rs.format.bgr8: 3, rs.format.rgba8: 4, rs.format.bgra8: 4, rs.format.yuyv: 2}
    if fmt == rs.format.yuyv and colour.shape == shape and colour.dtype == np.uint16:
        colour = colour.view(np.uint8).reshape(shape + (2,))  # the SDK hands YUYV as one uint16 a pixel
    if fmt not in channels:
        raise SourceError(f"RealSense: colour format {fmt} is not supported; expected rgb8, bgr8, rgba8, bgra8 or yuyv")
    if colour.shape != shape + (channels[fmt],) or colour.dtype != np.uint8:
        raise SourceError(f"RealSense: expected a {shape + (channels[fmt],)} uint8 colour image in {fmt}, got "
                          f"{colour.shape} {colour.dtype}")
    # The SDK owns the frame buffers and recycles them: every branch copies out.
    if fmt == rs.format.rgb8:
        return np.array(colour, dtype=np.uint8, copy=True)
    if fmt == rs.format.bgr8:
        return np.ascontiguousarray(colour[:, :, ::-1])
    if fmt == rs.format.yuyv:
        return cv2.cvtColor(colour, cv2.COLOR_YUV2RGB_YUYV)
    return cv2.cvtColor(colour, cv2.COLOR_RGBA2RGB if fmt == rs.format.rgba8 else cv2.COLOR_BGRA2RGB)


def frame_from_realsense(colour_frame, depth_frame, camera: CameraInfo, depth_unit_m: float, rs) -> RGBDFrame:
    """RGBDFrame from an aligned pair of pyrealsense2 frames.

    colour_frame : video frame, format rgb8, bgr8, rgba8, bgra8 or yuyv (``_rgb_of``)
    depth_frame : depth frame aligned to colour, z16: (H, W) uint16 in units of ``depth_unit_m``
    camera : CameraInfo of the colour stream (H, W must match)
    depth_unit_m : metres per depth unit (the depth sensor's ``get_depth_scale()``)
    returns RGBDFrame: depth_m = units * depth_unit_m (0 stays 0: no measurement),
    timestamp_s = colour timestamp (ms) / 1000, seq = colour frame number
    """
    fmt = colour_frame.get_profile().format()
    colour = np.asanyarray(colour_frame.get_data())
    raw = np.asanyarray(depth_frame.get_data())
    shape = (camera.height, camera.width)
    rgb = _rgb_of(colour, fmt, rs, shape)
    if raw.shape != shape or raw.dtype != np.uint16:
        raise SourceError(f"RealSense: expected a {shape} uint16 depth image aligned to colour, got {raw.shape} {raw.dtype}")
    depth_m = raw.astype(np.float32) * np.float32(depth_unit_m)
    return RGBDFrame(rgb=rgb, depth_m=depth_m, camera=camera, timestamp_s=colour_frame.get_timestamp() / 1000.0,
                     seq=int(colour_frame.get_frame_number()))


class RealSenseSource(FrameSource):
    """A RealSense camera streaming colour (rgb8) and depth (z16) at one size and rate, or a
    recording of one.

    width, height : pixels of both streams (the depth image is aligned to colour anyway)
    fps : frames per second the device is asked for
    serial : device serial number, or None for the first camera found
    timeout_s : seconds to wait for a frame before giving up with SourceError
    recording : path of a ``.db3`` or ``.bag`` recording to play instead of a camera; then
        ``frames()`` is one pass over it (a finite source) and ``name`` is
        ``realsense:FILE``. A recording has its own size, rate and device: any of
        ``width``, ``height``, ``fps`` and ``serial`` other than the defaults is refused
        with it (ValueError), rather than ignored.

    ``depth_scale`` (units per metre on the wire) is 1 / the device's depth unit, so the
    raw depth values travel unchanged.
    """

    RECORDING_SUFFIXES = (".db3", ".bag")

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, serial: str | None = None,
                 timeout_s: float = 5.0, recording: str | Path | None = None):
        if recording is not None:
            refuse_device_options(RealSenseSource, "size, frame rate and device",
                                  dict(width=width, height=height, fps=fps, serial=serial), recording)
        rs = optional_import("pyrealsense2", extra="realsense", feature="the RealSense source")
        self._rs = rs
        self.timeout_ms = int(1000 * timeout_s)
        self._pipeline = None
        self._streaming = False
        self._playback: _Playback | None = None
        if recording is not None:
            self._open_recording(Path(recording))
            return
        self.name = "realsense" if serial is None else f"realsense:{serial}"
        config = rs.config()
        if serial is not None:
            config.enable_device(serial)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        self._pipeline = rs.pipeline()
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as e:
            raise SourceError(f"RealSense: cannot stream colour and depth at {width}x{height}, {fps} fps ({e})") from None
        self._streaming = True
        try:
            self.depth_unit_m = _depth_unit(profile.get_device().first_depth_sensor())
            intrinsics = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
            self.camera = camera_info_from_realsense(intrinsics, rs)
        except BaseException:
            self.close()
            raise
        self.depth_scale = 1.0 / self.depth_unit_m
        self._align = rs.align(rs.stream.color)
        log.info("RealSense: %dx%d at %d fps, depth unit %.6g m, fx %.1f", width, height, fps, self.depth_unit_m,
                 self.camera.fx)

    def _open_recording(self, path: Path) -> None:
        if path.suffix not in self.RECORDING_SUFFIXES:
            raise SourceError(f"RealSense: expected a recording ending in {' or '.join(self.RECORDING_SUFFIXES)}, got {path}")
        if not path.is_file():
            raise SourceError(f"RealSense: recording {path} not found")
        self.name = f"realsense:{path.name}"
        self.recording = path
        playback = _Playback(self._rs, path, self.timeout_ms)  # reads the streams' descriptions; plays nothing yet
        try:
            self.depth_unit_m = playback.depth_unit_m
            self.camera = camera_info_from_realsense(playback.colour_intrinsics, self._rs)
        finally:
            playback.close()
        self.depth_scale = 1.0 / self.depth_unit_m
        self._align = self._rs.align(self._rs.stream.color)
        log.info("RealSense recording %s: %dx%d, depth unit %.6g m, fx %.1f", path, self.camera.width, self.camera.height,
                 self.depth_unit_m, self.camera.fx)

    def frames(self) -> Iterator[RGBDFrame]:
        if self._pipeline is None:
            yield from self._recorded_frames()
            return
        rs = self._rs
        while True:
            try:
                frameset = self._pipeline.wait_for_frames(self.timeout_ms)
            except RuntimeError as e:
                raise SourceError(f"RealSense: no frames within {self.timeout_ms} ms ({e})") from None
            aligned = self._align.process(frameset)
            colour, depth = aligned.get_color_frame(), aligned.get_depth_frame()
            if not colour or not depth:
                log.debug("RealSense: incomplete frameset skipped")
                continue
            yield frame_from_realsense(colour, depth, self.camera, self.depth_unit_m, rs)

    def _recorded_frames(self) -> Iterator[RGBDFrame]:
        """One pass over the recording, from its start."""
        self._playback = playback = _Playback(self._rs, self.recording, self.timeout_ms)
        try:
            playback.start()
            for frameset in playback.framesets():
                aligned = self._align.process(frameset)
                colour, depth = aligned.get_color_frame(), aligned.get_depth_frame()
                if not colour or not depth:
                    log.debug("RealSense recording: incomplete frameset skipped")
                    continue
                yield frame_from_realsense(colour, depth, self.camera, self.depth_unit_m, self._rs)
        finally:
            playback.close()
            self._playback = None

    def close(self) -> None:
        if self._streaming:  # stop() on a stopped pipeline raises
            self._streaming = False
            self._pipeline.stop()
        if self._playback is not None:
            self._playback.close()
            self._playback = None


def _depth_unit(depth_sensor) -> float:
    """Metres per depth unit of a depth sensor; raises SourceError unless positive."""
    unit = float(depth_sensor.get_depth_scale())
    if not unit > 0:
        raise SourceError(f"RealSense: the depth sensor reports a depth scale of {unit} m per unit")
    return unit


class _Playback:
    """One pass of a RealSense recording: the playback device's colour and depth sensors,
    each into a small frame queue, and their frames paired by timestamp.

    rs : the pyrealsense2 module; path : the recording; timeout_ms : longest wait for a frame
    """

    QUEUE_FRAMES = 4  # per stream: real-time playback and a consumer that keeps up need few

    def __init__(self, rs, path: Path, timeout_ms: int):
        self._rs, self.timeout_ms = rs, timeout_ms
        try:
            self.device = rs.context().load_device(str(path))
        except RuntimeError as e:
            raise SourceError(f"RealSense: cannot play {path} ({e})") from None
        self.playback = self.device.as_playback()
        self.playback.set_real_time(True)  # at the recorded pace, as the camera delivered it
        self._sensors, self._queues, self._profiles = [], {}, {}
        for index, sensor in enumerate(self.device.query_sensors()):
            for profile in sensor.get_stream_profiles():
                kind = profile.stream_type()
                if kind in (rs.stream.color, rs.stream.depth) and kind not in self._profiles:
                    self._profiles[kind] = (index, sensor, profile)
        missing = [name for kind, name in ((rs.stream.color, "colour"), (rs.stream.depth, "depth")) if kind not in self._profiles]
        if missing:
            raise SourceError(f"RealSense: {path} has no {' and no '.join(missing)} stream")
        colour = self._profiles[rs.stream.color][2].as_video_stream_profile()
        self.colour_intrinsics = colour.get_intrinsics()
        self.fps = colour.fps() or 30
        self.depth_unit_m = _depth_unit(self._profiles[rs.stream.depth][1].as_depth_sensor())
        self._pending: list = []
        self._playing = False
        self._combine = rs.processing_block(lambda frame, source: source.frame_ready(
            source.allocate_composite_frame(self._pending)))
        self._combined = rs.frame_queue(1, keep_frames=True)
        self._combine.start(self._combined)

    def start(self) -> None:
        """Play from the start. The playback runs as soon as one sensor starts: it is held
        until both listen, so that no stream loses its first frames."""
        rs = self._rs
        self.playback.pause()
        by_sensor: dict[int, tuple] = {}
        for kind, (index, sensor, profile) in self._profiles.items():
            self._queues[kind] = rs.frame_queue(self.QUEUE_FRAMES, keep_frames=True)
            by_sensor.setdefault(index, (sensor, []))[1].append(profile)
        for sensor, profiles in by_sensor.values():
            if len(profiles) == 1:
                sensor.open(profiles[0])
                sensor.start(self._queues[profiles[0].stream_type()])
            else:  # one sensor streams both (a D405's): opened once, its frames sorted by stream
                sensor.open(profiles)
                sensor.start(lambda frame: self._queues[frame.get_profile().stream_type()].enqueue(frame))
            self._sensors.append(sensor)
        self.playback.seek(datetime.timedelta(0))
        self.playback.resume()

    def _next(self, kind):
        """The next frame of stream ``kind``, or None at the end of the recording."""
        waited_ms = 0
        while True:
            ok, frame = self._queues[kind].try_wait_for_frame(50)
            if ok:
                self._playing = True
                return frame
            # The playback reports "stopped" until its first frame too: the end comes after one.
            if self._playing and self.playback.current_status() == self._rs.playback_status.stopped:
                frame = self._queues[kind].poll_for_frame()
                return frame if frame else None
            waited_ms += 50
            if waited_ms > self.timeout_ms:
                raise SourceError(f"RealSense: no frame of the recording within {self.timeout_ms} ms")

    def framesets(self):
        """Framesets of a depth and a colour frame taken at the same time (within half a colour
        frame period), in order, until the end of the recording; unpaired frames are skipped."""
        rs = self._rs
        tolerance_ms = 500.0 / self.fps
        colour, depth = self._next(rs.stream.color), self._next(rs.stream.depth)
        while colour is not None and depth is not None:
            gap_ms = colour.get_timestamp() - depth.get_timestamp()
            if gap_ms > tolerance_ms:
                depth = self._next(rs.stream.depth)
            elif gap_ms < -tolerance_ms:
                colour = self._next(rs.stream.color)
            else:
                self._pending[:] = [depth, colour]
                self._combine.invoke(colour)
                yield self._combined.wait_for_frame(self.timeout_ms).as_frameset()
                colour, depth = self._next(rs.stream.color), self._next(rs.stream.depth)

    def close(self) -> None:
        for sensor in self._sensors:
            sensor.stop()
            sensor.close()
        self._sensors = []
