"""Frames from a Microsoft Azure Kinect (or Orbbec Femto in K4A mode) through pyk4a (extra "kinect").

Colour is captured as BGRA32 and turned into RGB; depth is transformed into the colour
camera by the SDK (``capture.transformed_depth``: uint16 millimetres, 0 = no measurement),
so both images share the colour camera's calibration, which becomes the CameraInfo:
``calibration.get_camera_matrix(CalibrationType.COLOR)`` and the eight OpenCV rational
coefficients k1 k2 p1 p2 k3 k4 k5 k6 of ``get_distortion_coefficients(CalibrationType.COLOR)``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.sources._base import FrameSource, SourceError, optional_import

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


def camera_info_from_kinect(calibration, k4a, width: int, height: int,
                            frame_id: str = "camera_color_optical_frame") -> CameraInfo:
    """CameraInfo of the colour camera from a pyk4a Calibration.

    K : ``get_camera_matrix(CalibrationType.COLOR)``, (3, 3), pixels
    D : ``get_distortion_coefficients(CalibrationType.COLOR)``, (8,) OpenCV rational model
    """
    K = np.asarray(calibration.get_camera_matrix(k4a.CalibrationType.COLOR), dtype=np.float64)
    D = np.asarray(calibration.get_distortion_coefficients(k4a.CalibrationType.COLOR), dtype=np.float64).ravel()
    return CameraInfo(width=width, height=height, K=K, D=D, frame_id=frame_id)


def frame_from_kinect(capture, camera: CameraInfo, seq: int) -> RGBDFrame | None:
    """RGBDFrame from a pyk4a capture, or None if the capture lacks colour or depth.

    capture.color : (H, W, 4) uint8 BGRA; capture.transformed_depth : (H, W) uint16 mm in
    the colour camera; capture.color_timestamp_usec : device clock, microseconds
    returns rgb (H, W, 3) uint8 RGB, depth_m (H, W) float32 metres, timestamp_s in seconds
    """
    colour = capture.color
    depth_mm = capture.transformed_depth
    if colour is None or depth_mm is None:
        return None
    shape = (camera.height, camera.width)
    if colour.shape != shape + (4,) or colour.dtype != np.uint8:
        raise SourceError(f"Kinect: expected a {shape + (4,)} uint8 BGRA colour image, got {colour.shape} {colour.dtype}")
    if depth_mm.shape != shape or depth_mm.dtype != np.uint16:
        raise SourceError(f"Kinect: expected a {shape} uint16 depth image in the colour camera, got "
                          f"{depth_mm.shape} {depth_mm.dtype}")
    rgb = cv2.cvtColor(colour, cv2.COLOR_BGRA2RGB)
    depth_m = depth_mm.astype(np.float32) / np.float32(KINECT_DEPTH_SCALE)
    return RGBDFrame(rgb=rgb, depth_m=depth_m, camera=camera, timestamp_s=capture.color_timestamp_usec / 1e6, seq=seq)


class KinectSource(FrameSource):
    """An Azure Kinect streaming synchronised colour and depth.

    colour_resolution : a key of COLOUR_RESOLUTIONS, e.g. "720p" (1280 x 720)
    depth_mode : a key of DEPTH_MODES, e.g. "nfov_unbinned"
    fps : 5, 15 or 30 (the SDK refuses 30 with 3072p colour or WFOV unbinned depth)
    device_id : index of the device
    timeout_s : seconds to wait for a capture before giving up with SourceError

    Frames: seq counts captures from 0, timestamp_s is the colour image's device time.
    """

    COLOUR_RESOLUTIONS = tuple(COLOUR_RESOLUTIONS)
    DEPTH_MODES = tuple(DEPTH_MODES)
    FRAME_RATES = tuple(FRAME_RATES)

    def __init__(self, colour_resolution: str = "720p", depth_mode: str = "nfov_unbinned", fps: int = 30,
                 device_id: int = 0, timeout_s: float = 5.0):
        for name, value, table in (("colour_resolution", colour_resolution, COLOUR_RESOLUTIONS),
                                   ("depth_mode", depth_mode, DEPTH_MODES), ("fps", fps, FRAME_RATES)):
            if value not in table:
                raise ValueError(f"KinectSource.{name}: expected one of {', '.join(map(str, table))}, got {value!r}")
        k4a = optional_import("pyk4a", extra="kinect", feature="the Azure Kinect source")
        self._k4a = k4a
        self.name = f"kinect:{device_id}"
        self.depth_scale = KINECT_DEPTH_SCALE
        self.timeout_ms = int(1000 * timeout_s)
        width, height, resolution = COLOUR_RESOLUTIONS[colour_resolution]
        config = k4a.Config(
            color_resolution=getattr(k4a.ColorResolution, resolution),
            color_format=k4a.ImageFormat.COLOR_BGRA32,
            depth_mode=getattr(k4a.DepthMode, DEPTH_MODES[depth_mode]),
            camera_fps=getattr(k4a.FPS, FRAME_RATES[fps]),
            synchronized_images_only=True,
        )
        self._device = k4a.PyK4A(config=config, device_id=device_id)
        self._started = False
        try:
            self._device.start()
        except k4a.K4AException as e:
            raise SourceError(f"Kinect: cannot start device {device_id} with {colour_resolution} colour, "
                              f"{depth_mode} depth at {fps} fps ({e or type(e).__name__})") from None
        self._started = True
        try:
            self.camera = camera_info_from_kinect(self._device.calibration, k4a, width, height)
        except BaseException:
            self.close()
            raise
        self._seq = 0
        log.info("Kinect: %s colour, %s depth, %d fps, fx %.1f", colour_resolution, depth_mode, fps, self.camera.fx)

    def frames(self) -> Iterator[RGBDFrame]:
        k4a = self._k4a
        while True:
            try:
                capture = self._device.get_capture(timeout=self.timeout_ms)
            except k4a.K4ATimeoutException:
                raise SourceError(f"Kinect: no capture within {self.timeout_ms} ms") from None
            frame = frame_from_kinect(capture, self.camera, self._seq)
            if frame is None:
                log.debug("Kinect: capture without colour or depth skipped")
                continue
            self._seq += 1
            yield frame

    def close(self) -> None:
        if self._started:  # stopping a stopped device raises
            self._started = False
            self._device.stop()
