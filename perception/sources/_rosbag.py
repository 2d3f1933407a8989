"""Frames from a ROS 1 or ROS 2 bag through the pure-Python ``rosbags`` library (extra "rosbag").

Reads a colour topic (``sensor_msgs/Image``, or ``sensor_msgs/CompressedImage`` in JPEG or
PNG, as camera drivers often record colour), a ``sensor_msgs/Image`` depth topic and one
``sensor_msgs/CameraInfo`` topic. The depth topic must be registered to colour (e.g.
RealSense's ``/camera/aligned_depth_to_color/image_raw``): same size, same intrinsics.

Encodings: colour ``rgb8`` or ``bgr8``; depth ``16UC1`` (millimetres, REP 118's
convention for integer depth; 0 = no measurement) or ``32FC1`` (metres; NaN or 0 = no
measurement). Colour and depth are paired by their header stamps, nearest first within
0.02 s, as the sequence folder's rule (``perception.sequence.associate``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.sequence import associate
from perception.sources._base import FrameSource, SourceError, optional_import

log = logging.getLogger(__name__)

#: uint16 depth encodings are millimetres (REP 118).
MILLIMETRES_PER_METRE = 1000.0
COLOUR_ENCODINGS = ("rgb8", "bgr8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
#: Message types each topic may carry (rosbags names them so for ROS 1 and ROS 2 bags alike).
IMAGE, COMPRESSED_IMAGE, CAMERA_INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"
TOPIC_TYPES = {"rgb": (IMAGE, COMPRESSED_IMAGE), "depth": (IMAGE,), "info": (CAMERA_INFO,)}


def _stamp_s(msg) -> float:
    stamp = msg.header.stamp
    return stamp.sec + 1e-9 * stamp.nanosec


def _field(msg, ros2: str, ros1: str):
    """A field under its ROS 2 name (``k``) or, in ROS 1 messages, its ROS 1 name (``K``)."""
    return getattr(msg, ros2) if hasattr(msg, ros2) else getattr(msg, ros1)


def _pixels(msg, channels: int, dtype: np.dtype) -> np.ndarray:
    """(height, width[, channels]) array of an Image's data, honouring ``step`` and byte order."""
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * channels * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.step < row_bytes or data.size < msg.step * msg.height:
        raise SourceError(f"rosbag: {msg.encoding} image {msg.width}x{msg.height} has step {msg.step} and "
                          f"{data.size} bytes; expected step >= {row_bytes} and {msg.step * msg.height} bytes")
    rows = data[: msg.step * msg.height].reshape(msg.height, msg.step)[:, :row_bytes]
    pixels = np.ascontiguousarray(rows).view(dtype).astype(dtype.newbyteorder("="))
    return pixels.reshape((msg.height, msg.width, channels) if channels > 1 else (msg.height, msg.width))


def rgb_from_image(msg) -> np.ndarray:
    """(H, W, 3) uint8 RGB from a sensor_msgs/Image in rgb8 or bgr8."""
    if msg.encoding not in COLOUR_ENCODINGS:
        raise SourceError(f"rosbag: colour encoding {msg.encoding!r} is not supported; expected one of {COLOUR_ENCODINGS}")
    rgb = _pixels(msg, 3, np.uint8)
    return np.ascontiguousarray(rgb[:, :, ::-1]) if msg.encoding == "bgr8" else rgb


def rgb_from_compressed(msg) -> np.ndarray | None:
    """(H, W, 3) uint8 RGB from a sensor_msgs/CompressedImage (JPEG or PNG colour); None when
    its data does not decode."""
    bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
    return None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def depth_from_image(msg) -> np.ndarray:
    """(H, W) float32 metres from a sensor_msgs/Image in 16UC1 / mono16 (mm) or 32FC1 (m)."""
    if msg.encoding in ("16UC1", "mono16"):
        return _pixels(msg, 1, np.uint16).astype(np.float32) / np.float32(MILLIMETRES_PER_METRE)
    if msg.encoding == "32FC1":
        depth = _pixels(msg, 1, np.float32)
        # RGBDFrame refuses negative and infinite depth; both mean "no measurement" here.
        return np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(0)).astype(np.float32)
    raise SourceError(f"rosbag: depth encoding {msg.encoding!r} is not supported; expected one of {DEPTH_ENCODINGS}")


def camera_info_from_ros(msg) -> CameraInfo:
    """CameraInfo from a sensor_msgs/CameraInfo (ROS 1 ``K``/``D`` or ROS 2 ``k``/``d`` fields).

    Distortion models ``plumb_bob`` (5 coefficients) and ``rational_polynomial`` (8) are
    OpenCV's and kept; no coefficients or all zeros give no D; others raise SourceError.
    """
    K = np.asarray(_field(msg, "k", "K"), dtype=np.float64).reshape(3, 3)
    D = np.asarray(_field(msg, "d", "D"), dtype=np.float64).ravel()
    if not np.any(D):
        D = np.zeros(0)
    elif msg.distortion_model not in ("plumb_bob", "rational_polynomial"):
        raise SourceError(f"rosbag: camera distortion model {msg.distortion_model!r} is not supported; "
                          "expected plumb_bob or rational_polynomial")
    frame_id = msg.header.frame_id or "camera_color_optical_frame"
    try:
        return CameraInfo(width=int(msg.width), height=int(msg.height), K=K, D=D, frame_id=frame_id)
    except ValueError as e:
        raise SourceError(f"rosbag: unusable CameraInfo ({e})") from None


class RosbagSource(FrameSource):
    """Plays colour and depth images of a bag (a ROS 1 ``.bag`` file or a ROS 2 bag folder).

    path : the bag
    rgb_topic : sensor_msgs/Image or sensor_msgs/CompressedImage colour topic
    depth_topic : sensor_msgs/Image depth topic, registered to colour
    info_topic : sensor_msgs/CameraInfo topic of the colour camera (its first message is used)

    Frames: seq = index of the pair, timestamp_s = colour header stamp. ``depth_scale`` is
    1000 (millimetres) when the depth topic is 16UC1, None (float32 metres) for 32FC1.
    The bag is read twice per pass: once for the stamps (to pair images), once for pixels.
    A compressed colour image that does not decode drops its frame, with a warning, and is
    counted in ``skipped``.
    """

    def __init__(self, path: str | Path, rgb_topic: str, depth_topic: str, info_topic: str):
        self._highlevel = optional_import("rosbags.highlevel", extra="rosbag", feature="the ROS bag source")
        self._typesys = optional_import("rosbags.typesys", extra="rosbag", feature="the ROS bag source")
        self.path = Path(path)
        if rgb_topic == depth_topic:
            raise SourceError(f"rosbag: colour and depth topics must differ, got {rgb_topic!r} for both")
        if not self.path.exists():
            raise SourceError(f"rosbag {self.path}: no such file or folder")
        self.name = f"rosbag:{self.path.name}"
        self.skipped = 0
        self.topics = {"rgb": rgb_topic, "depth": depth_topic, "info": info_topic}
        with self._reader() as reader:
            by_topic = {c.topic: c for c in reader.connections}
            for role, topic in self.topics.items():
                if topic not in by_topic:
                    raise SourceError(f"rosbag {self.path}: no topic {topic!r} for {role}; topics: "
                                      f"{', '.join(sorted(by_topic)) or 'none'}")
                if by_topic[topic].msgtype not in TOPIC_TYPES[role]:
                    raise SourceError(f"rosbag {self.path}: the {role} topic {topic!r} carries "
                                      f"{by_topic[topic].msgtype}; expected {' or '.join(TOPIC_TYPES[role])}")
            self._compressed = by_topic[rgb_topic].msgtype == COMPRESSED_IMAGE
            stamps = {"rgb": [], "depth": []}
            depth_encodings = set()
            for connection, _, raw in reader.messages(connections=[by_topic[rgb_topic], by_topic[depth_topic],
                                                                   by_topic[info_topic]]):
                msg = self._deserialize(reader, raw, connection)
                if connection.topic == info_topic:
                    if self.camera is None:
                        self.camera = camera_info_from_ros(msg)
                    continue
                role = "rgb" if connection.topic == rgb_topic else "depth"
                stamps[role].append(_stamp_s(msg))
                if role == "depth":
                    depth_encodings.add(msg.encoding)
        if self.camera is None:
            raise SourceError(f"rosbag {self.path}: no message on the camera info topic {info_topic!r}")
        unsupported = depth_encodings - set(DEPTH_ENCODINGS)
        if unsupported:
            raise SourceError(f"rosbag {self.path}: depth encoding {min(unsupported)!r} is not supported; "
                              f"expected one of {DEPTH_ENCODINGS}")
        self.depth_scale = MILLIMETRES_PER_METRE if depth_encodings and depth_encodings <= {"16UC1", "mono16"} else None
        pairs = associate(np.array(stamps["rgb"]), np.array(stamps["depth"]))
        if len(pairs) == 0:
            raise SourceError(f"rosbag {self.path}: no colour/depth image pair within 0.02 s "
                              f"({len(stamps['rgb'])} colour, {len(stamps['depth'])} depth images)")
        self._pairs = pairs  # (P, 2): index among colour messages, index among depth messages
        self.timestamps = np.array(stamps["rgb"])[pairs[:, 0]]
        log.info("%s: %d frames from %d colour and %d depth images", self.name, len(pairs), len(stamps["rgb"]),
                 len(stamps["depth"]))

    def __len__(self) -> int:
        return len(self._pairs)

    def _reader(self):
        # ROS 2 bags written without message definitions need a default type store.
        store = self._typesys.get_typestore(self._typesys.Stores.ROS2_HUMBLE)
        try:
            return self._highlevel.AnyReader([self.path], default_typestore=store)
        except Exception as e:  # rosbags raises several unrelated error types for an unreadable bag
            raise SourceError(f"rosbag {self.path}: cannot open ({type(e).__name__}: {e})") from None

    def _deserialize(self, reader, raw, connection):
        try:
            return reader.deserialize(raw, connection.msgtype)
        except Exception as e:  # AnyReaderError and friends: a corrupt or foreign message
            raise SourceError(f"rosbag {self.path}: cannot decode a {connection.msgtype} on {connection.topic} "
                              f"({type(e).__name__}: {e})") from None

    def frames(self) -> Iterator[RGBDFrame]:
        want_rgb = {int(i): k for k, i in enumerate(self._pairs[:, 0])}
        want_depth = {int(j): k for k, j in enumerate(self._pairs[:, 1])}
        rgb_topic, depth_topic = self.topics["rgb"], self.topics["depth"]
        pending: dict[int, dict | None] = {}  # pair -> its halves read so far; None: dropped
        next_pair = 0
        counts = {"rgb": 0, "depth": 0}
        shape = (self.camera.height, self.camera.width)
        with self._reader() as reader:
            conns = [c for c in reader.connections if c.topic in (rgb_topic, depth_topic)]
            for connection, _, raw in reader.messages(connections=conns):
                role = "rgb" if connection.topic == rgb_topic else "depth"
                index = counts[role]
                counts[role] += 1
                pair = (want_rgb if role == "rgb" else want_depth).get(index)
                if pair is None:
                    continue
                msg = self._deserialize(reader, raw, connection)
                if role == "depth":
                    image = depth_from_image(msg)
                elif self._compressed:
                    image = rgb_from_compressed(msg)
                    if image is None:  # a corrupt image: its frame is dropped, as a camera drops one
                        log.warning("%s: a %d-byte compressed colour image on %s does not decode; its frame is "
                                    "skipped", self.name, len(msg.data), rgb_topic)
                        self.skipped += 1
                        pending[pair] = None
                else:
                    image = rgb_from_image(msg)
                if image is not None and image.shape[:2] != shape:
                    raise SourceError(f"rosbag {self.path}: {connection.topic} image is {image.shape[1]}x{image.shape[0]}, "
                                      f"the camera info says {shape[1]}x{shape[0]} (is depth registered to colour?)")
                if image is not None and pair >= next_pair and pending.get(pair, {}) is not None:
                    pending.setdefault(pair, {})[role] = image
                # Emit pairs in colour-time order as soon as both halves have been read.
                while next_pair in pending and (pending[next_pair] is None or len(pending[next_pair]) == 2):
                    half = pending.pop(next_pair)
                    if half is not None:
                        yield RGBDFrame(rgb=half["rgb"], depth_m=half["depth"], camera=self.camera,
                                        timestamp_s=float(self.timestamps[next_pair]), seq=next_pair)
                    next_pair += 1
