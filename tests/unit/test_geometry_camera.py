import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.geometry import (
    Undistorter,
    backproject,
    crop_intrinsics,
    pixel_index,
    project,
    ray_lengths,
    rays,
)

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


def test_undistorter_keeps_what_the_lens_does_not_touch():
    cam = CameraInfo(640, 480, K, np.array([-0.25, 0.08, 0.0, 0.0, 0.0]))
    frame = RGBDFrame(np.zeros((480, 640, 3), np.uint8), np.ones((480, 640), np.float32), cam, timestamp_s=2.5, seq=7,
                      held_vertices=np.array([3, 9], np.int32), held_points_m=np.array([[0.1, 0.0, 1.0], [0.2, 0.0, 1.0]]))
    out = Undistorter(cam)(frame)
    assert out.camera.D.size == 0 and (out.timestamp_s, out.seq) == (2.5, 7)
    assert out.held_vertices.tolist() == [3, 9]  # what the robot holds, and where, in 3D
    np.testing.assert_array_equal(out.held_points_m, frame.held_points_m)


def test_project_with_distortion_matches_opencv():
    rng = np.random.default_rng(3)
    points = rng.uniform([-0.3, -0.2, 0.8], [0.3, 0.2, 1.5], (20, 3))
    K2 = np.array([[500.0, 0, 320], [0, 510.0, 240], [0, 0, 1]])
    for D in (np.zeros(0), np.zeros(5), np.array([0.1, -0.05, 0.001, -0.002, 0.01]),
              np.array([0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005])):
        expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K2, D if D.size else None)
        np.testing.assert_allclose(project(points, K2, D), expected[:, 0], atol=1e-9)
        behind = project(np.array([[0.0, 0.0, -1.0], [0.1, 0.0, 1.0]]), K2, D)
        assert np.all(np.isnan(behind[0])) and np.all(np.isfinite(behind[1]))


def test_ray_lengths_are_the_norms_of_the_rays():
    lengths = ray_lengths(K, 64, 48)
    vv, uu = np.mgrid[0:48, 0:64]
    expected = np.linalg.norm(rays(np.column_stack([uu.ravel(), vv.ravel()]), K), axis=1).reshape(48, 64)
    assert lengths.shape == (48, 64) and lengths.dtype == np.float32
    np.testing.assert_allclose(lengths, expected, rtol=1e-6)


def test_crop_intrinsics_moves_the_principal_point():
    p = np.array([[0.1, -0.05, 1.2]])
    cropped = crop_intrinsics(K, 100, 40)
    np.testing.assert_allclose(project(p, cropped), project(p, K) - [100, 40], atol=1e-12)
    assert K[0, 2] == 320  # the input is not changed
