"""The unfold task's pieces: which corners share an edge, the judge, the robot's motions, its drawn hands."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from grasping import GraspPlanner, adjacent_corners
from ipc.messages import GraspPlan, MeshEstimate
from perception.geometry import look_at, project, transform_points
from sim.cloth_mesh import rectangle_cloth
from sim.grasp_execution import move_grippers
from sim.laundry import LaundryScene, laundry_spec
from sim.laundry.controller import (
    BLUNT_CORNER_MIN_ANGLE_DEG,
    CLOSE_TIP_M,
    MAX_REACH_OVER_MATERIAL,
    MAX_TIP_OFFSET_M,
    MIN_CORNER_VISIBLE,
    MIN_EDGE_STRAIGHTNESS,
    NEAR_BEST_SCORE,
    SURE_CORNER_MAX_ANGLE_DEG,
    closely_confirmed,
    corner_angles_deg,
    corner_to_lift_first,
    edge_straightness,
    seen_enough,
    stretchable_corner,
    why_not_a_corner,
    why_not_confirmed,
)
from sim.laundry.judge import MIN_STRETCH, TOLERANCE_M, judge_unfold, seen_by_camera
from sim.laundry.truth import material_extent, rectangle_corners_uv, share_an_edge
from sim.laundry.unfold import (
    TautSensor,
    UnfoldConfig,
    arm_for,
    inward_pull_n,
    lift_target,
    rolled,
    shoulders,
    stretch_targets,
)
from tests.unit.test_grasp_adjacent import polygon_corner_of, polygon_estimate, towel_estimate, tshirt_estimate

TOWEL, _ = rectangle_corners_uv(0.5, 0.4)


def test_towel_corners_share_an_edge_with_their_neighbours_only():
    assert share_an_edge("towel", 0, 1) and share_an_edge("towel", 3, 0) and share_an_edge("towel", 2, 1)
    assert not share_an_edge("towel", 0, 2) and not share_an_edge("towel", 1, 3)


def test_tshirt_edges_are_the_hem_and_the_cuffs():
    # corners: right cuff top, right cuff bottom, right hem, left hem, left cuff bottom, left cuff top
    assert share_an_edge("tshirt", 2, 3) and share_an_edge("tshirt", 0, 1) and share_an_edge("tshirt", 5, 4)
    assert not share_an_edge("tshirt", 1, 2) and not share_an_edge("tshirt", 0, 5)
    with pytest.raises(ValueError, match="unknown cloth kind"):
        share_an_edge("sock", 0, 1)


def test_adjacent_corners_held_stretched_and_clear_succeed():
    first, second = TOWEL[0] + [0.01, 0.01], TOWEL[1] + [-0.01, 0.005]
    apart = 0.95 * np.linalg.norm(first - second)
    verdict = judge_unfold("towel", first, second, apart, True, TOWEL)
    assert verdict.success and verdict.adjacent and verdict.reason == ""
    assert (verdict.first_corner, verdict.second_corner) == (0, 1)
    assert verdict.stretch == pytest.approx(0.95)


@pytest.mark.parametrize(("second", "apart", "clear", "reason"), [
    (TOWEL[2], 0.6, True, "do not share an edge"),
    (TOWEL[0] + [0.01, 0.0], 0.3, True, "same corner"),
    (TOWEL[1] + [0.0, 2 * TOLERANCE_M], 0.5, True, "second grasp"),
    (TOWEL[1], 0.5 * MIN_STRETCH * 0.5, True, "of its length"),
    (TOWEL[1], 0.5, False, "not clear of the table"),
])
def test_unfold_fails_for_the_right_reason(second, apart, clear, reason):
    verdict = judge_unfold("towel", TOWEL[0], second, apart, clear, TOWEL)
    assert not verdict.success
    assert reason in verdict.reason


def test_a_gripper_that_holds_nothing_fails():
    verdict = judge_unfold("towel", TOWEL[0], None, 0.0, True, TOWEL)
    assert not verdict.success and verdict.second_corner == -1 and "second gripper" in verdict.reason


def test_held_by_a_hem_corner_a_shirt_is_stretched_along_its_hem_not_up_its_side():
    # Outline points of the T-shirt (tests/unit/test_grasp_adjacent.py): right cuff bottom
    # 11, right hem 13, left hem 14. From the right hem corner the outline leads along the
    # hem to 14 and up the side seam, past the armpit, to 11: both are adjacent along the
    # outline, but only the hem is an edge that pulling the two corners apart stretches.
    est, outline = tshirt_estimate()
    corners = GraspPlanner().corners(est)
    held = int(corners[polygon_corner_of(est, corners, outline).index(13)])
    candidates = adjacent_corners(est, held).candidates
    assert sorted(polygon_corner_of(est, [c.plan.vertex_id for c in candidates], outline)) == [11, 14]
    straightness = {polygon_corner_of(est, [c.plan.vertex_id], outline)[0]: edge_straightness(c, est.canonical, held)
                    for c in candidates}
    assert straightness[14] > 0.97 and straightness[11] < MIN_EDGE_STRAIGHTNESS
    for order in (candidates, candidates[::-1]):  # whichever the planner ranks first
        chosen = stretchable_corner(order, est.canonical, held)
        assert polygon_corner_of(est, [chosen.plan.vertex_id], outline) == [14]
    assert stretchable_corner((), est.canonical, held) is None


def _shirt_held_by_a_cuff_corner():
    """The test T-shirt held by its left cuff's top corner (outline point 17): (estimate, held
    vertex, {outline point: AdjacentCorner}); its candidates are the cuff's other corner (16)
    and the neck corner (0)."""
    est, outline = tshirt_estimate()
    corners = GraspPlanner().corners(est)
    held = int(corners[polygon_corner_of(est, corners, outline).index(17)])
    return est, held, {polygon_corner_of(est, [c.plan.vertex_id], outline)[0]: c
                       for c in adjacent_corners(est, held).candidates}


def test_held_by_a_cuff_corner_a_shirt_is_stretched_along_its_cuff_not_to_its_neck():
    # Outline points of the T-shirt: left cuff top 17, left cuff bottom 16, neck corner 0.
    # From the cuff's top corner the sleeve's top runs as straight to the neck corner as the
    # cuff does to its other corner, but no edge of the shirt ends at the neck corner: blunt
    # (125 degrees), where the cuff's corners are about square.
    est, held, candidates = _shirt_held_by_a_cuff_corner()
    assert sorted(candidates) == [0, 16]
    assert all(edge_straightness(c, est.canonical, held) >= MIN_EDGE_STRAIGHTNESS for c in candidates.values())
    angles_deg, _ = corner_angles_deg(est)
    assert angles_deg[candidates[0].plan.vertex_id] > SURE_CORNER_MAX_ANGLE_DEG > angles_deg[candidates[16].plan.vertex_id]
    for order in ((candidates[0], candidates[16]), (candidates[16], candidates[0])):
        assert stretchable_corner(order, est.canonical, held, angles_deg=angles_deg) is candidates[16]
    # without the angles the planner's order decides
    assert stretchable_corner((candidates[0], candidates[16]), est.canonical, held) is candidates[0]


def test_a_blunt_corner_at_the_end_of_a_long_edge_is_no_corner_but_a_short_edge_blurs_a_square_one():
    est, held, candidates = _shirt_held_by_a_cuff_corner()
    neck, cuff = candidates[0], candidates[16]
    angles_deg, window_m = corner_angles_deg(est)
    assert window_m == pytest.approx(4 * 0.02)  # the planner's 4 spacings on this 2 cm mesh
    assert angles_deg[neck.plan.vertex_id] > BLUNT_CORNER_MIN_ANGLE_DEG and neck.material_distance_m > 2 * window_m
    assert "not a corner" in why_not_a_corner(neck, angles_deg, window_m)
    assert why_not_a_corner(cuff, angles_deg, window_m) == ""
    towel = towel_estimate()
    towel_held = int(GraspPlanner().corners(towel)[0])
    assert all(why_not_a_corner(c, *corner_angles_deg(towel)) == ""
               for c in adjacent_corners(towel, towel_held).candidates)
    # the cuff's corner read blunt, as on a shirt's 8-11 cm cuff: no corner only where the
    # edge is long enough for the angle to be the corner's own
    blurred = {**angles_deg, cuff.plan.vertex_id: 127.0}
    short = dataclasses.replace(cuff, material_distance_m=1.5 * window_m)
    assert why_not_a_corner(short, blurred, window_m) == ""
    assert why_not_a_corner(dataclasses.replace(cuff, material_distance_m=2.5 * window_m), blurred, window_m)
    assert why_not_a_corner(cuff, {**angles_deg, cuff.plan.vertex_id: BLUNT_CORNER_MIN_ANGLE_DEG}, window_m) == ""
    # both read blunt, the short cuff unseen: taken before the neck though the neck is seen
    unseen = dataclasses.replace(short, visible=0.0, tip_offset_m=None)
    assert neck.visible > MIN_CORNER_VISIBLE
    for order in ((neck, unseen), (unseen, neck)):
        assert stretchable_corner(order, est.canonical, held, angles_deg=blurred, window_m=window_m) is unseen
    # without the window the camera decides between two blunt corners
    assert stretchable_corner((unseen, neck), est.canonical, held, angles_deg=blurred) is neck


def test_a_reachable_corner_comes_before_a_straight_edge():
    est = towel_estimate()
    held = int(GraspPlanner().corners(est)[0])
    first, second = adjacent_corners(est, held).candidates
    assert edge_straightness(first, est.canonical, held) > 0.97 and edge_straightness(second, est.canonical, held) > 0.97
    assert stretchable_corner((first, second), est.canonical, held) is first
    out_of_reach = dataclasses.replace(first, reachable=False)
    assert stretchable_corner((out_of_reach, second), est.canonical, held) is second


#: A camera 1.5 m above the world's origin looking down at 45 degrees: the robot's
#: kinematics (the world) and the plans (the camera) disagree unless converted.
CAMERA_POSE = look_at([0.0, -1.0, 1.5], [0.0, 0.3, 0.2])


def _second_plan_on(est, held, candidates, held_offset_m=0.0):
    """``_second_plan`` of an "adjacent" trial whose planner answers ``candidates`` on
    ``est``, the first gripper at the held vertex (``held_offset_m`` farther along the
    camera's x), the camera at ``CAMERA_POSE``."""
    from types import SimpleNamespace

    from launch_scripts.trial_runner.unfold import _second_plan

    asked = []

    def ask(request, seq, republish):
        asked.append(request)
        return SimpleNamespace(candidates=candidates, estimate_seq=7), 1.0

    tracking = SimpleNamespace(frames={"last": SimpleNamespace(seq=7)}, estimates={7: est})
    held_world = transform_points(CAMERA_POSE, (est.vertices[held] + [held_offset_m, 0.0, 0.0])[None])[0]
    hand = SimpleNamespace(gripper=SimpleNamespace(position=held_world))
    result = _second_plan(SimpleNamespace(arm="drawn", T_world_cam=CAMERA_POSE), SimpleNamespace(ask=ask),
                          SimpleNamespace(regrasp="adjacent"), tracking, None, held, hand)
    assert asked[0].even_if_lost  # the robot judges each corner itself
    return result


def confirmed(corner, offset_m=0.01):
    """``corner`` with its grasp at the measured tip, ``offset_m`` from the estimate's corner."""
    return dataclasses.replace(corner, tip_offset_m=offset_m)


def test_a_corner_the_camera_did_not_see_is_never_grasped_blind():
    est = towel_estimate()
    held = int(GraspPlanner().corners(est)[0])
    first, second = (confirmed(c) for c in adjacent_corners(est, held).candidates)
    assert first.visible == 1.0 and second.visible == 1.0  # no flags and no frame: taken as seen
    unseen = dataclasses.replace(first, visible=0.0)
    assert stretchable_corner((unseen, second), est.canonical, held) is second  # the seen one, though ranked second

    plan, _, vertex, details = _second_plan_on(est, held, (unseen, second))
    assert plan is second.plan and vertex == second.plan.vertex_id and details["visible"] == 1.0
    barely = dataclasses.replace(second, visible=MIN_CORNER_VISIBLE / 2, tip_offset_m=CLOSE_TIP_M + 0.01)
    plan, distance, vertex, details = _second_plan_on(est, held, (unseen, barely))
    assert plan is None and distance is None and vertex == -1
    # neither seen enough: the planner's first, as ever, and nothing grasped
    assert details["reason"] == "adjacent corner not seen (nothing around it seen): not grasped blind"
    _, _, _, details = _second_plan_on(est, held, (barely, unseen))
    assert details["reason"] == (f"adjacent corner not seen (visibility 0.12 < {MIN_CORNER_VISIBLE:g}, its measured "
                                 f"tip {100 * (CLOSE_TIP_M + 0.01):.1f} cm away, over {100 * CLOSE_TIP_M:g} cm): "
                                 "not grasped blind")
    _, _, _, details = _second_plan_on(est, held, (dataclasses.replace(barely, tip_offset_m=None),))
    assert details["reason"] == (f"adjacent corner not seen (visibility 0.12 < {MIN_CORNER_VISIBLE:g}, no measured "
                                 "tip): not grasped blind")
    # little of it seen, but the measured surface ends where the estimate's corner is: taken
    closely = dataclasses.replace(barely, tip_offset_m=CLOSE_TIP_M)
    assert seen_enough(closely) and not seen_enough(barely) and not seen_enough(unseen)
    plan, _, vertex, details = _second_plan_on(est, held, (unseen, closely))
    assert plan is closely.plan and details["visible"] == round(MIN_CORNER_VISIBLE / 2, 3)
    # nothing of it seen: no tip can be found from it, and a tip reported all the same is not trusted
    assert not seen_enough(dataclasses.replace(closely, visible=0.0))


def test_a_corner_the_frame_confirms_closely_comes_first():
    est = towel_estimate()
    held = int(GraspPlanner().corners(est)[0])
    held_at = est.vertices[held]
    first, second = adjacent_corners(est, held).candidates
    loose, close = confirmed(first, MAX_TIP_OFFSET_M - 0.01), confirmed(second, CLOSE_TIP_M - 0.005)
    assert closely_confirmed(close) and not closely_confirmed(loose) and not why_not_confirmed(loose, held_at)
    assert stretchable_corner((loose, close), est.canonical, held, held_at) is close  # though ranked second
    # both within the grasp's tolerance: a few millimetres say nothing, the planner's order decides
    both = (confirmed(first, CLOSE_TIP_M - 0.001), close)
    assert stretchable_corner(both, est.canonical, held, held_at) is both[0]
    # a close tip where the corner lies farther from the held one than its edge allows is no
    # confirmation: the corner confirmed less closely is taken, and grasped
    length = second.material_distance_m
    too_far = dataclasses.replace(close, material_distance_m=0.5 * length)
    assert why_not_confirmed(too_far, held_at)
    assert stretchable_corner((too_far, loose), est.canonical, held, held_at) is loose
    plan, _, _, details = _second_plan_on(est, held, (too_far, loose))
    assert plan is loose.plan and details["tip_offset_m"] == round(loose.tip_offset_m, 4)


def test_a_corner_is_grasped_only_where_the_measured_why_not_confirmed_it():
    est = towel_estimate()
    held = int(GraspPlanner().corners(est)[0])
    held_at = est.vertices[held]
    first, second = adjacent_corners(est, held).candidates
    assert first.tip_offset_m is None  # no frame: no tip searched for
    assert why_not_confirmed(first, held_at) == "no measured tip (no tip search, no frame, or no tip within the search)"
    assert why_not_confirmed(confirmed(first, MAX_TIP_OFFSET_M), held_at) == ""
    far_tip = confirmed(first, MAX_TIP_OFFSET_M + 0.01)
    assert why_not_confirmed(far_tip, held_at) == \
        f"the measured tip lies {100 * (MAX_TIP_OFFSET_M + 0.01):.1f} cm from the estimate's corner"
    # a corner farther from the gripper than the cloth between them allows
    length = first.material_distance_m
    assert float(np.linalg.norm(first.plan.position - held_at)) <= MAX_REACH_OVER_MATERIAL * length
    stretched = dataclasses.replace(confirmed(first), material_distance_m=0.5 * length)
    assert "from the held corner, along an edge" in why_not_confirmed(stretched, held_at)

    # the confirmed one is preferred, though ranked second; neither confirmed: nothing grasped
    assert stretchable_corner((first, confirmed(second)), est.canonical, held, held_at).plan is second.plan
    assert stretchable_corner((first, confirmed(second)), est.canonical, held).plan is first.plan  # held point unknown
    plan, _, vertex, details = _second_plan_on(est, held, (first, confirmed(second, 0.02)))
    assert plan is second.plan and details["tip_offset_m"] == 0.02
    plan, distance, vertex, details = _second_plan_on(est, held, (far_tip, second))
    assert plan is None and distance is None and vertex == -1
    assert details["reason"] == (f"adjacent corner not confirmed by the measured surface (the measured tip lies "
                                 f"{100 * (MAX_TIP_OFFSET_M + 0.01):.1f} cm from the estimate's corner): not grasped")
    # the gripper, in the world, 25 cm farther from the corners than the mesh's held vertex: each is
    # then farther from the held corner than its edge allows (a towel 40 x 30 cm)
    both = (confirmed(first), confirmed(second))
    assert _second_plan_on(est, held, both)[0] is first.plan
    plan, _, _, details = _second_plan_on(est, held, both, held_offset_m=-0.25)
    assert plan is None and "from the held corner, along an edge" in details["reason"]


def test_lift_target_leaves_the_cloth_hanging_clear():
    canonical = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.3, 0.4, 0.0], [0.0, 0.4, 0.0]])
    config = UnfoldConfig(hang_clearance_m=0.1)
    target = lift_target(np.array([0.2, -0.1, 0.75]), canonical, 0, table_top_m=0.75, config=config)
    np.testing.assert_allclose(target, [0.2, -0.1, 0.75 + 0.5 + 0.1])


def test_stretch_targets_are_level_apart_by_the_material_distance_and_across_the_view():
    T_world_cam = look_at(np.array([0.3, -1.5, 1.4]), np.array([0.0, 0.0, 1.0]))
    a, b = np.array([0.05, 0.02, 1.5]), np.array([-0.1, 0.1, 1.2])
    ta, tb = stretch_targets(a, b, 0.45, T_world_cam)
    assert ta[2] == pytest.approx(1.5) and tb[2] == pytest.approx(1.5)
    assert np.linalg.norm(ta - tb) == pytest.approx(0.45)
    across = T_world_cam[:3, 0].copy()
    across[2] = 0.0
    # along the camera's horizontal image axis, each gripper keeping its side
    assert abs(np.dot(tb - ta, across / np.linalg.norm(across))) == pytest.approx(0.45)
    assert np.dot(tb - ta, across) * np.dot(b - a, across) > 0
    np.testing.assert_allclose(0.5 * (ta + tb)[:2], 0.5 * (a + b)[:2])


def test_the_inward_pull_is_what_draws_the_grippers_together_along_the_line_between_them():
    a, b = np.array([0.1, 0.2, 0.8]), np.array([0.1, 0.6, 0.8])  # apart along y
    down = np.array([0.0, 0.0, -2.0])  # the weight each carries: no pull along the line
    assert inward_pull_n(down + [0.3, 1.0, 0.0], down - [0.0, 1.0, 0.0], a, b) == pytest.approx(1.0)
    assert inward_pull_n(down - [0.0, 0.5, 0.0], down + [0.0, 0.5, 0.0], a, b) == pytest.approx(-0.5)  # pushed apart
    assert inward_pull_n(down + [0.0, 1.0, 0.0], down, b, a) == pytest.approx(-0.5)  # the same readings, swapped ends
    assert inward_pull_n(down, down, a, a) == 0.0
    with pytest.raises(ValueError, match="first_force_n"):
        inward_pull_n(np.zeros(2), down, a, b)


def test_taut_when_the_pull_is_strong_and_grows_steeply_as_the_grippers_part():
    config = UnfoldConfig(taut_pull=0.5, taut_stiffness_per_m=20.0, taut_frames=3)
    weight = 2.0
    down = np.array([0.0, 0.0, -1.0])  # each carries half the weight

    def feel(pulls, separations):
        """Readings of grippers along y, apart by ``separations``, pulled together with ``pulls`` (N)."""
        sensor = TautSensor(weight, config)
        return [sensor(down + [0.0, f, 0.0], down - [0.0, f, 0.0], np.zeros(3), np.array([0.0, d, 0.0]))
                for f, d in zip(pulls, separations)]

    parting = [0.30, 0.31, 0.32, 0.33]
    # a straight edge: the pull grows by 0.4 N a centimetre (20 weights per metre)
    assert feel([0.9, 1.3, 1.7, 2.1], parting) == [False, False, True, True]
    # a slack edge: a strong pull, but one that hardly grows (a hanging cloth's weight)
    assert feel([1.5, 1.52, 1.54, 1.56], parting) == [False] * 4
    # a steep rise of a weak pull (the springs pushing, then letting go) is not taut either
    assert feel([-0.6, -0.3, 0.0, 0.3], parting) == [False] * 4
    # not parting: nothing to fit
    assert feel([1.0, 1.5, 2.0], [0.3, 0.3, 0.3]) == [False] * 3
    with pytest.raises(ValueError, match="TautSensor.weight_n"):
        TautSensor(0.0, config)
    with pytest.raises(ValueError, match="taut_frames"):
        UnfoldConfig(taut_frames=1)


def test_each_arm_reaches_its_side_and_the_second_takes_the_other():
    config = UnfoldConfig()
    left, right = shoulders(0.75, config)
    assert left[0] < 0 < right[0]
    np.testing.assert_allclose(arm_for(np.array([-0.2, 0.0, 0.8]), 0.75, config), left)
    np.testing.assert_allclose(arm_for(np.array([-0.1, 0.0, 0.8]), 0.75, config, taken=left), right)


class _Gripper:
    def __init__(self, position):
        self.position = np.asarray(position, dtype=float)
        self.quat_xyzw = np.array([0.0, 0.0, 0.0, 1.0])
        self.targets = []

    def move_to(self, position, quat_xyzw=None):
        self.targets.append(np.asarray(position, dtype=float))


class _Scene:
    fps = 30.0

    def __init__(self, grippers):
        self.grippers, self.steps = grippers, 0

    def step(self):
        self.steps += 1
        for g in self.grippers:
            g.position = g.targets[-1]


def test_move_grippers_steps_once_a_frame_and_ramps_smoothly_to_the_target():
    g1, g2 = _Gripper([0.0, 0.0, 1.0]), _Gripper([0.5, 0.0, 1.0])
    scene = _Scene([g1, g2])
    frames = []
    move_grippers(scene, [(g1, [0.0, 0.0, 1.3], None), (g2, [0.8, 0.0, 1.0], None)], 1.0,
                  on_frame=lambda: frames.append(scene.steps))
    assert scene.steps == 30 and frames == list(range(1, 31))
    heights = np.array([t[2] for t in g1.targets])
    np.testing.assert_allclose(heights[-1], 1.3)
    speeds = np.diff(np.concatenate([[1.0], heights])) * scene.fps
    assert np.all(speeds > 0)
    # a smooth start and stop: slow at both ends, 1.5 times the mean speed in the middle
    assert speeds[0] < 0.1 * 0.3 and speeds[-1] < 0.1 * 0.3
    assert speeds.max() == pytest.approx(1.5 * 0.3, rel=0.05)
    np.testing.assert_allclose(g2.targets[-1], [0.8, 0.0, 1.0])


def test_a_wrist_turn_keeps_the_approach_and_turns_the_jaw_about_it():
    tilted_down = Rotation.from_rotvec([0.4, -0.3, 0.0]) * Rotation.from_matrix(
        np.column_stack([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]))
    q = tilted_down.as_quat()
    R0, R1 = tilted_down.as_matrix(), Rotation.from_quat(rolled(q, 90.0)).as_matrix()
    np.testing.assert_allclose(R1[:, 2], R0[:, 2], atol=1e-12)  # the approach, and so the wrist behind it, stay
    np.testing.assert_allclose(R1[:, 0], R0[:, 1], atol=1e-12)  # the jaw's x turned a quarter turn about it
    turned = q
    for _ in range(4):
        turned = rolled(turned, 90.0)
    np.testing.assert_allclose(np.abs(turned @ q), 1.0, atol=1e-12)  # a full turn is no turn
    with pytest.raises(ValueError, match="quat_xyzw: expected a unit quaternion"):
        rolled([0.0, 0.0, 0.0, 2.0], 90.0)
    for bad in ({"look_turns": -1}, {"look_turns": 1.5}, {"look_turn_deg": 180.0}, {"turn_speed_deg_s": 0.0}):
        with pytest.raises(ValueError, match=f"UnfoldConfig.{next(iter(bad))}"):
            UnfoldConfig(**bad)


def test_a_robot_hand_is_drawn_and_its_mask_sent_as_the_known_occluder():
    spec = laundry_spec(2, view="room", state="flat")
    with LaundryScene(spec, noise=False, known_occluders=True) as scene:
        assert scene.render().occluder_mask is None  # no hand yet
        corner = scene.corners_world()[0]
        down = Rotation.from_matrix(np.column_stack([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])).as_quat()
        left, _ = shoulders(spec.table_top_z, UnfoldConfig())
        scene.add_robot_hand(corner + [0.0, 0.0, 0.05], down, left)
        frame = scene.render()
        mask = frame.occluder_mask.astype(bool)
        assert mask.sum() > 500  # fingers, wrist and arm
        # the hand is drawn in front of the cloth: where it is, the cloth is not seen
        assert not (mask & scene.cloth_mask()).any()
        scene.reset()
        assert scene.hands == [] and scene.render().occluder_mask is None


def test_the_camera_sees_a_true_corner_in_view_not_one_under_a_hand_or_behind_the_cloth():
    spec = laundry_spec(2, view="room", state="flat")
    with LaundryScene(spec, noise=False, known_occluders=True) as scene:
        corners_cam = scene.cloth_vertices_cam()[scene.corner_vertices()]
        assert seen_by_camera(corners_cam, scene.render()).all()  # a flat towel: every corner in view
        # the same points 5 cm behind the surface the camera sees there: under another layer
        behind = corners_cam * (1.0 + 0.05 / corners_cam[:, 2:])
        assert not seen_by_camera(behind, scene.render()).any()
        # the robot's hand over corner 0 (its known mask) hides it, whatever the depth there
        frame = scene.render()
        u, v = np.rint(project(corners_cam[0][None], frame.camera.K)[0]).astype(int)
        hand = np.zeros(frame.depth_m.shape, bool)
        hand[v - 3:v + 4, u - 3:u + 4] = True
        seen = seen_by_camera(corners_cam, dataclasses.replace(frame, occluder_mask=hand))
        assert not seen[0] and seen[1:].all()


def test_the_report_counts_corners_declined_that_were_in_sight():
    from launch_scripts.trial_runner.report import markdown, report

    blind = "adjacent corner not seen (visibility 0.00 < 0.25): not grasped blind"
    unconfirmed = "adjacent corner not confirmed by the measured surface (no measured tip ...): not grasped"
    records = [{**_unfold_record(seed, "adjacent", False, 50.0), "failure": reason,
                "second_grasp": {"declined": {"visible": 0.0, "n_candidates": 2, "tip_offset_m": None}}}
               for seed, reason in ((0, blind), (2, unconfirmed), (4, blind))]
    records[0]["tracking"]["true_adjacent_seen"] = {"top_right": False, "bottom_left": True}
    records[1]["tracking"]["true_adjacent_seen"] = {"top_right": False, "bottom_left": False}
    records.append({**_unfold_record(6, "adjacent", False, 50.0), "tracking": {"true_adjacent_seen": {"a": True}}})
    rep = report(records, "python -m launch_scripts.trials --task unfold", {"kind": "corner"})
    assert rep["summary"]["by_regrasp"]["adjacent"]["declined"] == {"trials": 3, "true_adjacent_corner_in_sight": 1}
    assert "| 3 (1) |" in markdown(rep)
    assert "after turning" not in markdown(rep)


def test_the_report_counts_second_corners_taken_only_after_turning_the_cloth():
    from launch_scripts.trial_runner.report import markdown, report

    records = [{**_unfold_record(seed, "adjacent", success, 50.0), "looks": {"count": looks},
                "second_grasp": {"plan_cam": [0.0, 0.0, 1.0]}}
               for seed, success, looks in ((0, True, 2), (2, False, 4), (4, True, 1))]
    records.append({**_unfold_record(6, "adjacent", False, 50.0), "looks": {"count": 4},  # turned, still declined
                    "second_grasp": {"declined": {"visible": 0.0}}})
    rep = report(records, "python -m launch_scripts.trials --task unfold", {"kind": "corner"})
    turned = rep["summary"]["by_regrasp"]["adjacent"]["taken_after_turning"]
    assert (turned["n"], turned["successes"]) == (2, 1)
    assert "2 trials took their second corner only after turning the hanging cloth" in markdown(rep)


def test_the_report_judges_each_look_at_the_second_corner_by_ground_truth():
    from launch_scripts.trial_runner.report import markdown, report

    near, far = 0.5 * TOLERANCE_M, 3.0 * TOLERANCE_M

    def look(plan, corner):
        return {"visible": 0.5, "to_true_adjacent_m": {"plan": plan, "estimate_corner": corner}}

    # seed 0: declined a right plan, then took a right one; seed 2: declined a wrong plan whose
    # estimate's corner was right, then declined a wrong one for good; seed 4: took a wrong one
    # at once; seed 6: an older record without the judgement counts nowhere
    records = [{**_unfold_record(0, "adjacent", True, 40.0), "looks": {"count": 2, "declined": [look(near, far)]},
                "second_grasp": {"plan_cam": [0.0, 0.0, 1.0], **look(near, near)}},
               {**_unfold_record(2, "adjacent", False, 40.0),
                "looks": {"count": 2, "declined": [look(far, near), look(far, far)]},
                "second_grasp": {"declined": look(far, far)}},
               {**_unfold_record(4, "adjacent", False, 40.0), "looks": {"count": 1, "declined": []},
                "second_grasp": {"plan_cam": [0.0, 0.0, 1.0], **look(far, near)}},
               {**_unfold_record(6, "adjacent", False, 40.0), "looks": {"count": 1, "declined": [{"visible": 0.0}]}}]
    rep = report(records, "python -m launch_scripts.trials --task unfold", {"kind": "corner"})
    assert rep["summary"]["by_regrasp"]["adjacent"]["looks"] == {
        "looks": 5, "taken": 2, "taken_right": 1, "declined": 3, "declined_plan_right": 1, "declined_estimate_right": 1}
    assert "of 5 looks at the second corner, the robot took the corner it chose in 2 (1 planned" in markdown(rep)
    # the baselines judge no look
    rep = report([_unfold_record(0, "lowest", False, 40.0)], "python -m launch_scripts.trials", {"kind": "corner"})
    assert "looks at the second corner" not in markdown(rep)


def test_a_look_is_judged_against_the_true_corners_sharing_an_edge_with_the_held_one():
    from types import SimpleNamespace

    from launch_scripts.trial_runner.unfold import _judged

    uv, names = rectangle_corners_uv(0.5, 0.4)  # the towel's corners, material coordinates
    corners_cam = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [0.5, 0.4, 1.0], [0.0, 0.4, 1.0]])
    cloth = np.vstack([corners_cam, [[0.25, 0.2, 1.0]]])  # where the cloth's vertices are now
    scene = SimpleNamespace(spec=SimpleNamespace(corners_uv=uv, cloth_kind="towel", corner_names=names),
                            cloth_vertices_cam=lambda: cloth, corner_vertices=lambda: np.arange(4))
    held = 0
    assert [k for k in range(4) if k != held and share_an_edge("towel", held, k)] == [1, 3], "test setup"
    estimate = SimpleNamespace(vertices=np.array([[0.0, 0.0, 1.0], [0.52, 0.0, 1.0], [0.5, 0.4, 1.0]]))

    def corner(vertex, position):
        return SimpleNamespace(plan=SimpleNamespace(position=np.array(position), vertex_id=vertex))

    # the plan 1 cm from the adjacent corner top_right, the estimate's corner 2 cm from it
    assert _judged(scene, corner(1, [0.5, 0.01, 1.0]), estimate, uv[held]) == {"plan": 0.01, "estimate_corner": 0.02}
    # the corner opposite the held one shares no edge with it: 0.4 m from top_right, the nearest adjacent one
    judged = _judged(scene, corner(2, [0.5, 0.4, 1.0]), estimate, uv[held])
    assert judged == pytest.approx({"plan": 0.4, "estimate_corner": 0.4})


def test_the_lift_is_scored_for_wrong_frames_reported_with_confidence():
    from types import SimpleNamespace

    from launch_scripts.trial_runner.unfold import _honesty

    # 8 frames of 10 vertices: right (1 cm off) in frames 0-1, wrong (5 cm off) from frame 2 on,
    # confident until frame 5, flagged lost from frame 6: frame 5, the fourth wrong frame in a
    # row, is the one not flagged in time
    errors = {s: np.full(10, 0.01 if s < 2 else 0.05) for s in range(8)}
    estimates = {s: SimpleNamespace(confidence=0.9 if s < 6 else 0.2, lost=s >= 6) for s in range(8)}
    assert _honesty(errors, estimates, list(range(8))) == \
        {"frames": 8, "wrong": 6, "wrong_confident": 4, "wrong_not_lost_after_3": 1, "right_confident": 2}  # frame 5
    assert _honesty(errors, estimates, [0, 1]) == {"frames": 2, "wrong": 0, "wrong_confident": 0,
                                                    "wrong_not_lost_after_3": 0, "right_confident": 2}
    # a frame without an error (a mesh built anew) leaves the lift unscored
    assert _honesty(errors, estimates, list(range(9))) is None and _honesty(errors, estimates, []) is None

    from launch_scripts.trial_runner.report import markdown, report

    records = [_unfold_record(0, "adjacent", True, 40.0), _unfold_record(2, "adjacent", False, 60.0)]
    records[0]["tracking"]["honesty"] = _honesty(errors, estimates, list(range(8)))
    records[1]["tracking"]["honesty"] = {"frames": 100, "wrong": 10, "wrong_confident": 3, "wrong_not_lost_after_3": 2}
    rep = report(records, "python -m launch_scripts.trials --task unfold", {"kind": "corner"})
    assert rep["summary"]["by_regrasp"]["adjacent"]["lift_and_hang_frames"] == \
        {"frames": 108, "wrong": 16, "wrong_confident": 7, "wrong_not_lost_after_3": 3, "right_confident": 2}
    assert "| 16 / 7 / 3 of 108 |" in markdown(rep)


def _unfold_record(seed, regrasp, success, lift_mean):
    return {"seed": seed, "task": "unfold", "regrasp": regrasp, "kind": "corner", "success": success,
            "corner_success": True, "failure": "" if success else "the held corners do not share an edge",
            "scene": {"state": "flat", "cloth": "towel"}, "timing": {"total_s": 30.0 + seed},
            "tracking": {"lift_error_mm": {"mean": lift_mean, "p95": 3 * lift_mean},
                         "second_plan_error_mm": None, "frames_tracked": 150}}


def test_the_report_sets_the_ways_of_choosing_the_second_corner_side_by_side():
    from launch_scripts.trial_runner.report import markdown, report

    records = [_unfold_record(0, "adjacent", True, 40.0), _unfold_record(2, "adjacent", False, 60.0),
               _unfold_record(0, "lowest", False, 90.0), _unfold_record(2, "lowest", False, 110.0)]
    rep = report(records, "python -m launch_scripts.trials --task unfold", {"kind": "corner"})
    by = rep["summary"]["by_regrasp"]
    assert set(by) == {"adjacent", "lowest"}
    assert by["adjacent"]["success"]["successes"] == 1 and by["lowest"]["success"]["successes"] == 0
    assert by["adjacent"]["median_lift_error_mm"] == {"mean": 50.0, "p95": 150.0}
    assert by["lowest"]["median_second_plan_error_mm"] == {"mean": None, "p95": None}
    text = markdown(rep)
    assert "unfolding by two adjacent corners" in text
    assert "| adjacent | 1/2 = 50.0 %" in text and "| lowest | 0/2 = 0.0 %" in text
    assert "first grasps at a corner" in text and "median corner error" not in text
    corner_only = report([{**_unfold_record(0, "x", True, 1.0), "task": "corner"}], "c", {"kind": "corner"})
    assert "by_regrasp" not in corner_only["summary"] and "median corner error" in markdown(corner_only)


def test_the_lowest_point_baseline_records_why_when_only_specks_of_cloth_are_seen():
    from types import SimpleNamespace

    from ipc.messages import CameraInfo, RGBDFrame
    from launch_scripts.trial_runner.unfold import _second_plan

    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    camera = CameraInfo(width=640, height=480, K=K)
    wall = np.full((480, 640), 2.0, np.float32)
    reference = RGBDFrame(rgb=np.full((480, 640, 3), 90, np.uint8), depth_m=wall, camera=camera)
    # a patch of cloth colour whose depth is the wall's but for five scattered pixels nearer
    rgb, depth = reference.rgb.copy(), wall.copy()
    rgb[200:230, 300:330] = (200, 40, 40)
    for k in range(5):
        depth[202 + 6 * k, 302 + 6 * k] = 1.5
    frame = RGBDFrame(rgb=rgb, depth_m=depth, camera=camera, seq=7)
    estimate = SimpleNamespace(vertices=np.zeros((3, 3)), canonical=np.zeros((3, 3)))
    tracking = SimpleNamespace(frames={"last": frame}, estimates={7: estimate})
    scene = SimpleNamespace(T_world_cam=np.eye(4))
    config = SimpleNamespace(regrasp="lowest")
    plan, distance, vertex, details = _second_plan(scene, None, config, tracking, reference, 0, None)
    assert plan is None and vertex == -1
    assert details["reason"].startswith("no lowest point on the cloth seen below the gripper (Expected a cloth")


def _on_a_table(estimate: MeshEstimate, T_world_cam: np.ndarray, turn_deg: float) -> MeshEstimate:
    """``estimate``'s canonical mesh laid flat on a table (z = 0, world), centred on the origin and
    turned ``turn_deg`` about z, in the camera frame of ``T_world_cam``."""
    flat = Rotation.from_euler("z", turn_deg, degrees=True).apply(estimate.canonical - estimate.canonical.mean(axis=0))
    T_cam_world = np.linalg.inv(T_world_cam)
    return dataclasses.replace(estimate, vertices=flat @ T_cam_world[:3, :3].T + T_cam_world[:3, 3])


def _corner_plans(estimate: MeshEstimate, score: float = 1.0) -> tuple:
    return tuple(GraspPlan(position=estimate.vertices[v], approach=np.array([0.0, 0.0, 1.0]),
                           quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), opening_width_m=0.04, score=score,
                           vertex_id=int(v), kind="corner")
                 for v in GraspPlanner().corners(estimate))


def _facing(plan: GraspPlan, estimate: MeshEstimate, T_world_cam: np.ndarray) -> float:
    """Cosine between the camera's horizontal direction to the plan and the plan's to the cloth's centre."""
    corner, centre = (transform_points(T_world_cam, p) for p in (plan.position[None], estimate.vertices))
    out, beyond = (corner[0] - T_world_cam[:3, 3])[:2], (centre.mean(axis=0) - corner[0])[:2]
    return float(out @ beyond / np.linalg.norm(out) / np.linalg.norm(beyond))


T_ROOM = look_at([0.0, -1.5, 1.0], [0.0, 0.0, 0.0])  # 1.5 m away along -y, 1 m up, looking at the table's centre


def test_a_towel_is_lifted_first_by_a_corner_the_cloth_lies_beyond_from_the_camera():
    towel = _on_a_table(towel_estimate(), T_ROOM, 0.0)
    plans = _corner_plans(towel)
    chosen = corner_to_lift_first(plans, towel, T_ROOM)
    world = transform_points(T_ROOM, chosen.position[None])[0]
    assert world[1] < 0, "a near corner (the towel lies beyond it)"
    assert chosen is next(p for p in plans if transform_points(T_ROOM, p.position[None])[0][1] < 0), \
        "of the two near corners, equally placed, the planner's first"
    # the planner's ranking still comes first: near corners scoring clearly lower are not taken
    far = [p for p in plans if transform_points(T_ROOM, p.position[None])[0][1] > 0]
    near = [dataclasses.replace(p, score=1.0 - 2 * NEAR_BEST_SCORE) for p in plans if all(p is not q for q in far)]
    assert any(corner_to_lift_first((*far, *near), towel, T_ROOM) is p for p in far)
    assert corner_to_lift_first((), towel, T_ROOM) is None


@pytest.mark.parametrize("turn_deg", [0.0, 90.0, 180.0, 270.0])
def test_a_shirt_is_never_lifted_first_by_its_neck(turn_deg):
    est, outline = tshirt_estimate()
    shirt = _on_a_table(est, T_ROOM, turn_deg)
    plans = _corner_plans(shirt)
    true = {10, 11, 13, 14, 16, 17}  # outline points: the cuffs' and the hem's corners (0 and 8: the neck's)
    kind = dict(zip((p.vertex_id for p in plans), polygon_corner_of(shirt, [p.vertex_id for p in plans], outline)))
    chosen = corner_to_lift_first(plans, shirt, T_ROOM)
    assert kind[chosen.vertex_id] in true
    facing = {p.vertex_id: _facing(p, shirt, T_ROOM) for p in plans}
    assert facing[chosen.vertex_id] == max(f for v, f in facing.items() if kind[v] in true)
    if turn_deg == 0.0:  # the neck toward the camera: a neck corner faces it best, and is passed over
        assert kind[max(facing, key=facing.get)] not in true


def test_a_blunt_corner_is_not_lifted_first_even_when_it_faces_the_camera_best():
    # a right trapezoid: corners of about 60, 90, 90 and 120 degrees; a corner as blunt as the
    # last is, on the trials' meshes, a fold's or a shirt's shoulder, not a true corner
    polygon = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.4], [0.23, 0.4]])
    sheet = _on_a_table(polygon_estimate(polygon), T_ROOM, 150.0)
    plans = _corner_plans(sheet)
    kind = dict(zip((p.vertex_id for p in plans), polygon_corner_of(sheet, [p.vertex_id for p in plans], polygon)))
    facing = {p.vertex_id: _facing(p, sheet, T_ROOM) for p in plans}
    assert kind[max(facing, key=facing.get)] == 3, "test setup: the blunt corner faces the camera best"
    chosen = corner_to_lift_first(plans, sheet, T_ROOM)
    assert kind[chosen.vertex_id] != 3
    assert facing[chosen.vertex_id] == max(f for v, f in facing.items() if kind[v] != 3)


def test_material_extent_tells_a_jaw_on_two_layers_from_one_on_a_single_layer():
    cloth = rectangle_cloth(0.5, 0.4, spacing_m=0.02)
    uv = cloth.uv_m

    def near(corner):
        return np.flatnonzero(np.linalg.norm(uv - np.array(corner), axis=1) <= 0.03)

    one_layer = near([0.0, 0.0])
    assert len(one_layer) >= 3
    assert material_extent(uv, one_layer) <= 0.06
    # a towel folded in half brings its bottom-left corner onto its top-left one: a jaw there holds both
    two_layers = np.concatenate([one_layer, near([0.0, 0.4])])
    assert material_extent(uv, two_layers) == pytest.approx(0.4, abs=0.06)
    assert material_extent(uv, one_layer[:1]) == 0.0


@pytest.mark.slow
def test_the_robot_measures_how_far_below_its_gripper_the_cloth_hangs_whatever_its_arm_covers():
    from launch_scripts.trial_runner.unfold import _hang_record

    spec = laundry_spec(2, view="room", state="flat", cloth_kind="towel")
    config = UnfoldConfig()
    with LaundryScene(spec, noise=False, known_occluders=True) as scene:
        reference = scene.render_empty()
        corner = scene.corners_world()[0]
        down = Rotation.from_matrix(np.column_stack([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])).as_quat()
        hand = scene.add_robot_hand(corner, down, arm_for(corner, spec.table_top_z, config))
        hand.gripper.close_on(scene.physics.nodes_near(corner, 0.02))
        canonical = np.column_stack([scene.uv_m, np.zeros(len(scene.uv_m))])
        held = int(scene.corner_vertices()[0])
        top = lift_target(corner, canonical, held, spec.table_top_z, config)
        move_grippers(scene, [(hand.gripper, top, None)], 2.0)
        frame = scene.render()
        # the drawn arm differs from the empty workspace over more pixels than the cloth does
        assert frame.occluder_mask.sum() > scene.cloth_mask().sum()
        hang = _hang_record(scene, frame, reference, hand, canonical, held)
        true_below = hand.gripper.position[2] - scene.cloth_vertices_world()[:, 2].min()
        assert hang["below_gripper_m"] == pytest.approx(true_below, abs=0.03)
        assert hang["mesh_reach_m"] == pytest.approx(np.linalg.norm(canonical - canonical[held], axis=1).max(), abs=1e-4)
        assert hang["gripper_above_table_m"] == pytest.approx(top[2] - spec.table_top_z, abs=1e-3)
