"""Azure Kinect recordings (.mkv) written from arrays through the SDK's own recorder: test tooling.

pyk4a cannot make a capture from arrays, so this module calls the native libraries that
pyk4a loads (libk4a for images and captures, libk4arecord for the file) with ctypes, in
the order the SDK's recorder expects: ``k4a_record_create`` (without a device, as for
user-generated data), an attachment ``calibration.json`` holding the raw calibration
(the recorder tags it ``K4A_CALIBRATION_FILE`` with the attachment as the tag's target, which
``k4a_record_add_tag`` cannot express; playback finds it by its name when no tag points to it),
``k4a_record_write_header``, one ``k4a_record_write_capture`` per frame, flush, close.

``raw_calibration`` writes the calibration blob a device stores (the JSON that
``k4a_device_get_raw_calibration`` returns) from pinhole intrinsics in pixels of the
recorded modes, so that the SDK's mode-specific calibration gives back exactly those.

Runs wherever ``import pyk4a`` works with its native libraries (pyk4a-bundle ships them;
it imports only beside NumPy 1): ``python -m tests.k4a_writer SPEC.json`` writes the
recording SPEC describes (see ``main``).
"""

from __future__ import annotations

import ctypes
import glob
import json
import os
import sys
from dataclasses import dataclass

import numpy as np

# k4a_image_format_t, k4a_color_resolution_t, k4a_depth_mode_t, k4a_fps_t (k4atypes.h).
IMAGE_FORMATS = {"MJPG": 0, "NV12": 1, "YUY2": 2, "BGRA32": 3, "DEPTH16": 4}
COLOUR_RESOLUTIONS = {"OFF": 0, "720P": 1, "1080P": 2, "1440P": 3, "1536P": 4, "2160P": 5, "3072P": 6}
DEPTH_MODES = {"OFF": 0, "NFOV_2X2BINNED": 1, "NFOV_UNBINNED": 2, "WFOV_2X2BINNED": 3, "WFOV_UNBINNED": 4}
FPS = {5: 0, 15: 1, 30: 2}

# How the SDK derives a mode's intrinsics from the raw ones (normalised by the sensor's size,
# origin at the top left corner of the top left pixel): scale to the binned sensor, subtract
# the crop offset, and move the origin to the centre of the top left pixel (-0.5).
# mode -> (output width, height), (binned sensor width, height), (crop x, y), in pixels.
COLOUR_MODE_GEOMETRY = {
    "720P": ((1280, 720), (1280, 960), (0, 120)),
    "1080P": ((1920, 1080), (1920, 1440), (0, 180)),
    "1440P": ((2560, 1440), (2560, 1920), (0, 240)),
    "1536P": ((2048, 1536), (2048, 1536), (0, 0)),
    "2160P": ((3840, 2160), (3840, 2880), (0, 360)),
    "3072P": ((4096, 3072), (4096, 3072), (0, 0)),
}
DEPTH_MODE_GEOMETRY = {
    "NFOV_2X2BINNED": ((320, 288), (512, 512), (96, 90)),
    "NFOV_UNBINNED": ((640, 576), (1024, 1024), (192, 180)),
    "WFOV_2X2BINNED": ((512, 512), (512, 512), (0, 0)),
    "WFOV_UNBINNED": ((1024, 1024), (1024, 1024), (0, 0)),
}
COLOUR_SENSOR = (4096, 3072)
DEPTH_SENSOR = (1024, 1024)


@dataclass(frozen=True)
class Lens:
    """A camera of the recording in the pixels of its recorded mode.

    fx, fy, cx, cy : pixels, OpenCV convention (origin at the centre of the top left pixel)
    distortion : (8,) OpenCV rational coefficients k1 k2 p1 p2 k3 k4 k5 k6
    """

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple = (0.0,) * 8


def _raw_camera(lens: Lens, geometry, sensor, location: str, purpose: str, R, t_m) -> dict:
    _, (binned_w, binned_h), (crop_x, crop_y) = geometry
    k1, k2, p1, p2, k3, k4, k5, k6 = (float(c) for c in lens.distortion)
    # The blob's parameter order: cx cy fx fy k1..k6 codx cody p2 p1 (normalised by the binned sensor size).
    params = [(lens.cx + 0.5 + crop_x) / binned_w, (lens.cy + 0.5 + crop_y) / binned_h, lens.fx / binned_w,
              lens.fy / binned_h, k1, k2, k3, k4, k5, k6, 0.0, 0.0, p2, p1]
    return {"Intrinsics": {"ModelParameterCount": len(params), "ModelParameters": params,
                           "ModelType": "CALIBRATION_LensDistortionModelBrownConrady"},
            "Location": location, "Purpose": purpose, "MetricRadius": 1.7,
            "Rt": {"Rotation": [float(r) for r in np.ravel(R)], "Translation": [float(x) for x in t_m]},
            "SensorWidth": sensor[0], "SensorHeight": sensor[1], "Shutter": "CALIBRATION_ShutterTypeUndefined",
            "ThermalAdjustmentParams": {"Params": [0.0] * 12}}


def _raw_imu(sensor_type: str) -> dict:
    return {"BiasTemperatureModel": [0.0] * 12, "BiasUncertainty": [0.0] * 3,
            "Id": "CALIBRATION_InertialSensorId_LSM6DSM",
            "MixingMatrixTemperatureModel": [v for d in np.eye(3).ravel() for v in (float(d), 0.0, 0.0, 0.0)],
            "ModelTypeMask": 16, "Noise": [0.0] * 6,
            "Rt": {"Rotation": [float(r) for r in np.eye(3).ravel()], "Translation": [0.0, 0.0, 0.0]},
            "SecondOrderScaling": [0.0] * 9, "SensorType": sensor_type, "TemperatureBounds": [5.0, 60.0],
            "TemperatureC": 0.0}


def raw_calibration(colour: Lens, colour_resolution: str, depth: Lens, depth_mode: str,
                    R_colour_depth=None, t_colour_depth_m=(0.0, 0.0, 0.0)) -> str:
    """The raw calibration JSON of a device whose cameras have these intrinsics in these modes.

    R_colour_depth : (3, 3) rotation (None: identity), t_colour_depth_m : (3,) metres: a point p in the depth
        camera's frame is R p + t in the colour camera's (the blob stores each camera's pose
        from the depth camera this way)
    returns the JSON text; the SDK turns it back into ``colour`` for ``colour_resolution`` and
    ``depth`` for ``depth_mode``
    """
    cameras = [
        _raw_camera(depth, DEPTH_MODE_GEOMETRY[depth_mode], DEPTH_SENSOR, "CALIBRATION_CameraLocationD0",
                    "CALIBRATION_CameraPurposeDepth", np.eye(3), (0.0, 0.0, 0.0)),
        _raw_camera(colour, COLOUR_MODE_GEOMETRY[colour_resolution], COLOUR_SENSOR, "CALIBRATION_CameraLocationPV0",
                    "CALIBRATION_CameraPurposePhotoVideo", np.eye(3) if R_colour_depth is None else R_colour_depth,
                    t_colour_depth_m),
    ]
    imus = [_raw_imu("CALIBRATION_InertialSensorType_Gyro"), _raw_imu("CALIBRATION_InertialSensorType_Accelerometer")]
    return json.dumps({"CalibrationInformation": {
        "Cameras": cameras, "InertialSensors": imus,
        "Metadata": {"SerialId": "000000000000", "FactoryCalDate": "1/1/2024 12:00:00 AM GMT",
                     "Version": {"Major": 1, "Minor": 2}, "DeviceName": "AzureKinect-PV", "Notes": "clothkit test"}}})


class DeviceConfiguration(ctypes.Structure):
    """k4a_device_configuration_t of SDK 1.4."""

    _fields_ = [("color_format", ctypes.c_int), ("color_resolution", ctypes.c_int), ("depth_mode", ctypes.c_int),
                ("camera_fps", ctypes.c_int), ("synchronized_images_only", ctypes.c_bool),
                ("depth_delay_off_color_usec", ctypes.c_int32), ("wired_sync_mode", ctypes.c_int),
                ("subordinate_delay_off_master_usec", ctypes.c_uint32), ("disable_streaming_indicator", ctypes.c_bool)]


def _libraries():
    """libk4a and libk4arecord as pyk4a loaded them (its extension links both)."""
    import pyk4a  # loads libk4a, on which libk4arecord depends without saying where it is

    site = os.path.dirname(os.path.dirname(os.path.abspath(pyk4a.__file__)))
    names = {}
    for stem in ("libk4a", "libk4arecord"):
        found = sorted(glob.glob(os.path.join(site, "pyk4a_bundle.libs", f"{stem}-*.so*")))
        names[stem] = found[0] if found else f"{stem}.so.1.4"  # an installed SDK: the loader's search path
    k4a, record = ctypes.CDLL(names["libk4a"]), ctypes.CDLL(names["libk4arecord"])
    handle = ctypes.c_void_p
    k4a.k4a_capture_create.argtypes = [ctypes.POINTER(handle)]
    k4a.k4a_capture_release.argtypes = [handle]
    k4a.k4a_capture_set_color_image.argtypes = [handle, handle]
    k4a.k4a_capture_set_depth_image.argtypes = [handle, handle]
    k4a.k4a_image_create_from_buffer.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                                 ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p,
                                                 ctypes.POINTER(handle)]
    k4a.k4a_image_release.argtypes = [handle]
    k4a.k4a_image_set_device_timestamp_usec.argtypes = [handle, ctypes.c_uint64]
    record.k4a_record_create.argtypes = [ctypes.c_char_p, handle, DeviceConfiguration, ctypes.POINTER(handle)]
    record.k4a_record_add_attachment.argtypes = [handle, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_size_t]
    record.k4a_record_write_header.argtypes = [handle]
    record.k4a_record_write_capture.argtypes = [handle, handle]
    record.k4a_record_flush.argtypes = [handle]
    record.k4a_record_close.argtypes = [handle]
    record.k4a_record_close.restype = None
    return k4a, record


def _check(result: int, what: str) -> None:
    if result != 0:  # K4A_RESULT_SUCCEEDED
        raise RuntimeError(f"{what} failed")


def encode_colour(rgb: np.ndarray, colour_format: str) -> tuple[bytes, int]:
    """An (H, W, 3) uint8 RGB image in a Kinect colour format: (bytes, stride in bytes; 0 for MJPG)."""
    import cv2

    h, w = rgb.shape[:2]
    if colour_format == "BGRA32":
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGRA).tobytes(), 4 * w
    if colour_format == "MJPG":
        ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
        _check(0 if ok else 1, "JPEG encoding")
        return jpeg.tobytes(), 0
    if colour_format == "NV12":  # the Y plane, then U and V interleaved at half resolution
        i420 = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420).ravel()
        y, u, v = i420[:h * w], i420[h * w:h * w * 5 // 4], i420[h * w * 5 // 4:]
        return np.concatenate([y, np.stack([u, v], axis=1).ravel()]).tobytes(), w
    if colour_format == "YUY2":
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_YUY2).tobytes(), 2 * w
    raise ValueError(f"unknown colour format {colour_format!r}")


def write_recording(path: str, calibration_json: str | None, colour_format: str, colour_resolution: str,
                    depth_mode: str, fps: int, frames) -> None:
    """Write a recording through libk4arecord.

    calibration_json : the raw calibration attached as ``calibration.json``, or None for none
    colour_format : a key of IMAGE_FORMATS (colour); colour_resolution "OFF" or a key of
        COLOUR_RESOLUTIONS; depth_mode "OFF" or a key of DEPTH_MODES; fps 5, 15 or 30
    frames : iterable of (rgb (H, W, 3) uint8 or None, depth (h, w) uint16 millimetres or None,
        device timestamp in microseconds), H, W and h, w those of the modes
    """
    k4a, record = _libraries()
    config = DeviceConfiguration(color_format=IMAGE_FORMATS[colour_format],
                                 color_resolution=COLOUR_RESOLUTIONS[colour_resolution],
                                 depth_mode=DEPTH_MODES[depth_mode], camera_fps=FPS[fps], synchronized_images_only=True)
    recording = ctypes.c_void_p()
    _check(record.k4a_record_create(path.encode(), None, config, ctypes.byref(recording)), f"k4a_record_create({path})")
    try:
        if calibration_json is not None:
            blob = calibration_json.encode()
            _check(record.k4a_record_add_attachment(recording, b"calibration.json", blob, len(blob)),
                   "k4a_record_add_attachment")
        _check(record.k4a_record_write_header(recording), "k4a_record_write_header")
        for rgb, depth_mm, timestamp_us in frames:
            capture = ctypes.c_void_p()
            _check(k4a.k4a_capture_create(ctypes.byref(capture)), "k4a_capture_create")
            keep = []  # the buffers the images point into, alive until the capture is written (the recorder copies)
            try:
                images = []
                if rgb is not None:
                    data, stride = encode_colour(np.ascontiguousarray(rgb, np.uint8), colour_format)
                    images.append((k4a.k4a_capture_set_color_image, IMAGE_FORMATS[colour_format], rgb.shape[1],
                                   rgb.shape[0], stride, data))
                if depth_mm is not None:
                    depth_mm = np.ascontiguousarray(depth_mm, np.uint16)
                    images.append((k4a.k4a_capture_set_depth_image, IMAGE_FORMATS["DEPTH16"], depth_mm.shape[1],
                                   depth_mm.shape[0], 2 * depth_mm.shape[1], depth_mm.tobytes()))
                for attach, fmt, w, h, stride, data in images:
                    buffer = ctypes.create_string_buffer(data, len(data))
                    keep.append(buffer)
                    image = ctypes.c_void_p()
                    _check(k4a.k4a_image_create_from_buffer(fmt, w, h, stride, buffer, len(data), None, None,
                                                            ctypes.byref(image)), "k4a_image_create_from_buffer")
                    k4a.k4a_image_set_device_timestamp_usec(image, int(timestamp_us))
                    attach(capture, image)  # the capture takes its own reference
                    k4a.k4a_image_release(image)
                _check(record.k4a_record_write_capture(recording, capture), "k4a_record_write_capture")
            finally:
                k4a.k4a_capture_release(capture)
        _check(record.k4a_record_flush(recording), "k4a_record_flush")
    finally:
        record.k4a_record_close(recording)


def main(argv=None) -> int:
    """``python -m tests.k4a_writer SPEC.json``; SPEC holds ``path``, ``colour_format``,
    ``colour_resolution``, ``depth_mode``, ``fps``, ``calibration`` (the JSON text, or null)
    and ``frames``: the name of an .npz with ``timestamps_us`` (N,) int and, each optional,
    ``rgb`` (N, H, W, 3) uint8 and ``depth_mm`` (N, h, w) uint16, with ``has_rgb`` and
    ``has_depth`` (N,) bool to leave an image out of a capture."""
    with open((argv or sys.argv[1:])[0]) as f:
        spec = json.load(f)
    with np.load(spec["frames"]) as data:
        n = len(data["timestamps_us"])
        images = []
        for key, mask in (("rgb", "has_rgb"), ("depth_mm", "has_depth")):
            present = data[mask] if mask in data.files else np.ones(n, bool)
            images.append([a if keep else None for a, keep in zip(data[key], present)] if key in data.files else [None] * n)
        frames = list(zip(*images, data["timestamps_us"].tolist()))
    write_recording(spec["path"], spec["calibration"], spec["colour_format"], spec["colour_resolution"],
                    spec["depth_mode"], spec["fps"], frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
