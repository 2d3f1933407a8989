"""A corner's tip on the measured surface (grasping._tip): found where the sheet ends, not on
what lies beyond it, and nothing where no tip is within reach."""

import numpy as np
import pytest

from grasping import GraspPlannerConfig, adjacent_corners
from grasping._tip import measured_tip
from ipc.messages import CameraInfo, RGBDFrame
from perception.geometry import rays
from tests.unit.test_grasp_adjacent import RECTANGLE, nearest_vertex, towel_estimate

CAMERA = CameraInfo(width=320, height=240, K=np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]))
CORNER = np.array([0.2, 0.2, 1.0])  # of the square sheet |x|, |y| <= 0.2 at z = 1 m
OUT = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)  # the corner's bisector, out of the sheet


def frame_of(*surfaces, mask=None) -> RGBDFrame:
    """Depth of flat rectangles facing the camera, nearest first: ((x0, x1), (y0, y1), z) each; a wall at 3 m."""
    v, u = np.mgrid[0:CAMERA.height, 0:CAMERA.width]
    ray = rays(np.column_stack([u.ravel(), v.ravel()]), CAMERA.K)
    depth = np.full(len(ray), 3.0)
    for (x0, x1), (y0, y1), z in reversed(surfaces):
        x, y = ray[:, 0] * z, ray[:, 1] * z
        depth[(x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)] = z
    return RGBDFrame(rgb=np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8),
                     depth_m=depth.reshape(CAMERA.height, CAMERA.width).astype(np.float32), camera=CAMERA,
                     occluder_mask=mask)


SHEET = ((-0.2, 0.2), (-0.2, 0.2), 1.0)


def seeds_around(point, radius=0.02):
    grid = np.stack(np.meshgrid(np.linspace(-radius, radius, 5), np.linspace(-radius, radius, 5)), -1).reshape(-1, 2)
    return np.column_stack([point[0] + grid[:, 0], point[1] + grid[:, 1], np.full(len(grid), point[2])])


@pytest.mark.parametrize("offset_m", [-0.06, -0.03, 0.0, 0.03])
def test_the_tip_is_the_sheets_corner_whether_the_estimate_stops_short_or_overshoots(offset_m):
    estimate = CORNER + offset_m * OUT
    inside = CORNER - 0.04 * OUT  # seen material around the estimate's corner lies on the sheet
    tip = measured_tip(frame_of(SHEET), estimate, OUT, seeds_around(inside), 0.1, 0.02)
    assert tip is not None
    assert np.linalg.norm(tip - CORNER) < 0.01


def test_a_surface_running_on_past_the_search_has_no_tip():
    middle = np.array([-0.05, 0.0, 1.0])  # 25 cm from the sheet's right edge
    assert measured_tip(frame_of(SHEET), middle, np.array([1.0, 0, 0]), seeds_around(middle), 0.1, 0.02) is None


def test_what_lies_beyond_a_depth_step_is_not_the_sheet():
    # A board 4 cm behind the sheet, reaching 5 cm beyond its corner (inside the search).
    behind = ((0.0, 0.25), (0.0, 0.25), 1.04)
    estimate = CORNER - 0.03 * OUT
    frame = frame_of(SHEET, behind)
    tip = measured_tip(frame, estimate, OUT, seeds_around(estimate), 0.1, 0.02)
    assert np.linalg.norm(tip - CORNER) < 0.01
    # Joined across that step, the search runs onto the board: the cut is what keeps it off.
    joined = measured_tip(frame, estimate, OUT, seeds_around(estimate), 0.1, 0.1)
    assert joined is None or np.linalg.norm(joined - CORNER) > 0.03


def test_the_robots_own_hand_is_not_the_sheet():
    # A gripper at the sheet's depth, holding its corner and reaching 3 cm beyond it.
    hand = ((0.17, 0.23), (0.17, 0.23), 1.0)
    frame = frame_of(SHEET, hand)
    estimate = CORNER - 0.03 * OUT
    unmasked = measured_tip(frame, estimate, OUT, seeds_around(estimate), 0.1, 0.02)
    assert np.linalg.norm(unmasked - CORNER) > 0.03  # on the hand's end
    v, u = np.mgrid[0:CAMERA.height, 0:CAMERA.width]
    x, y = (u - 160) / 300.0, (v - 120) / 300.0
    mask = (x >= 0.2) | (y >= 0.2)  # the hand's pixels beyond the sheet
    mask &= (x >= 0.17) & (x <= 0.23) & (y >= 0.17) & (y <= 0.23)
    frame = frame_of(SHEET, hand, mask=mask)
    tip = measured_tip(frame, estimate, OUT, seeds_around(estimate), 0.1, 0.02)
    assert np.linalg.norm(tip - CORNER) < 0.015


def test_nothing_to_search_from_gives_no_tip():
    frame = frame_of(SHEET)
    assert measured_tip(frame, CORNER, OUT, np.empty((0, 3)), 0.1, 0.02) is None  # no seen material
    assert measured_tip(frame, np.array([5.0, 0.0, 1.0]), OUT, seeds_around(CORNER), 0.1, 0.02) is None  # out of view
    off_sheet = seeds_around(np.array([0.5, 0.5, 1.0]))  # seeds on the wall, not on the sheet
    assert measured_tip(frame, CORNER, OUT, off_sheet, 0.1, 0.02) is None


def test_adjacent_corners_go_to_the_measured_tips_only_when_asked():
    # The towel's estimate lies 4 cm left of where the frame shows the towel.
    est = towel_estimate(confidence=0.9)
    shown = ((-0.2 + 0.04, 0.2 + 0.04), (-0.15, 0.15), 1.0)
    frame = frame_of(shown)
    held = nearest_vertex(est, RECTANGLE[0])  # bottom left, at (-0.2, -0.15) in the camera frame
    plain = adjacent_corners(est, held, GraspPlannerConfig(pinch_inset_m=0.0), frame=frame)
    tips = adjacent_corners(est, held, GraspPlannerConfig(pinch_inset_m=0.0, tip_search_radius_m=0.1), frame=frame)
    right = {c.plan.vertex_id: c for c in tips.candidates}[nearest_vertex(est, RECTANGLE[1])]
    before = {c.plan.vertex_id: c for c in plain.candidates}[right.plan.vertex_id]
    true_corner = np.array([0.24, -0.15, 1.0])
    assert np.linalg.norm(before.plan.position - true_corner) > 0.035
    assert np.linalg.norm(right.plan.position - true_corner) < 0.012
    assert right.visible == before.visible and right.plan.vertex_id == before.plan.vertex_id
    # how far the frame says the estimate's corner is from where the towel ends: the 4 cm shift
    assert before.tip_offset_m is None and right.tip_offset_m == pytest.approx(0.04, abs=0.005)
    # measured from the estimate's corner vertex to the tip, whatever the grasp's inset
    inset = adjacent_corners(est, held, GraspPlannerConfig(pinch_inset_m=0.01, tip_search_radius_m=0.1), frame=frame)
    inset_right = {c.plan.vertex_id: c for c in inset.candidates}[right.plan.vertex_id]
    assert inset_right.tip_offset_m == pytest.approx(right.tip_offset_m, abs=1e-9)
    assert np.linalg.norm(inset_right.plan.position - right.plan.position) == pytest.approx(0.01, abs=1e-6)
    with pytest.raises(ValueError, match="tip_search_radius_m >= 0"):
        GraspPlannerConfig(tip_search_radius_m=-0.1)
