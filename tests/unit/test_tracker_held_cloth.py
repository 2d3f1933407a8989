"""The tracker on a cloth the robot handles: what it holds (held vertices), its empty
workspace (a background), and a mesh that keeps its size (the stretch term).
Rendered textured sheets whose true shape is known."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ipc.messages import CameraInfo, RGBDFrame
from perception import MeshTracker, TrackerConfig
from perception.background import COLOUR_TOL, differs_from_background, seen_through
from perception.confidence import (
    FLOOR,
    MIN_DISAGREEING,
    RESHAPED_M,
    UNCONFIRMED_CAP,
    assess,
    matches_cap,
    material_cap,
    reshaping,
)
from perception.tracker import TrackingError
from tests.render import frame_of, grid_surface, plane_points, texture

CAM = CameraInfo.from_fov(640, 480, np.deg2rad(45))
SIZE = (0.5, 0.4)
UV, FACES = grid_surface(*SIZE, 26, 21)
TABLE_M = 1.31  # a wall 1 cm behind the sheet: as continuous in depth with it as a table under a cloth


@pytest.fixture(scope="module")
def tex():
    return texture(np.random.default_rng(11))


def sheet_on_table(points, tex, k):
    return frame_of(points, UV, FACES, tex, CAM, SIZE, t=k / 30, seq=k, noise_m=0.001,
                    rng=np.random.default_rng(200 + k), background_m=TABLE_M)


def empty_table() -> RGBDFrame:
    rgb = np.full((480, 640, 3), 90, np.uint8)
    return RGBDFrame(rgb, np.full((480, 640), TABLE_M, np.float32), CAM, 0.0, 0)


def hinged(uv: np.ndarray, k: int) -> np.ndarray:
    """The sheet at frame k: its right half lifted off the table towards the camera about
    its middle, 8 degrees a frame (a cloth picked up by one side); material lengths kept."""
    angle = np.radians(8.0 * k)
    s = uv[:, 0] - SIZE[0] / 2  # across the hinge, metres; > 0 is lifted
    x = np.where(s > 0, s * np.cos(angle), s)
    z = np.where(s > 0, -s * np.sin(angle), 0.0)
    return np.column_stack([x, uv[:, 1] - SIZE[1] / 2, 1.30 + z])


def track_lift(tex, background, n=9):
    """Track the lift; returns the tracker and the mean vertex error (m) at each frame after the first."""
    tracker = MeshTracker(TrackerConfig(features="klt", use_boundary=False))
    first = sheet_on_table(hinged(UV, 0), tex, 0)
    # depth cannot find a sheet on a table: the robot's mask (here, the true one)
    e0 = tracker.initialise(first, mask=first.depth_m < TABLE_M - 0.005, background=background)
    material = e0.vertices[:, :2] + np.array(SIZE) / 2  # the mesh was laid on the flat sheet at z = 1.3
    errors = []
    for k in range(1, n):
        e = tracker.track(sheet_on_table(hinged(UV, k), tex, k))
        errors.append(np.linalg.norm(e.vertices - hinged(material, k), axis=1).mean())
    return tracker, np.array(errors)


def test_differs_from_background_finds_what_is_not_the_empty_workspace(tex):
    frame = sheet_on_table(hinged(UV, 0), tex, 0)
    differs = differs_from_background(frame, empty_table())
    on_sheet = frame.depth_m < TABLE_M - 0.005
    assert differs[on_sheet].mean() > 0.95  # the printed sheet differs in colour
    assert differs[~on_sheet].mean() < 0.01  # the table does not
    with pytest.raises(ValueError, match="differ in size"):
        differs_from_background(frame, dataclasses.replace(empty_table(), rgb=np.zeros((10, 10, 3), np.uint8),
                                                           depth_m=np.zeros((10, 10), np.float32),
                                                           camera=CameraInfo.from_fov(10, 10, 1.0)))


def test_a_pixel_differs_in_colour_by_the_euclidean_distance_over_all_three_channels():
    """Flat colours (the 3x3 blur leaves them as they are) at distances around the tolerance,
    the difference spread over one, two and three channels: the test is the Euclidean one."""
    cam = CameraInfo.from_fov(30, 20, 1.0)
    grey = np.full((20, 30, 3), 100, np.uint8)
    depth = np.full((20, 30), 2.0, np.float32)
    background = RGBDFrame(seq=0, timestamp_s=0.0, rgb=grey, depth_m=depth, camera=cam)
    for step, differs in (((12, 0, 0), False), ((13, 0, 0), True), ((8, 8, 0), False), ((9, 9, 0), True),
                          ((7, 7, 6), False), ((7, 7, 7), True), ((-7, -7, -7), True)):
        assert (np.linalg.norm(step) > COLOUR_TOL) == differs  # the cases straddle the tolerance
        rgb = (grey.astype(int) + np.array(step)).astype(np.uint8)
        found = differs_from_background(dataclasses.replace(background, rgb=rgb), background)
        assert found.all() == differs and found.any() == differs, step


def test_with_a_background_only_what_differs_from_it_is_the_object(tex):
    tracker, errors = track_lift(tex, empty_table())
    frame = sheet_on_table(hinged(UV, 8), tex, 8)
    obs = tracker.last_observation.mask
    assert obs.sum() > 5000
    assert not (obs & ~differs_from_background(frame, empty_table())).any()  # nothing of the table
    assert errors.max() < 0.005, errors
    with pytest.raises(TrackingError, match="background: expected a 640x480 frame"):
        small = RGBDFrame(np.zeros((10, 10, 3), np.uint8), np.zeros((10, 10), np.float32),
                          CameraInfo.from_fov(10, 10, 1.0))
        MeshTracker(TrackerConfig()).initialise(frame, mask=frame.depth_m < TABLE_M - 0.005, background=small)


def _edges(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def test_a_mesh_beside_the_lifted_sheet_is_seen_through_to_the_empty_workspace(tex):
    """Where the camera sees the empty workspace nothing stands in front of it: a vertex in
    view there, nearer than the surface seen, is in the air beside the cloth. The tracked lift
    has none; the true sheet moved 12 cm sideways hangs its lifted half in the air, which
    depth cannot see (those vertices match nothing) and the confidence must. Vertices lying
    on the workspace (the flat half, slid along the table) or behind it are not counted."""
    tracker, errors = track_lift(tex, empty_table())
    assert errors.max() < 0.005 and tracker.last_assessment.opaque == 1.0
    frame = sheet_on_table(hinged(UV, 8), tex, 8)
    differs = differs_from_background(frame, empty_table())
    true = hinged(UV, 8)
    assert not seen_through(true, CAM.K, differs, frame.depth_m, 0.03).any()
    aside = true + np.array([0.0, 0.12, 0.0])
    exposed = seen_through(aside, CAM.K, differs, frame.depth_m, 0.03)
    beyond = UV[:, 1] > SIZE[1] - 0.12 + 0.01  # off the sheet's edge, a centimetre clear of its blur
    lifted = true[:, 2] < TABLE_M - 0.04
    assert exposed[beyond & lifted].mean() > 0.95
    assert not exposed[~beyond].any() and not exposed[beyond & ~lifted & (true[:, 2] > 1.29)].any()
    behind = aside + np.array([0.0, 0.0, 0.5])  # as far behind the wall: the wall may hide it
    assert not seen_through(behind, CAM.K, differs, frame.depth_m, 0.03).any()

    edges = _edges(FACES)
    rest = np.linalg.norm(true[edges[:, 0]] - true[edges[:, 1]], axis=1)
    on_sheet = frame.depth_m < TABLE_M - 0.005
    cues = [assess(V, edges, rest, np.ones(len(V), bool), frame.depth_m, on_sheet, CAM.K, 0.03, 1.0,
                   exposed=seen_through(V, CAM.K, differs, frame.depth_m, 0.03)) for V in (true, aside)]
    assert cues[0].opaque == 1.0 and cues[1].opaque < FLOOR and cues[1].lost(0.4)
    without = assess(aside, edges, rest, np.ones(len(UV), bool), frame.depth_m, on_sheet, CAM.K, 0.03, 1.0)
    assert without.opaque == 1.0  # no empty workspace given, nothing said


def test_a_plain_cloth_that_changed_shape_is_not_trusted_for_its_material_points(tex):
    """A mesh moved or turned as a whole keeps its shape; a sheet lifted by one half does not.
    On a print the appearance check confirms where the material went; on a plain sheet nothing
    does, so once the mesh has changed shape the confidence stays under 0.5, though the mesh
    still lies on the sheet (not lost)."""
    flat, lifted = hinged(UV, 0), hinged(UV, 8)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert reshaping(flat, flat @ turn.T + [0.1, 0.0, 0.3]) < 1e-9
    assert reshaping(flat, lifted) > RESHAPED_M
    assert material_cap(False, 0.04) == UNCONFIRMED_CAP and material_cap(True, 0.04) == 1.0
    assert material_cap(False, 0.01) == 1.0

    plain = np.full_like(tex, 140)
    for surface, printed in ((tex, True), (plain, False)):
        tracker = MeshTracker(TrackerConfig(features="klt", use_boundary=False))
        first = sheet_on_table(flat, surface, 0)
        tracker.initialise(first, mask=first.depth_m < TABLE_M - 0.005, background=empty_table())
        caps, estimates = [], []
        for k in range(1, 9):
            estimates.append(tracker.track(sheet_on_table(hinged(UV, k), surface, k)))
            caps.append(tracker.last_assessment.material_cap)
        assert caps[0] == 1.0  # 8 degrees: the shape as laid, give or take a centimetre
        if printed:
            assert caps == [1.0] * 8 and estimates[-1].confidence > UNCONFIRMED_CAP
        else:
            assert caps[-1] == UNCONFIRMED_CAP and estimates[-1].confidence <= UNCONFIRMED_CAP
            assert not estimates[-1].lost


def test_matches_left_behind_by_a_mesh_that_slid_along_a_printed_cloth_unconfirm_it(tex):
    """A mesh slid 8 cm along a printed sheet lying on a table still agrees with the depth
    everywhere; the KLT points following the print stay on their material points, so most of
    them now lie off the mesh, and the confidence is held under 0.5 whatever the other cues
    say. One or two points off, or half of them, do not count."""
    off, on = np.full(MIN_DISAGREEING, 0.05), np.zeros(MIN_DISAGREEING)
    assert matches_cap(off, 0.02) == UNCONFIRMED_CAP
    assert matches_cap(off[:-1], 0.02) == 1.0  # too few to tell a slide from points that slipped
    assert matches_cap(np.concatenate([off, on]), 0.02) == 1.0  # half, not most
    assert matches_cap(np.concatenate([off, on[:-1]]), 0.02) == UNCONFIRMED_CAP
    assert matches_cap(np.zeros(0), 0.02) == 1.0

    flat = hinged(UV, 0)
    caps = {}
    for push in (0.0, 0.08):
        # neither the coarse stage nor a re-acquisition, which would find the print's offset
        # and move the mesh back (what they are for): here the slid mesh itself is under test
        tracker = MeshTracker(TrackerConfig(features="klt", use_boundary=False, coarse_motion=False,
                                            reacquire_every=0))
        first = sheet_on_table(flat, tex, 0)
        tracker.initialise(first, mask=first.depth_m < TABLE_M - 0.005)
        for k in (1, 2):
            tracker.track(sheet_on_table(flat, tex, k))
            assert tracker.last_assessment.material_cap == 1.0
        tracker._V = tracker._V + np.array([push, 0.0, 0.0])
        tracker._V_prev = tracker._V.copy()
        estimate = tracker.track(sheet_on_table(flat, tex, 3))
        caps[push] = (tracker.last_assessment.material_cap, estimate.confidence)
    assert caps[0.0] == (1.0, pytest.approx(1.0, abs=0.05)), caps
    assert caps[0.08][0] == UNCONFIRMED_CAP and caps[0.08][1] <= UNCONFIRMED_CAP, caps


def test_a_held_vertex_follows_the_gripper_where_the_camera_cannot_see_it(tex):
    """A corner lifted 6 cm towards the camera by a gripper that hides it."""
    rest = plane_points(UV, np.array([0.0, 0.0, 1.3]), SIZE)
    tracker = MeshTracker(TrackerConfig(features="klt"))
    e0 = tracker.initialise(frame_of(rest, UV, FACES, tex, CAM, SIZE))
    corner = int(np.argmin(np.linalg.norm(e0.vertices - rest[0], axis=1)))
    d = np.linalg.norm(UV - UV[0], axis=1)
    bent = rest.copy()
    bent[:, 2] -= 0.06 * np.clip(1.0 - d / 0.2, 0.0, 1.0) ** 2  # the corner region lifted
    frame = frame_of(bent, UV, FACES, tex, CAM, SIZE, seq=1)
    hand = np.zeros((480, 640), bool)
    u, v = np.rint(CAM.K[:2, :2] @ (bent[0, :2] / bent[0, 2]) + CAM.K[:2, 2]).astype(int)
    hand[max(0, v - 45):v + 45, max(0, u - 45):u + 45] = True
    frame = dataclasses.replace(frame, occluder_mask=hand)
    target = bent[0]
    held = dataclasses.replace(frame, held_vertices=np.array([corner]), held_points_m=target[None])
    e_free = _track_once(tex, rest, frame)
    e_held = tracker.track(held)
    assert np.linalg.norm(e_held.vertices[corner] - target) < 0.01
    assert np.linalg.norm(e_free.vertices[corner] - target) > 0.03  # hidden, it stays down
    assert "hold" in e_held.energies and "hold" not in e_free.energies
    with pytest.raises(TrackingError, match="held_vertices: vertex"):
        tracker.track(dataclasses.replace(frame, held_vertices=np.array([10_000]), held_points_m=target[None]))


def _track_once(tex, rest, frame):
    tracker = MeshTracker(TrackerConfig(features="klt"))
    tracker.initialise(frame_of(rest, UV, FACES, tex, CAM, SIZE))
    return tracker.track(frame)


def test_frames_name_a_half_given_hold():
    frame = empty_table()
    with pytest.raises(ValueError, match="both or neither"):
        dataclasses.replace(frame, held_vertices=np.array([1]))
    with pytest.raises(ValueError, match="held_points_m: expected \\(1, 3\\)"):
        dataclasses.replace(frame, held_vertices=np.array([1]), held_points_m=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="held_vertices: vertex ids from -1 to -1, expected 0 to"):
        dataclasses.replace(frame, held_vertices=np.array([-1]), held_points_m=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="held_vertices: vertex ids from 4294967301"):  # would wrap to vertex 5
        dataclasses.replace(frame, held_vertices=np.array([2**32 + 5]), held_points_m=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="held_points_m: expected finite metres"):
        dataclasses.replace(frame, held_vertices=np.array([1]), held_points_m=np.full((1, 3), np.nan))


def _reach_ratio(vertices, canonical, faces, held, point):
    """Per vertex: distance from ``point`` over its shortest distance to ``held`` along the flat sheet's mesh."""
    from scipy.sparse.csgraph import dijkstra

    from perception.geometry import edge_length_graph

    along = dijkstra(edge_length_graph(canonical, faces), directed=False, indices=held)
    return np.linalg.norm(vertices - point, axis=1) / np.maximum(along, 1e-9)


@pytest.mark.parametrize("tether", [True, False])
def test_no_vertex_outreaches_the_cloth_from_the_point_held(tex, tether):
    """The robot pulls a corner 30 cm outwards in one frame, its arm hiding all of the sheet but
    that corner: the hidden vertices have no data, and only the tether brings them along."""
    rest = plane_points(UV, np.array([0.0, 0.0, 1.3]), SIZE)
    tracker = MeshTracker(TrackerConfig(features="klt"))
    e0 = tracker.initialise(frame_of(rest, UV, FACES, tex, CAM, SIZE))
    tracker.set_config(dataclasses.replace(tracker.config, tether=tether))  # as the service sets it: from the next frame
    corner = int(np.argmin(np.linalg.norm(e0.vertices - rest[0], axis=1)))
    outwards = rest[0] - rest.mean(axis=0)
    pulled = rest + 0.3 * outwards / np.linalg.norm(outwards)
    frame = frame_of(pulled, UV, FACES, tex, CAM, SIZE, seq=1)
    u, v = np.rint(CAM.K[:2, :2] @ (pulled[0, :2] / pulled[0, 2]) + CAM.K[:2, 2]).astype(int)
    arm = np.ones((480, 640), bool)
    arm[max(0, v - 30):v + 30, max(0, u - 30):u + 30] = False
    frame = dataclasses.replace(frame, occluder_mask=arm, held_vertices=np.array([corner]),
                                held_points_m=pulled[0][None])
    estimate = tracker.track(frame)
    ratio = _reach_ratio(estimate.vertices, e0.canonical, e0.faces, corner, pulled[0])
    ratio[corner] = 0.0
    if tether:  # the 5 % slack, and rest lengths a hair off the sheet's (noise where the mesh was laid)
        assert ratio.max() < 1.06, ratio.max()
    else:  # the hidden far side left behind, stretched
        assert ratio.max() > 1.2, ratio.max()


def _track_turn(tex, with_orientation: bool) -> list:
    """A sheet held at the middle of its top edge, turned 60 degrees about the vertical
    through that point, 4 degrees a frame, its right half behind a known occluder throughout.
    Returns each frame's (mean vertex error (m), or None once the tracker has laid a new mesh;
    its estimate)."""
    rest = plane_points(UV, np.array([0.0, 0.0, 1.3]), SIZE)
    pivot = rest[int(np.argmin(np.linalg.norm(UV - [SIZE[0] / 2, 0.0], axis=1)))]
    hand = np.zeros((480, 640), bool)
    hand[:, 330:] = True
    tracker = MeshTracker(TrackerConfig(features="klt"))
    e0 = tracker.initialise(frame_of(rest, UV, FACES, tex, CAM, SIZE))
    held = int(np.argmin(np.linalg.norm(e0.vertices - pivot, axis=1)))
    tilted = Rotation.from_rotvec([0.3, -0.2, 0.1])  # how the gripper happens to be held: only its turns count
    frames = []
    for k in range(1, 16):
        turn = Rotation.from_rotvec([0.0, np.radians(4.0 * k), 0.0])
        frame = frame_of(turn.apply(rest - pivot) + pivot, UV, FACES, tex, CAM, SIZE, t=k / 30, seq=k)
        frame = dataclasses.replace(frame, occluder_mask=hand, held_vertices=np.array([held]),
                                    held_points_m=pivot[None],
                                    held_quats_xyzw=(turn * tilted).as_quat()[None] if with_orientation else None)
        estimate = tracker.track(frame)
        truth = turn.apply(e0.vertices - pivot) + pivot  # the mesh was laid on the flat sheet
        same_mesh = estimate.vertices.shape == truth.shape
        frames.append((float(np.linalg.norm(estimate.vertices - truth, axis=1).mean()) if same_mesh else None, estimate))
    return frames


def test_a_cloth_the_gripper_turns_is_turned_with_it_where_the_camera_cannot_see_it(tex):
    """Half of the sheet is hidden: those vertices have only the prediction to follow."""
    error, estimate = _track_turn(tex, with_orientation=True)[-1]
    assert error < 0.01, error
    # turned where the robot says it turned it, the hidden half is not taken for unconfirmed
    assert not estimate.lost and estimate.confidence > 0.8, estimate.confidence


def test_without_the_grippers_orientation_the_hidden_half_turns_with_the_half_seen(tex):
    """The hidden half has moved far since the camera saw it, which nothing confirms: the
    estimate follows the turn while it can, and says so when it no longer trusts it. Carried
    by its edges alone (not turned with the half seen), the hidden half was left behind,
    48.8 mm off at the last frame, with confidence 1.0."""
    frames = _track_turn(tex, with_orientation=False)
    followed = [error for error, _ in frames[:8]]
    assert all(e is not None and e < 0.005 for e in followed), followed  # 32 degrees turned
    for error, estimate in frames:
        if error is not None:  # a new mesh's material points cannot be compared
            assert error < 0.015 or estimate.lost, (error, estimate.confidence)


def test_a_mesh_that_lacks_material_the_held_cloth_has_is_lost_not_confident(tex):
    """Cloth does not stretch: none of it lies farther from a point a gripper holds than the
    mesh's material reaches from the vertex held there. A mesh laid on the left 60 % of the
    sheet (a fold hid the rest when it was laid) misses the material beyond it; held at the
    left edge's middle, the sheet measured reaches 1.6 times farther than that mesh does."""
    flat = sheet_on_table(hinged(UV, 0), tex, 0)
    on_sheet = flat.depth_m < TABLE_M - 0.005
    cols = np.nonzero(on_sheet.any(axis=0))[0]
    part = on_sheet.copy()
    part[:, cols[0] + int(0.6 * len(cols)):] = False
    for mask, lacking in ((on_sheet, False), (part, True)):
        tracker = MeshTracker(TrackerConfig(features="klt"))
        e0 = tracker.initialise(flat, mask=mask, background=empty_table())
        C = e0.canonical
        left = C[:, 0] < C[:, 0].min() + 0.01
        held = int(np.flatnonzero(left)[np.argmin(np.abs(C[left, 1] - np.median(C[:, 1])))])
        frame = dataclasses.replace(sheet_on_table(hinged(UV, 0), tex, 1), held_vertices=np.array([held], np.int32),
                                    held_points_m=e0.vertices[[held]], held_quats_xyzw=np.array([[0.0, 0.0, 0.0, 1.0]]))
        e = tracker.track(frame)
        cue = tracker.last_assessment.within_reach
        if lacking:
            assert cue < FLOOR and e.lost, (cue, e.confidence)
        else:
            assert cue == 1.0 and not e.lost and e.confidence > 0.8, tracker.last_assessment
        # a point no gripper holds (the hanging cloth's lowest point, orientation NaN) is no evidence
        unheld = dataclasses.replace(frame, seq=2, timestamp_s=2 / 30, held_quats_xyzw=np.full((1, 4), np.nan))
        tracker.track(unheld)
        assert tracker.last_assessment.within_reach == 1.0


def test_the_reach_ratio_is_the_farthest_measured_over_the_mesh_reach_of_each_held_point():
    from perception.confidence import REACH_ALL, REACH_NONE, reach_ratio, within_reach

    rng = np.random.default_rng(3)
    points = rng.uniform(-1, 1, (2000, 3)) * [0.3, 0.3, 0.0]  # a square 60 cm wide
    held = np.array([[-0.3, 0.0, 0.0], [0.3, 0.0, 0.0]])
    far = np.sqrt(0.6 ** 2 + 0.3 ** 2)  # from the middle of one side to the far corners
    ratio = reach_ratio(points, held, np.array([far, far]))
    assert 0.93 < ratio <= 1.0
    # one held point whose vertex reaches half as far: the largest ratio counts
    assert reach_ratio(points, held, np.array([far, far / 2])) == pytest.approx(2 * ratio)
    assert reach_ratio(np.zeros((0, 3)), held, np.array([1.0, 1.0])) == 0.0
    assert within_reach(REACH_ALL) == 1.0 and within_reach(REACH_NONE) == 0.0 and 0 < within_reach(1.2) < 1
