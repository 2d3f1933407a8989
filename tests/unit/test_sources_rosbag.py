"""RosbagSource on small ROS 1 and ROS 2 bags written here with the rosbags library."""

import cv2
import numpy as np
import pytest

from perception.sources import RosbagSource, SourceError

pytest.importorskip("rosbags.highlevel")
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

W, H = 8, 6
K = np.array([[7.5, 0, 3.5], [0, 7.25, 2.5], [0, 0, 1]])
D = np.array([0.1, -0.02, 0.001, 0.0, 0.003])


def colour(k):
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, 100 + k, 50
    return rgb


def depth_m(k):
    d = np.full((H, W), 1.0 + 0.25 * k, np.float32)
    d[0, 0] = 0.0
    return d


def image(store, stamp_s, data, encoding, step, ros1):
    Time, Header, Image = (store.types[n]
                           for n in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header", "sensor_msgs/msg/Image"))
    sec = int(stamp_s)
    stamp = Time(sec=sec, nanosec=round((stamp_s - sec) * 1e9))
    header = Header(seq=0, stamp=stamp, frame_id="cam") if ros1 else Header(stamp=stamp, frame_id="cam")
    buf = np.zeros(step * H, np.uint8)
    rows = np.frombuffer(np.ascontiguousarray(data).tobytes(), np.uint8).reshape(H, -1)
    buf.reshape(H, step)[:, : rows.shape[1]] = rows  # rows padded to ``step`` bytes, as drivers may do
    return Image(header=header, height=H, width=W, encoding=encoding, is_bigendian=0, step=step, data=buf)


def camera_info(store, ros1):
    Time, Header, Roi, Info = (store.types[n] for n in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
                                                          "sensor_msgs/msg/RegionOfInterest", "sensor_msgs/msg/CameraInfo"))
    stamp = Time(sec=0, nanosec=0)
    header = Header(seq=0, stamp=stamp, frame_id="cam_optical") if ros1 else Header(stamp=stamp, frame_id="cam_optical")
    names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
    arrays = dict(zip(names, (D, K.ravel(), np.eye(3).ravel(), np.zeros(12))))
    return Info(header=header, height=H, width=W, distortion_model="plumb_bob", binning_x=0, binning_y=0,
                roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False), **arrays)


def compressed(store, stamp_s, data, ros1):
    """A sensor_msgs/CompressedImage holding ``data`` (bytes) as PNG colour."""
    Time, Header, Compressed = (store.types[n] for n in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header",
                                                         "sensor_msgs/msg/CompressedImage"))
    sec = int(stamp_s)
    stamp = Time(sec=sec, nanosec=round((stamp_s - sec) * 1e9))
    header = Header(seq=0, stamp=stamp, frame_id="cam") if ros1 else Header(stamp=stamp, frame_id="cam")
    return Compressed(header=header, format="png", data=np.frombuffer(data, np.uint8))


def write_bag(path, ros1, colour_encoding="bgr8", depth_encoding="16UC1", n=3, corrupt=()):
    """A bag of ``n`` colour/depth pairs; ``colour_encoding`` "png" writes the colour as
    CompressedImage, with the frames in ``corrupt`` holding bytes that do not decode."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    writer = Writer1(path) if ros1 else Writer2(path, version=9)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    rgb_type = "sensor_msgs/msg/CompressedImage" if colour_encoding == "png" else "sensor_msgs/msg/Image"
    with writer:
        conns = {t: writer.add_connection(t, m, typestore=store) for t, m in (
            ("/rgb", rgb_type), ("/depth", "sensor_msgs/msg/Image"), ("/info", "sensor_msgs/msg/CameraInfo"))}
        writer.write(conns["/info"], 1, serialize(camera_info(store, ros1), "sensor_msgs/msg/CameraInfo"))
        for k in range(n):
            t = 10.0 + 0.1 * k
            rgb = colour(k)[:, :, ::-1] if colour_encoding == "bgr8" else colour(k)
            if depth_encoding == "16UC1":
                d, itemsize = np.rint(depth_m(k) * 1000).astype(np.uint16), 2
            elif depth_encoding == "8UC1":
                d, itemsize = np.ones((H, W), np.uint8), 1
            else:
                d, itemsize = depth_m(k).copy(), 4
                d[0, 1] = np.nan  # NaN is "no measurement" in float depth
            # Depth is stamped 5 ms after colour and written first: pairing must use the stamps.
            depth_msg = image(store, t + 0.005, d, depth_encoding, W * itemsize + 4, ros1)
            writer.write(conns["/depth"], 100 + 10 * k, serialize(depth_msg, "sensor_msgs/msg/Image"))
            if colour_encoding == "png":
                data = b"not a png" if k in corrupt else cv2.imencode(".png", colour(k)[:, :, ::-1])[1].tobytes()
                rgb_msg = compressed(store, t, data, ros1)
            else:
                rgb_msg = image(store, t, rgb, colour_encoding, W * 3, ros1)
            writer.write(conns["/rgb"], 101 + 10 * k, serialize(rgb_msg, rgb_type))
    return path


@pytest.mark.parametrize("ros1", [False, True], ids=["ros2", "ros1"])
def test_colour_and_depth_pairs_with_units_channels_and_intrinsics(tmp_path, ros1):
    path = write_bag(tmp_path / ("b.bag" if ros1 else "b"), ros1)
    src = RosbagSource(path, "/rgb", "/depth", "/info")
    assert len(src) == 3 and src.depth_scale == 1000.0
    for _ in range(2):
        frames = list(src.frames())
        assert [f.seq for f in frames] == [0, 1, 2]
        for k, f in enumerate(frames):
            np.testing.assert_array_equal(f.rgb, colour(k))  # bgr8 turned to RGB
            np.testing.assert_allclose(f.depth_m, depth_m(k), atol=1e-6)  # 16UC1 millimetres to metres
            assert f.timestamp_s == pytest.approx(10.0 + 0.1 * k)
    np.testing.assert_allclose(src.camera.K, K)
    np.testing.assert_allclose(src.camera.D, D)
    assert src.camera.frame_id == "cam_optical"


def test_float_depth_in_metres_with_nan_and_rgb8(tmp_path):
    src = RosbagSource(write_bag(tmp_path / "b", False, "rgb8", "32FC1", n=2), "/rgb", "/depth", "/info")
    assert src.depth_scale is None
    f = list(src.frames())[1]
    np.testing.assert_array_equal(f.rgb, colour(1))
    assert f.depth_m[0, 1] == 0.0 and f.depth_m[1, 1] == pytest.approx(1.25)


def test_bad_topics_and_encodings_are_named(tmp_path):
    path = write_bag(tmp_path / "b", False)
    with pytest.raises(SourceError, match="no topic '/colour' for rgb; topics: /depth, /info, /rgb"):
        RosbagSource(path, "/colour", "/depth", "/info")
    with pytest.raises(SourceError, match="no such file"):
        RosbagSource(tmp_path / "none", "/rgb", "/depth", "/info")
    with pytest.raises(SourceError, match="colour and depth topics must differ, got '/rgb' for both"):
        RosbagSource(path, "/rgb", "/rgb", "/info")
    with pytest.raises(SourceError, match="depth encoding '8UC1' is not supported"):
        RosbagSource(write_bag(tmp_path / "c", False, depth_encoding="8UC1"), "/rgb", "/depth", "/info")


@pytest.mark.parametrize("ros1", [False, True], ids=["ros2", "ros1"])
def test_compressed_colour_is_decoded_and_a_corrupt_image_drops_only_its_frame(tmp_path, ros1):
    path = write_bag(tmp_path / ("b.bag" if ros1 else "b"), ros1, colour_encoding="png", n=4, corrupt=(1,))
    src = RosbagSource(path, "/rgb", "/depth", "/info")
    frames = list(src.frames())
    assert [f.seq for f in frames] == [0, 2, 3] and src.skipped == 1  # the stream goes on past the bad image
    for f in frames:
        np.testing.assert_array_equal(f.rgb, colour(f.seq))  # PNG colour decoded to RGB
        np.testing.assert_allclose(f.depth_m, depth_m(f.seq), atol=1e-6)


def test_a_topic_of_another_message_type_is_named(tmp_path):
    path = write_bag(tmp_path / "b", False, colour_encoding="png")
    with pytest.raises(SourceError, match="the depth topic '/rgb' carries sensor_msgs/msg/CompressedImage; "
                                          "expected sensor_msgs/msg/Image"):
        RosbagSource(path, "/depth", "/rgb", "/info")
    with pytest.raises(SourceError, match="the info topic '/depth' carries sensor_msgs/msg/Image; "
                                          "expected sensor_msgs/msg/CameraInfo"):
        RosbagSource(path, "/rgb", "/depth", "/depth")
