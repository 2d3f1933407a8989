"""The plane an object rests on or hangs in front of (``perception.support``): found from the
ring around the object when it is a table or a wall, refused when the ring's plane is no
larger than the object or lies in front of it."""

import numpy as np

from ipc.messages import CameraInfo
from perception.geometry import rays
from perception.support import fit_support

CAM = CameraInfo.from_fov(320, 240, np.deg2rad(50))
K = CAM.K
ROWS, COLS = np.mgrid[0:240, 0:320]
RAYS = rays(np.column_stack([COLS.ravel(), ROWS.ravel()]), K)


def plane_depth(normal, offset):
    """(240, 320) float32 depth of the plane ``normal @ p + offset = 0`` (NaN where it is not seen)."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    with np.errstate(divide="ignore"):
        z = -offset / (RAYS @ normal)
    return np.where(z > 0, z, np.nan).reshape(240, 320).astype(np.float32)


TABLE = (np.array([0.0, -0.8, -0.6]), 0.9)  # seen from above at an angle, about 1.1-1.8 m away


def cloth_on_table(rng):
    depth = plane_depth(*TABLE) + rng.normal(0, 0.002, (240, 320)).astype(np.float32)
    cloth = np.zeros((240, 320), bool)
    cloth[90:170, 100:220] = True
    depth[cloth] -= 0.004  # a few millimetres thick
    return depth, cloth


def test_the_table_under_a_cloth_is_found_and_carries_on_under_it():
    rng = np.random.default_rng(1)
    depth, cloth = cloth_on_table(rng)
    plane = fit_support(depth, cloth, K)
    assert plane is not None
    normal = TABLE[0] / np.linalg.norm(TABLE[0])
    assert abs(plane.normal @ normal) > 0.999 and abs(plane.offset - TABLE[1]) < 0.01
    table = plane_depth(*TABLE)
    assert plane.on_plane(table, K)[cloth].all()  # bared, the table under the cloth is table
    lifted = table - 0.05 * table / np.abs(table)  # 5 cm nearer along z: a hand above it
    assert not plane.on_plane(lifted, K)[cloth].any()
    # The same on a box read on every other pixel, as ``perception.occluders`` reads it.
    box = table[60:200:2, 80:240:2]
    assert plane.on_plane(box, K, 80, 60, 2).all()
    assert fit_support(depth, cloth, K).offset == plane.offset  # the same fit every time


def test_no_plane_is_claimed_for_an_object_held_up_in_a_room():
    rng = np.random.default_rng(2)
    # A bar held by two hands in its own plane, 1 m away, in a room beyond the sensor's range:
    # all the ring's measured points lie on that plane, which is no larger than the bar and hands.
    room = np.zeros((240, 320), np.float32)
    held = np.zeros((240, 320), bool)
    held[95:155, 60:260] = True  # the bar and the hands holding it
    depth = np.where(held, 1.0 + rng.normal(0, 0.002, (240, 320)), room).astype(np.float32)
    bar = np.zeros((240, 320), bool)
    bar[110:140, 90:230] = True
    assert fit_support(depth, bar, K) is None
    # A wall 2.5 m away is the support of what hangs in front of it.
    depth[~held] = 2.5
    wall = fit_support(depth, held, K)
    assert wall is not None  # the wall, facing the camera 2.5 m away, not the bar's own plane at 1 m
    assert wall.normal[2] < -0.999 and abs(wall.offset - 2.5) < 0.01  # normal towards the camera: -z
    # Nor is a plane the object lies behind (a frame in front of it), nor one without depth.
    behind = np.full((240, 320), 2.5, np.float32)  # a wall with the bar seen through a hole in it
    behind[bar] = 2.7
    assert fit_support(behind, bar, K) is None
    assert fit_support(np.zeros((240, 320), np.float32), bar, K) is None
