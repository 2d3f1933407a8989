"""Constructors of the request, reply and heartbeat messages: values kept, bad input named."""

import math

import numpy as np
import pytest

from ipc import messages as m
from ipc.examples import example_messages
from ipc.messages import CameraInfo, RGBDFrame


def test_examples_cover_every_message_class():
    classes = {
        obj for obj in vars(m).values()
        if isinstance(obj, type) and obj.__module__ == m.__name__ and hasattr(obj, "__dataclass_fields__")
    }
    assert classes == set(example_messages())


def test_grasp_request_defaults_and_conversion():
    r = m.GraspRequest()
    assert (r.request_id, r.max_candidates, r.kinds, r.estimate) == (0, 5, m.GraspPlan.KINDS, None)
    assert m.GraspRequest(kinds=["corner"], max_candidates=np.int64(3)).kinds == ("corner",)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"request_id": -1}, r"GraspRequest\.request_id"),
        ({"request_id": 1.5}, r"GraspRequest\.request_id"),
        ({"max_candidates": 0}, r"GraspRequest\.max_candidates"),
        ({"max_candidates": 101}, r"GraspRequest\.max_candidates"),
        ({"kinds": ()}, r"GraspRequest\.kinds"),
        ({"kinds": ("corner", "corner")}, r"GraspRequest\.kinds"),
        ({"kinds": ("middle",)}, r"GraspRequest\.kinds"),
        ({"kinds": "corner"}, r"GraspRequest\.kinds: .*string"),
        ({"estimate": "mesh"}, r"GraspRequest\.estimate"),
    ],
)
def test_grasp_request_rejects(kwargs, match):
    with pytest.raises(ValueError, match=match):
        m.GraspRequest(**kwargs)


def test_grasp_plan_reply_orders_best_first():
    ex = example_messages()[m.GraspPlanReply]
    assert [c.score for c in ex.candidates] == [0.8, 0.5]
    assert m.GraspPlanReply().candidates == ()
    with pytest.raises(ValueError, match=r"GraspPlanReply\.candidates: expected best first"):
        m.GraspPlanReply(candidates=ex.candidates[::-1])
    with pytest.raises(ValueError, match=r"GraspPlanReply\.candidates\[0\]: expected GraspPlan"):
        m.GraspPlanReply(candidates=("corner",))


def test_grasp_plan_with_a_huge_component_is_refused_in_one_line_without_a_warning():
    import warnings

    plan = example_messages()[m.GraspPlanReply].candidates[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a corrupt message must not make NumPy warn in a service's log
        with pytest.raises(ValueError, match=r"^GraspPlan\.quat_xyzw: expected a unit quaternion, got norm inf$"):
            m.GraspPlan(position=plan.position, approach=plan.approach, quat_xyzw=[1e300, 0.0, 0.0, 1.0],
                        opening_width_m=0.04, score=0.5, vertex_id=1, kind="corner")
        with pytest.raises(ValueError, match=r"^GraspPlan\.approach: expected a unit vector, got norm 2$"):
            m.GraspPlan(position=plan.position, approach=[0.0, 0.0, 2.0], quat_xyzw=plan.quat_xyzw,
                        opening_width_m=0.04, score=0.5, vertex_id=1, kind="corner")


def test_adjacent_corner_checks_its_fields():
    ex = example_messages()[m.AdjacentCorner]
    assert (ex.side, ex.material_distance_m, ex.visible, ex.reachable) == (1, 0.1, 1.0, True)
    plan = ex.plan
    ok = {"plan": plan, "side": np.int64(-1), "material_distance_m": 0, "visible": np.float32(0.5), "reachable": np.bool_(0)}
    corner = m.AdjacentCorner(**ok)
    assert (corner.side, corner.material_distance_m, corner.visible, corner.reachable) == (-1, 0.0, 0.5, False)
    assert [type(v) for v in (corner.side, corner.material_distance_m, corner.visible, corner.reachable)] == \
           [int, float, float, bool]
    boundary = m.GraspPlan(position=plan.position, approach=plan.approach, quat_xyzw=plan.quat_xyzw,
                           opening_width_m=0.04, score=0.5, vertex_id=1, kind="boundary")
    for change, match in [
        ({"plan": boundary}, r"^AdjacentCorner\.plan: expected a grasp of kind 'corner', got 'boundary'$"),
        ({"plan": "corner"}, r"^AdjacentCorner\.plan: expected GraspPlan, got str$"),
        ({"side": 0}, r"^AdjacentCorner\.side: expected \+1 or -1, got 0$"),
        ({"side": True}, r"^AdjacentCorner\.side: expected \+1 or -1, got True$"),
        ({"side": 1.0}, r"^AdjacentCorner\.side: expected \+1 or -1, got 1\.0$"),
        ({"material_distance_m": -0.1}, r"^AdjacentCorner\.material_distance_m: expected a number >= 0, got -0\.1$"),
        ({"material_distance_m": math.inf}, r"AdjacentCorner\.material_distance_m: expected a number >= 0"),
        ({"visible": 1.5}, r"^AdjacentCorner\.visible: expected a number in \[0, 1\], got 1\.5$"),
        ({"visible": math.nan}, r"AdjacentCorner\.visible: expected a number in \[0, 1\], got nan"),
        ({"reachable": 1}, r"^AdjacentCorner\.reachable: expected a bool, got 1$"),
        ({"tip_offset_m": -0.01}, r"^AdjacentCorner\.tip_offset_m: expected a number >= 0 or None, got -0\.01$"),
        ({"tip_offset_m": math.nan}, r"AdjacentCorner\.tip_offset_m: expected a number >= 0 or None, got nan"),
    ]:
        with pytest.raises(ValueError, match=match):
            m.AdjacentCorner(**{**ok, **change})


def test_adjacent_corners_request_needs_a_held_vertex():
    r = m.AdjacentCornersRequest(held_vertex=np.int32(7))
    assert (r.request_id, r.held_vertex, r.max_candidates, r.estimate, r.even_if_lost) == (0, 7, 2, None, False)
    assert type(r.held_vertex) is int
    with pytest.raises(TypeError, match="held_vertex"):
        m.AdjacentCornersRequest()
    for kwargs, match in [
        ({"held_vertex": -1}, r"^AdjacentCornersRequest\.held_vertex: expected a non-negative integer, got -1$"),
        ({"held_vertex": 2.0}, r"AdjacentCornersRequest\.held_vertex: expected a non-negative integer, got 2\.0"),
        ({"held_vertex": 1, "max_candidates": 0}, r"^AdjacentCornersRequest\.max_candidates: expected an integer in \[1, 100\]"),
        ({"held_vertex": 1, "max_candidates": 101}, r"AdjacentCornersRequest\.max_candidates"),
        ({"held_vertex": 1, "request_id": -2}, r"AdjacentCornersRequest\.request_id"),
        ({"held_vertex": 1, "estimate": "mesh"}, r"^AdjacentCornersRequest\.estimate: expected MeshEstimate or None, got str$"),
        ({"held_vertex": 1, "even_if_lost": 1}, r"^AdjacentCornersRequest\.even_if_lost: expected a bool, got 1$"),
    ]:
        with pytest.raises(ValueError, match=match):
            m.AdjacentCornersRequest(**kwargs)


def test_adjacent_corners_reply_orders_best_first_one_per_side():
    ex = example_messages()[m.AdjacentCornersReply]
    assert [(c.side, c.plan.score) for c in ex.candidates] == [(1, 0.95), (-1, 0.0)]
    assert m.AdjacentCornersReply().candidates == () and m.AdjacentCornersReply().held_outline_vertex == -1
    ahead, behind = ex.candidates
    for kwargs, match in [
        ({"candidates": (behind, ahead)}, r"AdjacentCornersReply\.candidates: expected best first \(non-increasing plan "
                                          r"scores\), got scores \[0\.0, 0\.95\]"),
        ({"candidates": (ahead, ahead)}, r"^AdjacentCornersReply\.candidates: expected at most one corner per side, "
                                         r"got sides \[1, 1\]$"),
        ({"candidates": (ahead.plan,)}, r"AdjacentCornersReply\.candidates\[0\]: expected AdjacentCorner, got GraspPlan"),
        ({"held_outline_vertex": -2}, r"^AdjacentCornersReply\.held_outline_vertex: expected a vertex id >= 0 or -1, got -2$"),
        ({"held_vertex": -1}, r"AdjacentCornersReply\.held_vertex"),
    ]:
        with pytest.raises(ValueError, match=match):
            m.AdjacentCornersReply(**kwargs)


def test_initialise_request_mask():
    assert m.InitialiseRequest().mask is None
    mask = m.InitialiseRequest(mask=np.eye(3, dtype=bool)).mask
    assert mask.dtype == np.uint8 and mask.shape == (3, 3)
    with pytest.raises(ValueError, match=r"InitialiseRequest\.mask: no non-zero pixel"):
        m.InitialiseRequest(mask=np.zeros((4, 5), np.uint8))
    with pytest.raises(ValueError, match=r"InitialiseRequest\.mask: expected shape \(N, N\), got \(4,\)"):
        m.InitialiseRequest(mask=np.ones(4, np.uint8))
    with pytest.raises(ValueError, match=r"InitialiseRequest\.mask: expected dtype uint8"):
        m.InitialiseRequest(mask=np.ones((2, 2), np.float32))


def test_parameters_keep_their_types():
    p = m.SetParametersRequest(parameters={"a": np.float32(0.5), "b": np.int64(3), "c": np.bool_(True), "d": "sift"}).parameters
    assert p == {"a": 0.5, "b": 3, "c": True, "d": "sift"}
    assert [type(v) for v in p.values()] == [float, int, bool, str]


@pytest.mark.parametrize(
    "params, match",
    [
        ({}, "at least one parameter"),
        ({"": 1.0}, "non-empty strings"),
        ({3: 1.0}, "non-empty strings"),
        ({"a": math.nan}, r"\['a'\]: expected a finite number"),
        ({"a": [1, 2]}, r"\['a'\]: expected bool, int, float or str, got list"),
        ([("a", 1)], "expected a dict"),
    ],
)
def test_set_parameters_rejects(params, match):
    with pytest.raises(ValueError, match=match):
        m.SetParametersRequest(parameters=params)


def test_status_reply():
    assert m.StatusReply().state == "idle"
    assert m.StatusReply(parameters={}).parameters == {}
    with pytest.raises(ValueError, match=r"StatusReply\.state: expected one of"):
        m.StatusReply(state="running")
    with pytest.raises(ValueError, match=r"StatusReply\.frames_processed"):
        m.StatusReply(frames_processed=-1)
    with pytest.raises(ValueError, match=r"StatusReply\.message: expected a single-line"):
        m.StatusReply(message="two\nlines")


def test_status_reply_counters_and_measurements():
    reply = m.StatusReply(frames_received=np.int64(5), frames_rejected=3, rejected_by_kind={"no_depth": 2, "tracker": 1},
                          latency_ms_median=np.float32(2.5), confidence=1)
    assert reply.frames_received == 5 and type(reply.frames_received) is int
    assert reply.latency_ms_median == 2.5 and type(reply.latency_ms_median) is float
    assert reply.confidence == 1.0 and reply.latency_ms_p99 is None and reply.frame_age_s is None
    assert m.StatusReply().source == "waiting" and m.StatusReply().rejected_by_kind == {}


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"frames_dropped": -1}, r"^StatusReply\.frames_dropped: expected a non-negative integer, got -1$"),
        ({"frames_received": 2.0}, r"StatusReply\.frames_received: expected a non-negative integer, got 2\.0"),
        ({"lost_streak": True}, r"StatusReply\.lost_streak: expected a non-negative integer, got True"),
        ({"uptime_s": None}, r"^StatusReply\.uptime_s: expected a number >= 0, got None$"),
        ({"uptime_s": -0.5}, r"StatusReply\.uptime_s: expected a number >= 0, got -0\.5"),
        ({"latency_ms_median": math.nan}, r"^StatusReply\.latency_ms_median: expected a number >= 0 or None, got nan$"),
        ({"latency_ms_p99": math.inf}, r"StatusReply\.latency_ms_p99: expected a number >= 0 or None, got inf"),
        ({"tracking_ms_median": "3"}, r"StatusReply\.tracking_ms_median: expected a number >= 0 or None, got '3'"),
        ({"frame_age_s": -1.0}, r"StatusReply\.frame_age_s: expected a number >= 0 or None"),
        ({"confidence": 1.5}, r"^StatusReply\.confidence: expected a number in \[0, 1\] or None, got 1\.5$"),
        ({"source": "gone"}, r"StatusReply\.source: expected one of \('waiting', 'live', 'stale'\), got 'gone'"),
        ({"rejected_by_kind": [("no_depth", 1)]}, r"StatusReply\.rejected_by_kind: expected a dict, got list"),
        ({"rejected_by_kind": {"": 0}}, r"StatusReply\.rejected_by_kind: kinds must be non-empty strings"),
        ({"frames_rejected": 1, "rejected_by_kind": {"no_depth": -1}},
         r"StatusReply\.rejected_by_kind\['no_depth'\]: expected a non-negative integer, got -1"),
        ({"frames_rejected": 2, "rejected_by_kind": {"no_depth": 1}},
         r"^StatusReply\.rejected_by_kind: counts sum to 1, expected frames_rejected = 2$"),
    ],
)
def test_status_reply_rejects(kw, match):
    with pytest.raises(ValueError, match=match):
        m.StatusReply(**kw)


def test_error_reply():
    e = m.ErrorReply("not_ready", "no estimate yet", request_id=4)
    assert (e.code, e.message, e.request_id) == ("not_ready", "no estimate yet", 4)
    with pytest.raises(ValueError, match=r"ErrorReply\.code"):
        m.ErrorReply("oops", "x")
    with pytest.raises(ValueError, match=r"ErrorReply\.message"):
        m.ErrorReply("internal", "")
    with pytest.raises(ValueError, match=r"ErrorReply\.message"):
        m.ErrorReply("internal", "a\nb")


def test_heartbeat():
    h = m.Heartbeat("frames", seq=2, timestamp_s=1, period_s=0.5)
    assert (h.seq, h.timestamp_s, h.period_s) == (2, 1.0, 0.5)
    for kwargs, match in [
        ({"source": ""}, r"Heartbeat\.source"),
        ({"source": "x", "seq": -1}, r"Heartbeat\.seq"),
        ({"source": "x", "timestamp_s": math.inf}, r"Heartbeat\.timestamp_s"),
        ({"source": "x", "period_s": 0}, r"Heartbeat\.period_s"),
    ]:
        with pytest.raises(ValueError, match=match):
            m.Heartbeat(**kwargs)


@pytest.mark.parametrize("cls", [m.ResetRequest, m.StatusRequest])
def test_plain_requests(cls):
    assert cls(request_id=5).request_id == 5
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.request_id"):
        cls(request_id=-2)


def test_rgbd_frame_refuses_integers_it_would_have_to_guess_or_wrap():
    cam = CameraInfo.from_fov(8, 6, np.deg2rad(60))
    rgb, depth = np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32)
    with pytest.raises(ValueError, match=r"depth_m: expected float metres, got uint16 \(integer depth comes with its scale"):
        RGBDFrame(rgb, (depth * 1000).astype(np.uint16), cam)  # millimetres: never guess a scale
    with pytest.raises(ValueError, match=r"rgb: values from 4095 to 4095 do not fit uint8"):
        RGBDFrame(np.full((6, 8, 3), 4095, np.uint16), depth, cam)  # 12-bit colour would wrap modulo 256
    assert RGBDFrame(rgb.astype(np.int64), depth, cam).rgb.dtype == np.uint8  # values that fit are kept
