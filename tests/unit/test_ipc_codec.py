"""Codec: round trip of every message class, framing, depth encodings, and named errors."""

import dataclasses

import msgpack
import numpy as np
import pytest

from ipc import codec
from ipc import messages as m
from ipc.codec import DTYPES, Limits, ProtocolError, decode, encode, peek_type
from ipc.examples import example_messages

EXAMPLES = example_messages()


def assert_same(a, b, path="msg"):
    """Recursive equality of messages: same types, arrays equal in dtype, shape and values."""
    assert type(a) is type(b), f"{path}: {type(a).__name__} != {type(b).__name__}"
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert (a.dtype, a.shape) == (b.dtype, b.shape), path
        assert np.array_equal(a, b), path
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            assert_same(a[k], b[k], f"{path}[{k!r}]")
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def without_nan_depth(msg):
    """What decoding must give: missing depth as 0, never NaN."""
    if isinstance(msg, m.RGBDFrame):
        return dataclasses.replace(msg, depth_m=np.nan_to_num(msg.depth_m, nan=0.0))
    return msg


def header(frames) -> dict:
    return msgpack.unpackb(frames[0])


def repack(top: dict, frames) -> list:
    return [msgpack.packb(top, use_bin_type=True), *frames[1:]]


# -- round trips ---------------------------------------------------------------


def test_every_message_class_travels():
    classes = {obj for obj in vars(m).values()
               if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == m.__name__}
    assert set(codec.MESSAGE_TYPES.values()) == classes
    assert all(codec.MESSAGE_TYPES[cls.__name__] is cls for cls in classes)


def test_schema_lists_exactly_the_dataclass_fields():
    for cls, schema in codec._SCHEMAS.items():
        wire_only = {"depth_scale"} if cls is m.RGBDFrame else set()
        assert set(schema.fields) == {f.name for f in dataclasses.fields(cls)} | wire_only, cls.__name__


@pytest.mark.parametrize("inline_max_bytes", [0, codec.INLINE_MAX_BYTES, 2**40])
@pytest.mark.parametrize("cls", list(EXAMPLES), ids=lambda c: c.__name__)
def test_round_trip(cls, inline_max_bytes):
    msg = EXAMPLES[cls]
    frames = encode(msg, inline_max_bytes=inline_max_bytes)
    assert header(frames)["type"] == cls.__name__ and header(frames)["version"] == m.SCHEMA_VERSION
    out = decode(frames)
    assert_same(without_nan_depth(msg), out)
    assert_same(out, decode(encode(out)))


def _is_default(field: dataclasses.Field, value) -> bool:
    if field.default is not dataclasses.MISSING:
        default = field.default
    elif field.default_factory is not dataclasses.MISSING:
        default = field.default_factory()
    else:
        return False
    if isinstance(value, np.ndarray) or isinstance(default, np.ndarray):
        return isinstance(value, np.ndarray) and isinstance(default, np.ndarray) and np.array_equal(value, default)
    return type(value) is type(default) and value == default


def test_every_field_travels_with_a_value_other_than_its_default():
    """The decoder fills a missing field with its default, so a field the encoder dropped would
    still round-trip where the example holds the default: here every field holds another value."""
    estimate = EXAMPLES[m.MeshEstimate]
    changed = {
        m.CameraInfo: {"frame_id": "left_ir_optical_frame"},
        m.MeshEstimate: {"lost": True, "frame_id": "left_ir_optical_frame"},
        m.GraspPlan: {"frame_id": "left_ir_optical_frame"},
        m.AdjacentCorner: {"tip_offset_m": 0.021},
        m.AdjacentCornersRequest: {"max_candidates": 5, "estimate": estimate, "even_if_lost": True},
        m.AdjacentCornersReply: {"held_vertex": 17},
        m.StatusReply: {"lost_streak": 4},
        m.Heartbeat: {"period_s": 0.25},
    }
    for cls, msg in EXAMPLES.items():
        msg = dataclasses.replace(msg, **changed.get(cls, {}))
        left = [f.name for f in dataclasses.fields(cls) if _is_default(f, getattr(msg, f.name))]
        assert not left, f"{cls.__name__}: {left} hold their defaults; give them other values above"
        assert_same(without_nan_depth(msg), decode(encode(msg)))


def test_status_reply_nil_measurements_travel_as_nil():
    fields = header(encode(m.StatusReply()))["fields"]
    for name in ("frame_age_s", "latency_ms_median", "latency_ms_p99", "tracking_ms_median", "confidence"):
        assert name in fields and fields[name] is None, name
    full = EXAMPLES[m.StatusReply]
    assert decode(encode(full)).rejected_by_kind == full.rejected_by_kind == {"no_depth": 2, "camera_changed": 1}


def test_round_trip_of_optional_parts_left_out():
    for msg in [m.GraspRequest(), m.InitialiseRequest(), m.GraspPlanReply(), m.StatusReply(), m.CameraInfo(2, 2, np.eye(3)),
                m.AdjacentCornersRequest(held_vertex=3), m.AdjacentCornersReply()]:
        assert_same(msg, decode(encode(msg)))


def test_a_corners_measured_tip_and_a_request_even_if_lost_travel():
    ahead, behind = EXAMPLES[m.AdjacentCornersReply].candidates
    reply = dataclasses.replace(EXAMPLES[m.AdjacentCornersReply],
                                candidates=(dataclasses.replace(ahead, tip_offset_m=0.031), behind))
    got = decode(encode(reply))
    assert [c.tip_offset_m for c in got.candidates] == [0.031, None]
    fields = header(encode(reply))["fields"]
    assert [c["tip_offset_m"] for c in fields["candidates"]] == [0.031, None]  # nil, never NaN
    request = m.AdjacentCornersRequest(held_vertex=3, even_if_lost=True)
    assert decode(encode(request)).even_if_lost is True
    assert header(encode(m.AdjacentCornersRequest(held_vertex=3)))["fields"]["even_if_lost"] is False


def test_missing_optional_fields_take_their_defaults():
    frames = encode(m.StatusReply(request_id=3))
    top = header(frames)
    top["fields"] = {"request_id": 3}
    assert_same(m.StatusReply(request_id=3), decode(repack(top, frames)))


def test_large_arrays_go_as_buffer_frames_without_copy():
    rng = np.random.default_rng(1)
    cam = m.CameraInfo.from_fov(64, 48, 1.0)
    frame = m.RGBDFrame(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), rng.uniform(0.2, 4, (48, 64)).astype(np.float32), cam)
    frames = encode(frame, inline_max_bytes=1000)
    # header, rgb (9216 bytes), depth (12288 bytes); K and D (small) stay inline
    assert [len(f) for f in frames[1:]] == [48 * 64 * 3, 48 * 64 * 4]
    assert np.shares_memory(np.frombuffer(frames[1], np.uint8), frame.rgb)
    buffers = [bytearray(f) for f in frames]
    out = decode(buffers)
    assert np.shares_memory(out.rgb, np.frombuffer(buffers[1], np.uint8))
    assert np.shares_memory(out.depth_m, np.frombuffer(buffers[2], np.float32))


def test_single_frame_when_everything_inline():
    assert len(encode(EXAMPLES[m.RGBDFrame], inline_max_bytes=2**40)) == 1


def test_peek_type_reads_only_the_header():
    frames = encode(EXAMPLES[m.RGBDFrame], inline_max_bytes=0)
    assert peek_type(frames[:1]) is m.RGBDFrame
    with pytest.raises(ProtocolError, match="header"):
        peek_type([b"\xc1"])


# -- depth ---------------------------------------------------------------------


@pytest.mark.parametrize("scale", [1000.0, 5000.0])
def test_uint16_depth_rounds_to_the_scale(scale):
    msg = EXAMPLES[m.RGBDFrame]
    frames = encode(msg, depth_scale=scale)
    fields = header(frames)["fields"]
    assert (fields["depth_m"]["dtype"], fields["depth_scale"]) == ("uint16", scale)
    out = decode(frames)
    expected = np.nan_to_num(msg.depth_m, nan=0.0)
    assert out.depth_m.dtype == np.float32
    assert np.all(np.abs(out.depth_m - expected) <= 0.5 / scale + 1e-6)
    assert np.array_equal(out.depth_m == 0, expected == 0)  # missing stays missing, measured stays measured
    assert out.depth_m[2, 3] == pytest.approx(0.001)


def test_uint16_depth_raw_values():
    depth = np.array([[0.0, 1.0, 2.0]], np.float32)
    frame = m.RGBDFrame(np.zeros((1, 3, 3), np.uint8), depth, m.CameraInfo(3, 1, np.eye(3)))
    fields = header(encode(frame, depth_scale=5000, inline_max_bytes=2**20))["fields"]
    assert np.frombuffer(fields["depth_m"]["data"], "<u2").tolist() == [0, 5000, 10000]


def test_uint16_depth_beyond_range_is_refused():
    frame = m.RGBDFrame(np.zeros((1, 2, 3), np.uint8), np.array([[1.0, 70.0]], np.float32), m.CameraInfo(2, 1, np.eye(3)))
    with pytest.raises(ProtocolError, match=r"RGBDFrame\.depth_m: 70\.000 m exceeds the uint16 range at depth_scale 1000"):
        encode(frame, depth_scale=1000)
    with pytest.raises(ProtocolError, match="depth_scale must be a positive number"):
        encode(frame, depth_scale=0.0)


def test_uint16_depth_without_scale_is_refused():
    frames = encode(EXAMPLES[m.RGBDFrame], depth_scale=1000)
    top = header(frames)
    top["fields"]["depth_scale"] = None
    with pytest.raises(ProtocolError, match=r"RGBDFrame\.depth_scale: required for uint16 depth"):
        decode(repack(top, frames))
    del top["fields"]["depth_scale"]
    with pytest.raises(ProtocolError, match=r"RGBDFrame\.depth_scale: required for uint16 depth"):
        decode(repack(top, frames))


def test_float_depth_with_scale_is_refused():
    frames = encode(EXAMPLES[m.RGBDFrame])
    top = header(frames)
    top["fields"]["depth_scale"] = 1000.0
    with pytest.raises(ProtocolError, match=r"RGBDFrame\.depth_scale: must be nil or absent for float32"):
        decode(repack(top, frames))


# -- errors name what was wrong ------------------------------------------------


def mutated(msg, edit, **encode_kw):
    """Frames of ``msg`` after ``edit(fields)`` changed its decoded header fields in place."""
    frames = encode(msg, **encode_kw)
    top = header(frames)
    edit(top["fields"])
    return repack(top, frames)


def set_array(fields, name, values, dtype):
    fields[name] = {"dtype": dtype, "shape": list(np.shape(values)), "data": np.asarray(values, DTYPES[dtype]).tobytes()}


CASES = [
    (m.StatusRequest, lambda f: f.update(extra=1), r"^StatusRequest: unknown field 'extra'$"),
    (m.StatusRequest, lambda f: f.update({b"request_id": f.pop("request_id", 0)}),
     r"^StatusRequest: field names are str, got a bytes key b'request_id'$"),
    (m.Heartbeat, lambda f: f.pop("source"), r"^Heartbeat: missing required field 'source'$"),
    (m.StatusRequest, lambda f: f.update(request_id="7"), r"^StatusRequest\.request_id: expected an integer, got str$"),
    (m.StatusRequest, lambda f: f.update(request_id=True), r"StatusRequest\.request_id: expected an integer, got bool"),
    (m.StatusRequest, lambda f: f.update(request_id=-1), r"StatusRequest\.request_id: expected an integer in \[0, "),
    (m.Heartbeat, lambda f: f.update(timestamp_s=float("nan")), r"Heartbeat\.timestamp_s: expected a finite number, got nan"),
    (m.Heartbeat, lambda f: f.update(period_s=float("inf")), r"Heartbeat\.period_s: expected a finite number, got inf"),
    (m.MeshEstimate, lambda f: f.update(timing_ms=-1.0), r"MeshEstimate\.timing_ms: expected a number >= 0"),
    (m.MeshEstimate, lambda f: f["energies"].update(depth=float("-inf")),
     r"MeshEstimate\.energies\['depth'\]: expected a finite number"),
    (m.MeshEstimate, lambda f: f.update(lost=1), r"MeshEstimate\.lost: expected a bool, got int"),
    (m.MeshEstimate, lambda f: f.update(confidence=1.5), r"MeshEstimate\.confidence: expected a value in \[0, 1\]"),
    (
        m.MeshEstimate,
        lambda f: set_array(f, "vertices", [[0, 0, np.inf]] * 4, "float64"),
        r"MeshEstimate\.vertices: contains NaN or infinite",
    ),
    (m.MeshEstimate, lambda f: set_array(f, "faces", [[0, 1, 9]], "int32"), r"MeshEstimate\.faces: vertex ids outside \[0, 4\)"),
    (
        m.MeshEstimate,
        lambda f: set_array(f, "faces", [[0, 1, 2]], "float64"),
        r"MeshEstimate\.faces: dtype 'float64' not allowed; expected one of \('int32',\)",
    ),
    (
        m.MeshEstimate,
        lambda f: set_array(f, "boundary", [[0, 1]], "int32"),
        r"MeshEstimate\.boundary: expected a shape of 1 non-negative integers",
    ),
    (m.GraspPlan, lambda f: set_array(f, "position", [0, np.nan, 1], "float64"),
     r"GraspPlan\.position: contains NaN or infinite"),
    (m.GraspPlan, lambda f: f.update(kind="middle"), r"GraspPlan\.kind: expected one of"),
    (m.GraspPlan, lambda f: f.update(vertex_id=-3), r"GraspPlan\.vertex_id: expected an integer in \[0, "),
    (m.RGBDFrame, lambda f: set_array(f, "depth_m", np.full((3, 4), np.inf), "float32"),
     r"RGBDFrame\.depth_m: infinite depth values"),
    (m.RGBDFrame, lambda f: set_array(f, "depth_m", np.full((3, 4), -1.0), "float32"),
     r"RGBDFrame\.depth_m: negative depth values"),
    (
        m.RGBDFrame,
        lambda f: set_array(f, "depth_m", np.ones((3, 5)), "float32"),
        r"RGBDFrame\.depth_m: expected shape \(3, 4\), got \(3, 5\)",
    ),
    (m.RGBDFrame, lambda f: set_array(f["camera"], "K", np.eye(3) * np.nan, "float64"),
     r"RGBDFrame\.camera: CameraInfo\.K: contains NaN"),
    (m.RGBDFrame, lambda f: f["camera"].update(width=0), r"RGBDFrame\.camera\.width: expected an integer in \[1, 65535\], got 0"),
    (m.RGBDFrame, lambda f: f.update(camera=[1, 2]), r"RGBDFrame\.camera: expected a map of fields, got list"),
    (m.RGBDFrame, lambda f: f["rgb"].update(shape=[3, 4]),
     r"RGBDFrame\.rgb: expected a shape of 3 non-negative integers, got \[3, 4\]"),
    (m.RGBDFrame, lambda f: f["rgb"].update(shape=[3, -4, 3]), r"RGBDFrame\.rgb: expected a shape of 3 non-negative integers"),
    (
        m.RGBDFrame,
        lambda f: f["rgb"].update(shape=[2**40, 2**40, 3]),
        r"RGBDFrame\.rgb: declared shape \[1099511627776, 1099511627776, 3\] needs \d+ bytes, over the limit",
    ),
    (
        m.RGBDFrame,
        lambda f: f["rgb"].update(shape=[3, 4, 4]),
        r"RGBDFrame\.rgb: declared uint8 shape \[3, 4, 4\] needs 48 bytes but inline data has 36",
    ),
    (m.RGBDFrame, lambda f: f["rgb"].update(dtype="object"), r"RGBDFrame\.rgb: dtype 'object' not allowed"),
    (m.RGBDFrame, lambda f: f["rgb"].update(data="abc"), r"RGBDFrame\.rgb: expected bin data, got str"),
    (m.RGBDFrame, lambda f: f["rgb"].update(extra=1),
     r"RGBDFrame\.rgb: expected an array map with keys dtype, shape and data or frame"),
    (m.RGBDFrame, lambda f: f["rgb"].update(frame=1), r"RGBDFrame\.rgb: expected an array map"),
    (m.GraspRequest, lambda f: f.update(kinds="corner"), r"GraspRequest\.kinds: expected an array, got str"),
    (m.GraspRequest, lambda f: f["estimate"].update(iterations=-1),
     r"GraspRequest\.estimate\.iterations: expected an integer in \[0, "),
    (m.GraspPlanReply, lambda f: f["candidates"].reverse(), r"GraspPlanReply\.candidates: expected best first"),
    (
        m.GraspPlanReply,
        lambda f: f["candidates"][1].update(score="high"),
        r"GraspPlanReply\.candidates\[1\]\.score: expected a number, got str",
    ),
    (m.AdjacentCorner, lambda f: f.update(side=0), r"^AdjacentCorner\.side: expected \+1 or -1, got 0$"),
    (m.AdjacentCorner, lambda f: f.update(side=2), r"^AdjacentCorner\.side: expected an integer in \[-1, 1\], got 2$"),
    (m.AdjacentCorner, lambda f: f["plan"].update(kind="boundary"), r"AdjacentCorner\.plan: expected a grasp of kind 'corner'"),
    (m.AdjacentCorner, lambda f: f.update(visible=1.5), r"AdjacentCorner\.visible: expected a number in \[0, 1\], got 1\.5"),
    (m.AdjacentCorner, lambda f: f.update(material_distance_m=-1.0), r"AdjacentCorner\.material_distance_m: expected"),
    (m.AdjacentCorner, lambda f: f.update(reachable=1), r"AdjacentCorner\.reachable: expected a bool, got int"),
    (m.AdjacentCorner, lambda f: f.update(tip_offset_m=-0.01),
     r"AdjacentCorner\.tip_offset_m: expected a number >= 0\.0, got -0\.01"),
    (m.AdjacentCornersRequest, lambda f: f.update(even_if_lost=1),
     r"AdjacentCornersRequest\.even_if_lost: expected a bool, got int"),
    (m.AdjacentCornersRequest, lambda f: f.pop("held_vertex"),
     r"^AdjacentCornersRequest: missing required field 'held_vertex'$"),
    (m.AdjacentCornersRequest, lambda f: f.update(held_vertex=-1),
     r"AdjacentCornersRequest\.held_vertex: expected an integer in \[0, "),
    (m.AdjacentCornersRequest, lambda f: f.update(max_candidates=0),
     r"AdjacentCornersRequest\.max_candidates: expected an integer in \[1, 100\], got 0"),
    (m.AdjacentCornersReply, lambda f: f["candidates"].reverse(), r"AdjacentCornersReply\.candidates: expected best first"),
    (m.AdjacentCornersReply, lambda f: f["candidates"][1].update(side=1),
     r"AdjacentCornersReply\.candidates: expected at most one corner per side"),
    (m.AdjacentCornersReply, lambda f: f["candidates"][0]["plan"].update(kind="highest"),
     r"AdjacentCornersReply\.candidates\[0\].*expected a grasp of kind 'corner', got 'highest'"),
    (m.AdjacentCornersReply, lambda f: f.update(held_outline_vertex=-2),
     r"AdjacentCornersReply\.held_outline_vertex: expected an integer in \[-1, "),
    (
        m.SetParametersRequest,
        lambda f: f["parameters"].update(x=[1]),
        r"SetParametersRequest\.parameters\['x'\]: expected bool, int, float or str, got list",
    ),
    (m.SetParametersRequest, lambda f: f.update(parameters={}),
     r"SetParametersRequest\.parameters: expected at least one parameter"),
    (m.InitialiseRequest, lambda f: set_array(f, "mask", np.zeros((2, 2)), "uint8"),
     r"InitialiseRequest\.mask: no non-zero pixel"),
    (m.ErrorReply, lambda f: f.update(code="bad"), r"ErrorReply\.code: expected one of"),
    (m.StatusReply, lambda f: f.update(message=b"ok"), r"StatusReply\.message: expected a string, got bytes"),
    (m.StatusReply, lambda f: f.update(frames_dropped=-1),
     r"^StatusReply\.frames_dropped: expected an integer in \[0, \d+\], got -1$"),
    (m.StatusReply, lambda f: f.update(frames_received=3.0), r"^StatusReply\.frames_received: expected an integer, got float$"),
    (m.StatusReply, lambda f: f.update(messages_malformed=None),
     r"StatusReply\.messages_malformed: expected an integer, got NoneType"),
    (m.StatusReply, lambda f: f["rejected_by_kind"].update(no_depth=-2),
     r"StatusReply\.rejected_by_kind\['no_depth'\]: expected an integer in \[0, "),
    (m.StatusReply, lambda f: f["rejected_by_kind"].update(no_depth=5),
     r"StatusReply\.rejected_by_kind: counts sum to 6, expected frames_rejected = 3"),
    (m.StatusReply, lambda f: f.update(latency_ms_median="fast"),
     r"^StatusReply\.latency_ms_median: expected a number, got str$"),
    (m.StatusReply, lambda f: f.update(latency_ms_p99=float("nan")),
     r"StatusReply\.latency_ms_p99: expected a finite number, got nan"),
    (m.StatusReply, lambda f: f.update(tracking_ms_median=-1.0),
     r"StatusReply\.tracking_ms_median: expected a number >= 0\.0, got -1\.0"),
    (m.StatusReply, lambda f: f.update(uptime_s=None), r"StatusReply\.uptime_s: expected a number, got NoneType"),
    (m.StatusReply, lambda f: f.update(confidence=1.25),
     r"StatusReply\.confidence: expected a number in \[0, 1\] or None, got 1\.25"),
    (m.StatusReply, lambda f: f.update(source="gone"), r"StatusReply\.source: expected one of"),
]


@pytest.mark.parametrize("cls, edit, match", CASES, ids=[f"{c.__name__}-{i}" for i, (c, _, _) in enumerate(CASES)])
def test_bad_field_is_named(cls, edit, match):
    frames = mutated(EXAMPLES[cls], edit, inline_max_bytes=2**20)
    with pytest.raises(ProtocolError, match=match) as info:
        decode(frames)
    assert "\n" not in str(info.value)


def test_header_errors():
    frames = encode(EXAMPLES[m.StatusRequest])
    top = header(frames)
    for key, value, match in [
        ("version", 1, rf"^header\.version: unsupported schema version 1; this decoder speaks {m.SCHEMA_VERSION}$"),
        ("version", 1.0, r"header\.version: unsupported schema version 1\.0"),
        ("version", "1", r"header\.version: unsupported schema version '1'"),
        ("type", "Pickle", r"^header\.type: unknown message type 'Pickle'$"),
        ("type", 7, r"header\.type: unknown message type 7"),
        ("fields", [1], r"StatusRequest: expected a map of fields, got list"),
    ]:
        with pytest.raises(ProtocolError, match=match):
            decode(repack({**top, key: value}, frames))
    with pytest.raises(ProtocolError, match=r"header: expected a map with keys type, version, fields; got \['fields', 'type'\]"):
        decode(repack({"type": "StatusRequest", "fields": {}}, frames))
    with pytest.raises(ProtocolError, match="header: expected a map with keys type, version, fields; got 'list'"):
        decode([msgpack.packb([1, 2])])
    with pytest.raises(ProtocolError, match=r"header: not valid msgpack \(ExtraData"):
        decode([frames[0] + b"\x00"])
    with pytest.raises(ProtocolError, match="message has no frames"):
        decode([])
    with pytest.raises(ProtocolError, match="frames must be byte buffers"):
        decode([12])


def test_extension_types_and_duplicate_keys_are_refused():
    pickled = msgpack.ExtType(1, b"\x80\x04N.")
    ext = msgpack.packb({"type": "StatusRequest", "version": m.SCHEMA_VERSION, "fields": {"request_id": pickled}})
    with pytest.raises(ProtocolError, match="msgpack extension type 1 is not allowed"):
        decode([ext])
    # Hand-made map with the key "request_id" twice: a second value must not shadow the first.
    body = b"\x82" + msgpack.packb("request_id") + b"\x01" + msgpack.packb("request_id") + b"\x02"
    dup = (
        b"\x83"
        + msgpack.packb("type")
        + msgpack.packb("StatusRequest")
        + msgpack.packb("version")
        + msgpack.packb(m.SCHEMA_VERSION)
        + msgpack.packb("fields")
        + body
    )
    with pytest.raises(ProtocolError, match="duplicate map key 'request_id'"):
        decode([dup])


def test_frame_references_are_checked():
    mask_only = m.InitialiseRequest(request_id=7, mask=EXAMPLES[m.InitialiseRequest].mask)
    frames = encode(mask_only, inline_max_bytes=0)
    assert len(frames) == 2
    with pytest.raises(ProtocolError, match=r"InitialiseRequest\.mask: frame index 1 outside \[1, 0\]"):
        decode(frames[:1])
    with pytest.raises(ProtocolError, match="InitialiseRequest: frame 2 is not referenced by any array"):
        decode([*frames, b"spare"])
    match = r"InitialiseRequest\.mask: declared uint8 shape \[3, 4\] needs 12 bytes but frame 1 has 11"
    with pytest.raises(ProtocolError, match=match):
        decode([frames[0], bytes(frames[1])[:-1]])
    top = header(frames)
    top["fields"]["mask"]["frame"] = True
    with pytest.raises(ProtocolError, match=r"frame index True outside"):
        decode(repack(top, frames))
    est = encode(EXAMPLES[m.MeshEstimate], inline_max_bytes=0)
    top = header(est)
    top["fields"]["faces"]["frame"] = top["fields"]["vertices"]["frame"]
    with pytest.raises(ProtocolError, match=r"MeshEstimate\.faces: frame 1 is referenced twice"):
        decode(repack(top, est))


def test_limits_are_checked_before_decoding():
    frames = encode(EXAMPLES[m.RGBDFrame], inline_max_bytes=0)
    total = sum(len(f) for f in frames)
    with pytest.raises(ProtocolError, match=f"message of {total} bytes exceeds the limit of 100"):
        decode(frames, Limits(max_message_bytes=100))
    with pytest.raises(ProtocolError, match=f"message has {len(frames)} frames, over the limit of 2"):
        decode(frames, Limits(max_frames=2))
    with pytest.raises(ProtocolError, match=r"RGBDFrame\.rgb: declared shape \[3, 4, 3\] needs 36 bytes, over the limit of 20"):
        decode(frames, Limits(max_array_bytes=20))
    with pytest.raises(ProtocolError, match=r"Heartbeat\.source: string of 10 characters exceeds the limit of 4"):
        decode(encode(EXAMPLES[m.Heartbeat]), Limits(max_string_chars=4))
    with pytest.raises(ProtocolError, match="not valid msgpack"):
        decode(encode(EXAMPLES[m.GraspPlanReply]), Limits(max_items=1))
    with pytest.raises(ValueError, match=r"Limits\.max_frames: expected a positive integer, got 0"):
        Limits(max_frames=0)


def test_encode_refuses_what_cannot_travel():
    with pytest.raises(ProtocolError, match="encode: dict is not a message type"):
        encode({"type": "StatusRequest"})
    bad = dataclasses.replace(EXAMPLES[m.MeshEstimate])
    object.__setattr__(bad, "timestamp_s", float("nan"))  # bypasses the constructor, as a buggy producer might
    with pytest.raises(ProtocolError, match=r"MeshEstimate\.timestamp_s: expected a finite number, got nan"):
        encode(bad)
    with pytest.raises(ProtocolError, match="inline_max_bytes must be a non-negative integer"):
        encode(EXAMPLES[m.StatusRequest], inline_max_bytes=-1)


def test_big_endian_arrays_travel_little_endian():
    est = EXAMPLES[m.MeshEstimate]
    swapped = dataclasses.replace(est, vertices=est.vertices.astype(">f8"))
    fields = header(encode(swapped))["fields"]
    assert np.array_equal(np.frombuffer(fields["vertices"]["data"], "<f8").reshape(-1, 3), est.vertices)
