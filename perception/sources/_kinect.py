"""Frames from a Microsoft Azure Kinect (or Orbbec Femto in K4A mode), or a recording of one,
through pyk4a (extra "kinect").

Colour becomes RGB: BGRA32 by reordering its channels; MJPG (the Azure Kinect recorder's
format, which pyk4a hands over undecoded), NV12 and YUY2 decoded by OpenCV. Depth is
transformed into the colour camera by the SDK (``k4a_transformation_depth_image_to_color_camera``:
uint16 millimetres, 0 = no measurement), so both images share the colour camera's calibration,
which becomes the CameraInfo: ``calibration.get_camera_matrix(CalibrationType.COLOR)`` and the
eight OpenCV rational coefficients k1 k2 p1 p2 k3 k4 k5 k6 of
``get_distortion_coefficients(CalibrationType.COLOR)``.

The SDK (1.4) runs that transformation on the GPU through OpenGL: it needs an X display (on a
headless machine Xvfb with Mesa's software OpenGL serves). Its transformation thread sometimes
returns without having written the output, which then holds whatever the memory held (with
Mesa's software OpenGL up to four in ten calls made straight after the previous one; none of
calls 50 ms apart). So each transformation carries a fresh token through the SDK's custom
channel (``depth_image_to_color_camera_custom``, nearest-neighbour) and is redone when a
measured pixel of the output does not carry it.

A recording (``.mkv`` as the Azure Kinect recorder ``k4arecorder`` writes it, or any k4a
recording with a colour track, a depth track and the device calibration) plays through
pyk4a's ``PyK4APlayback``. ``frames()`` reads it once from the start, as fast as the frames
are taken; ``publish_frames`` with realtime pacing (the command line's default for a
recording) sends them at the recorded rate.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.sources._base import FrameSource, SourceError, optional_import, refuse_device_options

log = logging.getLogger(__name__)

#: Azure Kinect depth images are in millimetres (k4a_image_format_t DEPTH16).
KINECT_DEPTH_SCALE = 1000.0

#: Colour resolutions of the Azure Kinect (k4a_color_resolution_t): name -> (width, height, pyk4a enum member).
COLOUR_RESOLUTIONS = {
    "720p": (1280, 720, "RES_720P"),
    "1080p": (1920, 1080, "RES_1080P"),
    "1440p": (2560, 1440, "RES_1440P"),
    "1536p": (2048, 1536, "RES_1536P"),
    "2160p": (3840, 2160, "RES_2160P"),
    "3072p": (4096, 3072, "RES_3072P"),
}
#: Depth modes that measure depth (not PASSIVE_IR), name -> pyk4a DepthMode member.
DEPTH_MODES = {"nfov_unbinned": "NFOV_UNBINNED", "nfov_2x2binned": "NFOV_2X2BINNED",
               "wfov_unbinned": "WFOV_UNBINNED", "wfov_2x2binned": "WFOV_2X2BINNED"}
#: Frame rates, Hz -> pyk4a FPS member.
FRAME_RATES = {5: "FPS_5", 15: "FPS_15", 30: "FPS_30"}
#: Colour formats this source turns into RGB (pyk4a ImageFormat member names).
COLOUR_FORMATS = ("COLOR_BGRA32", "COLOR_MJPG", "COLOR_NV12", "COLOR_YUY2")


def camera_info_from_kinect(calibration, k4a, width: int, height: int,
                            frame_id: str = "camera_color_optical_frame") -> CameraInfo:
    """CameraInfo of the colour camera from a pyk4a Calibration.

    K : ``get_camera_matrix(CalibrationType.COLOR)``, (3, 3), pixels
    D : ``get_distortion_coefficients(CalibrationType.COLOR)``, (8,) OpenCV rational model
    """
    K = np.asarray(calibration.get_camera_matrix(k4a.CalibrationType.COLOR), dtype=np.float64)
    D = np.asarray(calibration.get_distortion_coefficients(k4a.CalibrationType.COLOR), dtype=np.float64).ravel()
    return CameraInfo(width=width, height=height, K=K, D=D, frame_id=frame_id)


def rgb_from_kinect(colour: np.ndarray, colour_format: str, shape: tuple[int, int]) -> np.ndarray | None:
    """RGB image of a pyk4a colour image, or None if an MJPG image does not decode.

    colour : COLOR_BGRA32 (H, W, 4) uint8; COLOR_MJPG (n,) uint8, the JPEG file's bytes;
        COLOR_NV12 (3H/2, W, 1) uint8, the Y plane then interleaved U V at half resolution;
        COLOR_YUY2 (H, W, 2) uint8, Y U Y V
    colour_format : one of COLOUR_FORMATS
    shape : (H, W) of the colour camera
    returns (H, W, 3) uint8 RGB; raises SourceError for another shape or dtype, or another format
    """
    h, w = shape
    expected = {"COLOR_BGRA32": (h, w, 4), "COLOR_MJPG": "(n,)", "COLOR_NV12": (h * 3 // 2, w, 1),
                "COLOR_YUY2": (h, w, 2)}
    if colour_format not in expected:
        raise SourceError(f"Kinect: colour format {colour_format} is not supported; expected one of "
                          f"{', '.join(COLOUR_FORMATS)}")
    want = expected[colour_format]
    if colour.dtype != np.uint8 or (colour.ndim != 1 if colour_format == "COLOR_MJPG" else colour.shape != want):
        raise SourceError(f"Kinect: expected a {want} uint8 {colour_format} colour image, got {colour.shape} {colour.dtype}")
    if colour_format == "COLOR_BGRA32":
        return cv2.cvtColor(colour, cv2.COLOR_BGRA2RGB)
    if colour_format == "COLOR_NV12":
        return cv2.cvtColor(colour.reshape(h * 3 // 2, w), cv2.COLOR_YUV2RGB_NV12)
    if colour_format == "COLOR_YUY2":
        return cv2.cvtColor(colour, cv2.COLOR_YUV2RGB_YUY2)
    bgr = cv2.imdecode(colour, cv2.IMREAD_COLOR) if colour.size else None
    if bgr is None:
        return None
    if bgr.shape[:2] != shape:
        raise SourceError(f"Kinect: an MJPG colour image decodes to {bgr.shape[1]}x{bgr.shape[0]}, expected {w}x{h}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


class DepthToColour:
    """The SDK's transformation of depth images into the colour camera, checked to have run.

    k4a : the pyk4a module; calibration : the pyk4a Calibration of the device or recording
    ``to_colour(depth_mm)``: depth_mm (h, w) uint16 millimetres in the depth camera ->
    (H, W) uint16 millimetres in the colour camera, 0 = no measurement

    Each call carries a token the SDK copies to every measured pixel of a second output; an
    output without it was not written by this call (see the module docstring) and is redone,
    up to ATTEMPTS times. An output without any measurement is taken when the input has none,
    or when it comes twice in a row (the measured points are all outside the colour camera's
    view; an unwritten output may hold zeros too). ``redone`` counts the redone
    transformations. The SDK's thread takes requests under a lock the next call waits for, so
    an output it returned unwritten can still be written until the next call: the latest
    output stays referenced until then.
    """

    ATTEMPTS = 8

    def __init__(self, k4a, calibration):
        self._k4a, self._calibration = k4a, calibration
        self._token = 0
        self._latest = None
        self.redone = 0

    def __call__(self, depth_mm: np.ndarray) -> np.ndarray:
        k4a = self._k4a
        measured = bool(np.any(depth_mm))
        empty_before = False
        for _ in range(self.ATTEMPTS):
            self._token = self._token % 65535 + 1
            carrier = np.full(depth_mm.shape, self._token, np.uint16)
            try:
                out = k4a.depth_image_to_color_camera_custom(depth_mm, carrier, self._calibration, True)
            except k4a.K4AException as e:
                raise SourceError(_cannot_transform(e)) from None
            if out is None:
                raise SourceError(_cannot_transform(None))
            self._latest = out
            carried, depth_in_colour = out
            seen = depth_in_colour > 0
            if np.any(seen):
                if np.all(carried[seen] == self._token):
                    return depth_in_colour
                empty_before = False
            elif not measured or empty_before:
                return depth_in_colour
            else:
                empty_before = True
            self.redone += 1
            log.debug("Kinect: the SDK's depth transformation returned an unwritten output; redone")
        raise SourceError(f"Kinect: the SDK's depth transformation returned an unwritten output {self.ATTEMPTS} "
                          "times in a row")


def _cannot_transform(error) -> str:
    display = os.environ.get("DISPLAY")
    where = (f"the X display {display} has no OpenGL the SDK can use (see the SDK's log)" if display else
             "DISPLAY is not set: on a machine without a screen run under Xvfb, e.g. xvfb-run -a COMMAND")
    detail = f"; {error}" if error else ""
    return (f"Kinect: the SDK cannot transform depth into the colour camera (SDK 1.4 does it with OpenGL on an "
            f"X display; {where}{detail})")


def frame_from_kinect(capture, camera: CameraInfo, seq: int, to_colour: Callable[[np.ndarray], np.ndarray],
                      colour_format: str = "COLOR_BGRA32") -> RGBDFrame | None:
    """RGBDFrame from a pyk4a capture, or None if the capture lacks colour or depth, or its MJPG
    colour does not decode.

    capture.color : colour image in ``colour_format`` (see rgb_from_kinect);
    capture.depth : (h, w) uint16 mm in the depth camera; capture.color_timestamp_usec : device clock, microseconds
    to_colour : a DepthToColour (depth camera -> colour camera, uint16 mm)
    returns rgb (H, W, 3) uint8 RGB, depth_m (H, W) float32 metres in the colour camera,
    timestamp_s = the colour image's device timestamp in seconds
    """
    colour, depth_mm = capture.color, capture.depth
    if colour is None or depth_mm is None:
        return None
    shape = (camera.height, camera.width)
    rgb = rgb_from_kinect(colour, colour_format, shape)
    if rgb is None:
        log.warning("Kinect: a %d-byte MJPG colour image does not decode; its capture is skipped", colour.size)
        return None
    depth_in_colour = to_colour(depth_mm)
    if depth_in_colour.shape != shape or depth_in_colour.dtype != np.uint16:
        raise SourceError(f"Kinect: expected a {shape} uint16 depth image in the colour camera, got "
                          f"{depth_in_colour.shape} {depth_in_colour.dtype}")
    depth_m = depth_in_colour.astype(np.float32) / np.float32(KINECT_DEPTH_SCALE)
    return RGBDFrame(rgb=rgb, depth_m=depth_m, camera=camera, timestamp_s=capture.color_timestamp_usec / 1e6, seq=seq)


class KinectSource(FrameSource):
    """An Azure Kinect streaming synchronised colour and depth, or a recording of one.

    colour_resolution : a key of COLOUR_RESOLUTIONS, e.g. "720p" (1280 x 720)
    depth_mode : a key of DEPTH_MODES, e.g. "nfov_unbinned"
    fps : 5, 15 or 30 (the SDK refuses 30 with 3072p colour or WFOV unbinned depth)
    device_id : index of the device
    timeout_s : seconds to wait for a capture before giving up with SourceError
    recording : path of a k4a recording (``.mkv``) to play instead of a device; it has its own
        resolution, depth mode and rate, so the four options above must keep their defaults.
        ``frames()`` is then one pass over it from the start (a finite source) and ``name`` is
        ``kinect:FILE``

    Frames: seq counts the frames of a stream or pass from 0 (captures without colour or
    depth, such as a recording's first and last, are skipped), timestamp_s is the colour
    image's device time (as recorded, for a recording).
    """

    COLOUR_RESOLUTIONS = tuple(COLOUR_RESOLUTIONS)
    DEPTH_MODES = tuple(DEPTH_MODES)
    FRAME_RATES = tuple(FRAME_RATES)

    def __init__(self, colour_resolution: str = "720p", depth_mode: str = "nfov_unbinned", fps: int = 30,
                 device_id: int = 0, timeout_s: float = 5.0, recording: str | Path | None = None):
        for name, value, table in (("colour_resolution", colour_resolution, COLOUR_RESOLUTIONS),
                                   ("depth_mode", depth_mode, DEPTH_MODES), ("fps", fps, FRAME_RATES)):
            if value not in table:
                raise ValueError(f"KinectSource.{name}: expected one of {', '.join(map(str, table))}, got {value!r}")
        self.depth_scale = KINECT_DEPTH_SCALE
        self.timeout_ms = int(1000 * timeout_s)
        self._device = self._playback = None
        self._to_colour: DepthToColour | None = None
        self._started = False
        self._seq = 0
        if recording is not None:
            refuse_device_options(KinectSource, "colour resolution, depth mode, frame rate and device",
                                  dict(colour_resolution=colour_resolution, depth_mode=depth_mode, fps=fps,
                                       device_id=device_id), recording)
            self._open_recording(Path(recording))
            return
        k4a = optional_import("pyk4a", extra="kinect", feature="the Azure Kinect source")
        self._k4a = k4a
        self.name = f"kinect:{device_id}"
        self.colour_format = "COLOR_BGRA32"
        width, height, resolution = COLOUR_RESOLUTIONS[colour_resolution]
        config = k4a.Config(
            color_resolution=getattr(k4a.ColorResolution, resolution),
            color_format=getattr(k4a.ImageFormat, self.colour_format),
            depth_mode=getattr(k4a.DepthMode, DEPTH_MODES[depth_mode]),
            camera_fps=getattr(k4a.FPS, FRAME_RATES[fps]),
            synchronized_images_only=True,
        )
        self._device = k4a.PyK4A(config=config, device_id=device_id)
        try:
            self._device.start()
        except k4a.K4AException as e:
            raise SourceError(f"Kinect: cannot start device {device_id} with {colour_resolution} colour, "
                              f"{depth_mode} depth at {fps} fps ({e or type(e).__name__})") from None
        self._started = True
        try:
            calibration = self._device.calibration
            self.camera = camera_info_from_kinect(calibration, k4a, width, height)
        except BaseException:
            self.close()
            raise
        self._to_colour = DepthToColour(k4a, calibration)
        log.info("Kinect: %s colour, %s depth, %d fps, fx %.1f", colour_resolution, depth_mode, fps, self.camera.fx)

    def _open_recording(self, path: Path) -> None:
        if not path.exists():
            raise SourceError(f"Kinect: recording {path} not found")
        if not path.is_file():
            raise SourceError(f"Kinect: recording {path} is not a file")
        k4a = optional_import("pyk4a", extra="kinect", feature="the Azure Kinect source")
        self._k4a = k4a
        self.name = f"kinect:{path.name}"
        self.recording = path
        playback = k4a.PyK4APlayback(path)
        try:
            playback.open()
        except k4a.K4AException:
            raise SourceError(f"Kinect: {path} is not an Azure Kinect recording (the SDK cannot open it)") from None
        self._playback = playback
        try:
            self._describe_recording(k4a, playback, path)
        except BaseException:
            self.close()
            raise

    def _describe_recording(self, k4a, playback, path: Path) -> None:
        """Check the recording's tracks and calibration, set camera and colour_format, and
        transform its first depth image, so that a recording that cannot play fails here."""
        config = playback.configuration
        missing = [name for name, key in (("colour", "color_track_enabled"), ("depth", "depth_track_enabled"))
                   if not config[key]]
        if missing:
            raise SourceError(f"Kinect: {path} has no {' and no '.join(missing)} track")
        self.colour_format = config["color_format"].name
        if self.colour_format not in COLOUR_FORMATS:
            raise SourceError(f"Kinect: {path} holds {self.colour_format} colour; expected one of {', '.join(COLOUR_FORMATS)}")
        size = {getattr(k4a.ColorResolution, member): (w, h) for w, h, member in COLOUR_RESOLUTIONS.values()}
        width, height = size[config["color_resolution"]]
        try:
            calibration = playback.calibration
        except k4a.K4AException:
            raise SourceError(f"Kinect: {path} holds no device calibration (its calibration.json attachment)") from None
        self.camera = camera_info_from_kinect(calibration, k4a, width, height)
        self._to_colour = DepthToColour(k4a, calibration)
        for capture in self._captures(playback, path):
            if capture.depth is not None:
                self._to_colour(capture.depth)
                break
        else:
            raise SourceError(f"Kinect: {path} holds no depth image")
        log.info("Kinect recording %s: %s colour %dx%d, %s depth, %.1f s, fx %.1f", path,
                 self.colour_format.removeprefix("COLOR_"), width, height, config["depth_mode"].name,
                 playback.length / 1e6, self.camera.fx)

    def _captures(self, playback, path: Path) -> Iterator:
        """The recording's captures from its start."""
        playback.seek(0)
        count = 0
        while True:
            try:
                capture = playback.get_next_capture()
            except EOFError:
                return
            except self._k4a.K4AException:
                raise SourceError(f"Kinect: cannot read {path} after {count} captures") from None
            count += 1
            yield capture

    def frames(self) -> Iterator[RGBDFrame]:
        if self._playback is not None:
            yield from self._recorded_frames()
            return
        k4a = self._k4a
        while True:
            try:
                capture = self._device.get_capture(timeout=self.timeout_ms)
            except k4a.K4ATimeoutException:
                raise SourceError(f"Kinect: no capture within {self.timeout_ms} ms") from None
            except k4a.K4AException as e:  # the device failed or was unplugged mid-stream
                raise SourceError(f"Kinect: the device stopped delivering captures ({e})") from None
            frame = frame_from_kinect(capture, self.camera, self._seq, self._to_colour, self.colour_format)
            if frame is None:
                log.debug("Kinect: capture without colour or depth skipped")
                continue
            self._seq += 1
            yield frame

    def _recorded_frames(self) -> Iterator[RGBDFrame]:
        """One pass over the recording, from its start."""
        seq = skipped = 0
        for capture in self._captures(self._playback, self.recording):
            frame = frame_from_kinect(capture, self.camera, seq, self._to_colour, self.colour_format)
            if frame is None:
                skipped += 1
                continue
            seq += 1
            yield frame
        if skipped:
            log.info("Kinect recording %s: %d frames; skipped %d of %d captures (without colour, without depth, or "
                     "with colour that does not decode)", self.recording.name, seq, skipped, seq + skipped)

    @property
    def transformations_redone(self) -> int:
        """Depth transformations the SDK returned unwritten, and this source redid."""
        return self._to_colour.redone if self._to_colour is not None else 0

    def close(self) -> None:
        if self._started:  # stopping a stopped device raises
            self._started = False
            self._device.stop()
        if self._playback is not None:
            playback, self._playback = self._playback, None
            playback.close()
