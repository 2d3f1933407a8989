"""Frames from an Intel RealSense camera through pyrealsense2 (extra "realsense").

The depth stream is aligned to the colour stream with ``rs.align(rs.stream.color)``, so
both images share the colour camera's intrinsics, which become the frames' CameraInfo
(with the colour lens distortion). Depth units come from the device's depth sensor
(``get_depth_scale()``: metres per unit, 0.001 on most D400 cameras), never assumed.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.sources._base import FrameSource, SourceError, optional_import

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


def frame_from_realsense(colour_frame, depth_frame, camera: CameraInfo, depth_unit_m: float, rs) -> RGBDFrame:
    """RGBDFrame from an aligned pair of pyrealsense2 frames.

    colour_frame : video frame, format rgb8 or bgr8, (H, W, 3) uint8 data
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
    if colour.shape != shape + (3,) or colour.dtype != np.uint8:
        raise SourceError(f"RealSense: expected a {shape + (3,)} uint8 colour image, got {colour.shape} {colour.dtype}")
    if raw.shape != shape or raw.dtype != np.uint16:
        raise SourceError(f"RealSense: expected a {shape} uint16 depth image aligned to colour, got {raw.shape} {raw.dtype}")
    # The SDK owns the frame buffers and recycles them: copy out before the frame is released.
    if fmt == rs.format.rgb8:
        rgb = np.array(colour, dtype=np.uint8, copy=True)
    elif fmt == rs.format.bgr8:
        rgb = np.ascontiguousarray(colour[:, :, ::-1])
    else:
        raise SourceError(f"RealSense: colour format {fmt} is not supported; expected rgb8 or bgr8")
    depth_m = raw.astype(np.float32) * np.float32(depth_unit_m)
    return RGBDFrame(rgb=rgb, depth_m=depth_m, camera=camera, timestamp_s=colour_frame.get_timestamp() / 1000.0,
                     seq=int(colour_frame.get_frame_number()))


class RealSenseSource(FrameSource):
    """A RealSense camera streaming colour (rgb8) and depth (z16) at one size and rate.

    width, height : pixels of both streams (the depth image is aligned to colour anyway)
    fps : frames per second the device is asked for
    serial : device serial number, or None for the first camera found
    timeout_s : seconds to wait for a frame before giving up with SourceError

    ``depth_scale`` (units per metre on the wire) is 1 / the device's depth unit, so the
    raw depth values travel unchanged.
    """

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, serial: str | None = None,
                 timeout_s: float = 5.0):
        rs = optional_import("pyrealsense2", extra="realsense", feature="the RealSense source")
        self._rs = rs
        self.name = "realsense" if serial is None else f"realsense:{serial}"
        self.timeout_ms = int(1000 * timeout_s)
        config = rs.config()
        if serial is not None:
            config.enable_device(serial)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        self._pipeline = rs.pipeline()
        self._streaming = False
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as e:
            raise SourceError(f"RealSense: cannot stream colour and depth at {width}x{height}, {fps} fps ({e})") from None
        self._streaming = True
        try:
            self.depth_unit_m = float(profile.get_device().first_depth_sensor().get_depth_scale())
            if not self.depth_unit_m > 0:
                raise SourceError(f"RealSense: the depth sensor reports a depth scale of {self.depth_unit_m} m per unit")
            intrinsics = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
            self.camera = camera_info_from_realsense(intrinsics, rs)
        except BaseException:
            self.close()
            raise
        self.depth_scale = 1.0 / self.depth_unit_m
        self._align = rs.align(rs.stream.color)
        log.info("RealSense: %dx%d at %d fps, depth unit %.6g m, fx %.1f", width, height, fps, self.depth_unit_m,
                 self.camera.fx)

    def frames(self) -> Iterator[RGBDFrame]:
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

    def close(self) -> None:
        if self._streaming:  # stop() on a stopped pipeline raises
            self._streaming = False
            self._pipeline.stop()
