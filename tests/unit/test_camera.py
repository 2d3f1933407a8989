import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.camera import Undistorter, backproject, pixel_index, project

K = np.array([[500.0, 0, 320], [0, 480.0, 240], [0, 0, 1]])


def test_project_backproject_round_trip():
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.4, 0.4, 50), rng.uniform(0.5, 3, 50)])
    uv = project(p, K)
    np.testing.assert_allclose(backproject(uv, p[:, 2], K), p, atol=1e-12)
    # agrees with OpenCV's projection
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, None)
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)
    assert np.all(np.isnan(project(np.array([[0.1, 0.1, -1.0]]), K)))  # behind the camera


def test_pixel_index_flags_outside_and_nan():
    cols, rows, inside = pixel_index(np.array([[0.4, 0.4], [639.6, 10], [np.nan, 3], [10, 479.4]]), 640, 480)
    assert inside.tolist() == [True, False, False, True]
    assert cols[0] == 0 and rows[3] == 479


def test_undistorter_moves_pixels_to_pinhole_positions():
    D = np.array([-0.25, 0.08, 0.0, 0.0, 0.0])
    cam = CameraInfo(640, 480, K, D)
    point = np.array([[0.35, 0.25, 1.0]])  # far off-axis, where distortion is strong
    distorted, _ = cv2.projectPoints(point, np.zeros(3), np.zeros(3), K, D)
    u, v = np.rint(distorted.reshape(2)).astype(int)
    rgb = np.zeros((480, 640, 3), np.uint8)
    cv2.circle(rgb, (int(u), int(v)), 3, (255, 255, 255), -1)
    depth = np.zeros((480, 640), np.float32)
    depth[v - 3 : v + 4, u - 3 : u + 4] = 1.0
    out = Undistorter(cam)(RGBDFrame(rgb, depth, cam))
    assert out.camera.D.size == 0
    ys, xs = np.nonzero(out.depth_m > 0)
    expected = project(point, K)[0]
    assert abs(xs.mean() - expected[0]) < 1.5 and abs(ys.mean() - expected[1]) < 1.5
    assert np.all(out.depth_m[ys, xs] == 1.0)  # nearest-neighbour: no invented depths
    # no distortion: the same frame object comes back
    plain = RGBDFrame(rgb, depth, CameraInfo(640, 480, K))
    assert Undistorter(plain.camera)(plain) is plain
