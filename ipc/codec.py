"""msgpack codec for the messages of ``ipc.messages``; the wire format of docs/protocol.md.

One message travels as a list of frames (ZeroMQ multipart message parts):

- frame 0, the header: a msgpack map ``{"type": str, "version": int, "fields": map}``;
- frames 1..n: raw array buffers that the header references by index.

An array field is a msgpack map ``{"dtype": str, "shape": [int, ...], "data": bin}``
(inline) or ``{"dtype": str, "shape": [int, ...], "frame": int}`` (a buffer frame),
little-endian, C order. Large arrays (images) go as buffer frames so that neither side
copies them; a decoder accepts either form for any array.

Decoding trusts nothing: every check failure, from bad msgpack to a negative depth, is a
``ProtocolError`` (a ValueError) with a one-line message naming the field. Sizes are
checked against ``Limits`` before anything is allocated. There is no pickle and no
msgpack extension type on the wire; an extension type is refused.

Decoded arrays may be read-only views on the received buffers (zero copy): copy one
before writing to it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import msgpack
import numpy as np

from ipc import messages as m

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_LIMITS",
    "DTYPES",
    "INLINE_MAX_BYTES",
    "Limits",
    "MESSAGE_TYPES",
    "ProtocolError",
    "decode",
    "encode",
    "peek_type",
]


class ProtocolError(ValueError):
    """A message that breaks the wire protocol; the text is one line naming what was wrong."""


@dataclass(frozen=True)
class Limits:
    """Size caps that a decoder enforces before allocating.

    max_message_bytes : all frames of one message together, bytes
    max_array_bytes : one declared array (product of its shape times item size), bytes
    max_frames : frames in one message, header included
    max_string_chars : one string field, characters
    max_items : entries of one msgpack array or map (lists, dicts, shapes)
    """

    max_message_bytes: int = 64 * 2**20
    max_array_bytes: int = 64 * 2**20
    max_frames: int = 32
    max_string_chars: int = 64 * 2**10
    max_items: int = 100_000

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"Limits.{f.name}: expected a positive integer, got {value!r}")


DEFAULT_LIMITS = Limits()

#: Arrays up to this many bytes are written inline in the header; larger ones go as
#: buffer frames. At 16 KiB a MeshEstimate of a few hundred vertices stays one frame
#: while images, whose copy would cost more than the extra frame, are sent zero-copy.
INLINE_MAX_BYTES = 16 * 2**10

#: Wire dtype names and their NumPy dtypes; every array travels little-endian.
DTYPES = {
    "uint8": np.dtype("<u1"),
    "uint16": np.dtype("<u2"),
    "int32": np.dtype("<i4"),
    "float32": np.dtype("<f4"),
    "float64": np.dtype("<f8"),
}

_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
_UINT16_MAX = np.iinfo(np.uint16).max


def _short(value, limit: int = 60) -> str:
    """repr of a received value cut to ``limit`` characters, so an error stays one short line."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _one_line(text: str, limit: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ---------------------------------------------------------------------------
# Encoding and decoding state


class _Out:
    """What encoding one message accumulates: the buffer frames, plus the sender's options."""

    def __init__(self, inline_max_bytes: int, depth_scale: float | None):
        self.frames: list = []
        self.inline_max_bytes = inline_max_bytes
        self.depth_scale = depth_scale


class _In:
    """The received frames and limits while decoding one message; tracks frames used."""

    def __init__(self, frames: Sequence[memoryview], limits: Limits):
        self.frames = frames
        self.limits = limits
        self.used: set[int] = set()


# ---------------------------------------------------------------------------
# Field specifications: the wire type of each field. Values that the message
# constructors check (shapes, ranges of the numerical fields) are left to them;
# a spec checks what the wire needs: msgpack type, dtype, size, finiteness.


class _Spec:
    """How one field travels: ``encode`` gives the msgpack value, ``decode`` checks and reverses it."""

    def encode(self, value, out: _Out, where: str):
        raise NotImplementedError

    def decode(self, obj, inp: _In, where: str):
        raise NotImplementedError


class _Int(_Spec):
    """An integer in [lo, hi] (at most int64); msgpack int of any width, never bool."""

    def __init__(self, lo: int = _INT64_MIN, hi: int = _INT64_MAX):
        self.lo, self.hi = lo, hi

    def _check(self, value, where: str) -> int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise ProtocolError(f"{where}: expected an integer, got {type(value).__name__}")
        value = int(value)
        if not self.lo <= value <= self.hi:
            raise ProtocolError(f"{where}: expected an integer in [{self.lo}, {self.hi}], got {value}")
        return value

    def encode(self, value, out, where):
        return self._check(value, where)

    def decode(self, obj, inp, where):
        return self._check(obj, where)


class _Float(_Spec):
    """A finite number; msgpack float 32/64 or int on the wire, Python float in memory."""

    def __init__(self, lo: float | None = None, positive: bool = False):
        self.lo, self.positive = lo, positive

    def _check(self, value, where: str) -> float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ProtocolError(f"{where}: expected a number, got {type(value).__name__}")
        value = float(value)
        if not math.isfinite(value):
            raise ProtocolError(f"{where}: expected a finite number, got {value}")
        if self.positive and value <= 0:
            raise ProtocolError(f"{where}: expected a positive number, got {value}")
        if self.lo is not None and value < self.lo:
            raise ProtocolError(f"{where}: expected a number >= {self.lo}, got {value}")
        return value

    def encode(self, value, out, where):
        return self._check(value, where)

    def decode(self, obj, inp, where):
        return self._check(obj, where)


class _Bool(_Spec):
    """msgpack bool."""

    def encode(self, value, out, where):
        if not isinstance(value, (bool, np.bool_)):
            raise ProtocolError(f"{where}: expected a bool, got {type(value).__name__}")
        return bool(value)

    def decode(self, obj, inp, where):
        if not isinstance(obj, bool):
            raise ProtocolError(f"{where}: expected a bool, got {type(obj).__name__}")
        return obj


class _Str(_Spec):
    """msgpack str (UTF-8), at most ``Limits.max_string_chars`` characters."""

    def encode(self, value, out, where):
        if not isinstance(value, str):
            raise ProtocolError(f"{where}: expected a string, got {type(value).__name__}")
        return value

    def decode(self, obj, inp, where):
        if not isinstance(obj, str):
            raise ProtocolError(f"{where}: expected a string, got {type(obj).__name__}")
        if len(obj) > inp.limits.max_string_chars:
            raise ProtocolError(f"{where}: string of {len(obj)} characters exceeds the limit of {inp.limits.max_string_chars}")
        return obj


class _Scalar(_Spec):
    """A parameter value: bool, int (int64), finite float or str, each kept as its type."""

    _int, _float, _bool, _str = _Int(), _Float(), _Bool(), _Str()

    def _pick(self, value, where) -> _Spec:
        if isinstance(value, (bool, np.bool_)):
            return self._bool
        if isinstance(value, (int, np.integer)):
            return self._int
        if isinstance(value, (float, np.floating)):
            return self._float
        if isinstance(value, str):
            return self._str
        raise ProtocolError(f"{where}: expected bool, int, float or str, got {type(value).__name__}")

    def encode(self, value, out, where):
        return self._pick(value, where).encode(value, out, where)

    def decode(self, obj, inp, where):
        return self._pick(obj, where).decode(obj, inp, where)


class _Optional(_Spec):
    """``inner`` or nil."""

    def __init__(self, inner: _Spec):
        self.inner = inner

    def encode(self, value, out, where):
        return None if value is None else self.inner.encode(value, out, where)

    def decode(self, obj, inp, where):
        return None if obj is None else self.inner.decode(obj, inp, where)


class _List(_Spec):
    """msgpack array of ``item``; a tuple in memory."""

    def __init__(self, item: _Spec):
        self.item = item

    def encode(self, value, out, where):
        return [self.item.encode(v, out, f"{where}[{i}]") for i, v in enumerate(value)]

    def decode(self, obj, inp, where):
        if not isinstance(obj, list):
            raise ProtocolError(f"{where}: expected an array, got {type(obj).__name__}")
        return tuple(self.item.decode(v, inp, f"{where}[{i}]") for i, v in enumerate(obj))


class _Map(_Spec):
    """msgpack map, str -> ``value``; a dict in memory."""

    def __init__(self, value: _Spec):
        self.value = value

    def encode(self, value, out, where):
        if not isinstance(value, dict):
            raise ProtocolError(f"{where}: expected a dict, got {type(value).__name__}")
        return {_Str().encode(k, out, where): self.value.encode(v, out, f"{where}[{k!r}]") for k, v in value.items()}

    def decode(self, obj, inp, where):
        if not isinstance(obj, dict):
            raise ProtocolError(f"{where}: expected a map, got {type(obj).__name__}")
        result = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise ProtocolError(f"{where}: expected string keys, got {_short(k)}")
            result[_Str().decode(k, inp, where)] = self.value.decode(v, inp, f"{where}[{_short(k, 40)}]")
        return result


class _Array(_Spec):
    """An array map with one of ``dtypes`` and ``ndim`` dimensions."""

    _KEYS = ({"dtype", "shape", "data"}, {"dtype", "shape", "frame"})

    def __init__(self, dtypes: tuple[str, ...], ndim: int):
        self.dtypes, self.ndim = dtypes, ndim

    def encode(self, value, out, where):
        arr = np.asarray(value)
        name = next((n for n in self.dtypes if DTYPES[n].kind == arr.dtype.kind and DTYPES[n].itemsize == arr.dtype.itemsize), None)
        if name is None:
            raise ProtocolError(f"{where}: dtype {arr.dtype} cannot travel; expected one of {self.dtypes}")
        if arr.ndim != self.ndim:
            raise ProtocolError(f"{where}: expected {self.ndim} dimensions, got shape {arr.shape}")
        # Converts only when the array is strided or big-endian; otherwise a no-op view.
        arr = np.ascontiguousarray(arr, dtype=DTYPES[name])
        head = {"dtype": name, "shape": list(arr.shape)}
        if arr.nbytes > out.inline_max_bytes:
            out.frames.append(memoryview(arr).cast("B"))
            head["frame"] = len(out.frames)
        else:
            head["data"] = arr.tobytes()
        return head

    def decode(self, obj, inp, where):
        if not isinstance(obj, dict) or set(obj) not in self._KEYS:
            keys = sorted(map(str, obj)) if isinstance(obj, dict) else type(obj).__name__
            raise ProtocolError(f"{where}: expected an array map with keys dtype, shape and data or frame, got {_short(keys)}")
        name = obj["dtype"]
        if not isinstance(name, str) or name not in self.dtypes:
            raise ProtocolError(f"{where}: dtype {_short(name)} not allowed; expected one of {self.dtypes}")
        shape = obj["shape"]
        if (
            not isinstance(shape, list)
            or len(shape) != self.ndim
            or any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in shape)
        ):
            raise ProtocolError(f"{where}: expected a shape of {self.ndim} non-negative integers, got {_short(shape)}")
        dtype = DTYPES[name]
        nbytes = math.prod(shape) * dtype.itemsize  # Python ints: no overflow for absurd shapes
        if nbytes > inp.limits.max_array_bytes:
            raise ProtocolError(f"{where}: declared shape {shape} needs {nbytes} bytes, over the limit of {inp.limits.max_array_bytes}")
        if "data" in obj:
            buf = obj["data"]
            if not isinstance(buf, bytes):
                raise ProtocolError(f"{where}: expected bin data, got {type(buf).__name__}")
            source = "inline data"
        else:
            index = obj["frame"]
            if isinstance(index, bool) or not isinstance(index, int) or not 1 <= index < len(inp.frames):
                raise ProtocolError(f"{where}: frame index {_short(index)} outside [1, {len(inp.frames) - 1}]")
            if index in inp.used:
                raise ProtocolError(f"{where}: frame {index} is referenced twice")
            inp.used.add(index)
            buf = inp.frames[index]
            source = f"frame {index}"
        if len(buf) != nbytes:
            raise ProtocolError(f"{where}: declared {name} shape {shape} needs {nbytes} bytes but {source} has {len(buf)}")
        return np.frombuffer(buf, dtype=dtype).reshape(shape)


class _Message(_Spec):
    """A message as a map of its fields, nested or at the top of the header.

    fields : name -> spec, in wire order; dataclass fields without a default are required
    to_wire : optional, message -> dict of the values to encode (for wire-only fields)
    from_wire : optional, (decoded fields, where) -> constructor keyword arguments
    """

    def __init__(self, cls: type, fields: dict[str, _Spec], to_wire: Callable | None = None, from_wire: Callable | None = None):
        self.cls, self.fields = cls, fields
        self.to_wire, self.from_wire = to_wire, from_wire
        self.required = {
            f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        }

    def encode(self, value, out, where):
        if type(value) is not self.cls:
            raise ProtocolError(f"{where}: expected {self.cls.__name__}, got {type(value).__name__}")
        values = self.to_wire(value, out) if self.to_wire else {n: getattr(value, n) for n in self.fields}
        return {n: spec.encode(values[n], out, f"{where}.{n}") for n, spec in self.fields.items()}

    def decode(self, obj, inp, where):
        if not isinstance(obj, dict):
            raise ProtocolError(f"{where}: expected a map of fields, got {type(obj).__name__}")
        for name in obj:
            if name not in self.fields:
                raise ProtocolError(f"{where}: unknown field {_short(name)}")
        missing = sorted(self.required - obj.keys())
        if missing:
            raise ProtocolError(f"{where}: missing required field {missing[0]!r}")
        kwargs = {n: self.fields[n].decode(v, inp, f"{where}.{n}") for n, v in obj.items()}
        if self.from_wire:
            kwargs = self.from_wire(kwargs, where)
        try:
            return self.cls(**kwargs)
        except (ValueError, TypeError, ArithmeticError) as e:
            # The constructors name the class and field themselves; add the path only when nested.
            prefix = "" if where == self.cls.__name__ else f"{where}: "
            raise ProtocolError(_one_line(f"{prefix}{e}")) from None


# ---------------------------------------------------------------------------
# Depth: float32 metres, or uint16 with depth_scale units per metre.


def _bool_to_wire(mask: np.ndarray | None) -> np.ndarray | None:
    """A bool array travels as uint8 (0 or 1), viewed without a copy."""
    return None if mask is None else mask.view(np.uint8)


def _rgbd_to_wire(frame: m.RGBDFrame, out: _Out) -> dict:
    values = {n: getattr(frame, n) for n in ("rgb", "camera", "timestamp_s", "seq")}
    values["occluder_mask"] = _bool_to_wire(frame.occluder_mask)
    scale = out.depth_scale
    if scale is None:
        values["depth_m"], values["depth_scale"] = frame.depth_m, None
        return values
    # In place on one float32 array: this runs for every frame of a sensor publisher.
    # float32 resolves 1/256 unit at 65535 units, so rounding to the nearest unit is right.
    units = frame.depth_m * np.float32(scale)
    np.fmax(units, 0.0, out=units)  # fmax drops NaN (missing) for the 0; depth is never negative
    far = float(units.max(initial=0.0))
    if far > _UINT16_MAX + 0.5:
        raise ProtocolError(
            f"RGBDFrame.depth_m: {far / scale:.3f} m exceeds the uint16 range at depth_scale {scale:g} (max {_UINT16_MAX / scale:.3f} m)"
        )
    np.rint(units, out=units)
    values["depth_m"] = units.astype(np.uint16)
    values["depth_scale"] = scale
    return values


def _rgbd_from_wire(kwargs: dict, where: str) -> dict:
    scale = kwargs.pop("depth_scale", None)
    depth = kwargs.get("depth_m")
    if depth.dtype == np.uint16:
        if scale is None:
            raise ProtocolError(f"{where}.depth_scale: required for uint16 depth (units per metre), got none")
        kwargs["depth_m"] = np.divide(depth, scale, dtype=np.float32)
    elif scale is not None:
        raise ProtocolError(f"{where}.depth_scale: must be nil or absent for float32 depth, got {scale}")
    elif np.isnan(depth.min()):  # min is NaN iff some value is: one fast pass
        # Missing depth is 0 in memory whatever the sender used, so readers test one value.
        kwargs["depth_m"] = np.where(np.isnan(depth), np.float32(0), depth)
    return kwargs


# ---------------------------------------------------------------------------
# The schema of every message


def _schemas() -> dict[type, _Message]:
    f64 = ("float64",)
    timestamp, seq, request_id, count = _Float(), _Int(), _Int(lo=0), _Int(lo=0)
    time_or_nil = _Optional(_Float(lo=0.0))  # a duration >= 0, nil while nothing was measured
    camera = _Message(
        m.CameraInfo,
        {
            "width": _Int(1, 65535),
            "height": _Int(1, 65535),
            "K": _Array(f64, 2),
            "D": _Array(f64, 1),
            "frame_id": _Str(),
        },
    )
    estimate = _Message(
        m.MeshEstimate,
        {
            "vertices": _Array(f64, 2),
            "faces": _Array(("int32",), 2),
            "boundary": _Array(("int32",), 1),
            "canonical": _Array(f64, 2),
            "timestamp_s": timestamp,
            "seq": seq,
            "energies": _Map(_Float()),
            "iterations": _Int(lo=0),
            "confidence": _Float(),
            "lost": _Bool(),
            "timing_ms": _Float(lo=0.0),
            "frame_id": _Str(),
            "visible": _Optional(_Array(("uint8",), 1)),
        },
        to_wire=lambda est, out: {**{f.name: getattr(est, f.name) for f in dataclasses.fields(est)},
                                  "visible": _bool_to_wire(est.visible)},
    )
    plan = _Message(
        m.GraspPlan,
        {
            "position": _Array(f64, 1),
            "approach": _Array(f64, 1),
            "quat_xyzw": _Array(f64, 1),
            "opening_width_m": _Float(),
            "score": _Float(),
            "vertex_id": _Int(lo=0),
            "kind": _Str(),
            "frame_id": _Str(),
            "timestamp_s": timestamp,
        },
    )
    schemas = [
        camera,
        _Message(
            m.RGBDFrame,
            {
                "rgb": _Array(("uint8",), 3),
                "depth_m": _Array(("float32", "uint16"), 2),
                "depth_scale": _Optional(_Float(positive=True)),
                "camera": camera,
                "timestamp_s": timestamp,
                "seq": seq,
                "occluder_mask": _Optional(_Array(("uint8",), 2)),
            },
            to_wire=_rgbd_to_wire,
            from_wire=_rgbd_from_wire,
        ),
        estimate,
        plan,
        _Message(
            m.GraspRequest,
            {
                "request_id": request_id,
                "max_candidates": _Int(),
                "kinds": _List(_Str()),
                "estimate": _Optional(estimate),
            },
        ),
        _Message(
            m.GraspPlanReply,
            {"request_id": request_id, "candidates": _List(plan), "estimate_seq": seq},
        ),
        _Message(m.InitialiseRequest, {"request_id": request_id, "mask": _Optional(_Array(("uint8",), 2))}),
        _Message(
            m.OccluderMaskRequest,
            {"request_id": request_id, "mask": _Optional(_Array(("uint8",), 2)), "seq": _Int(lo=-1)},
        ),
        _Message(m.ResetRequest, {"request_id": request_id}),
        _Message(m.SetParametersRequest, {"request_id": request_id, "parameters": _Map(_Scalar())}),
        _Message(m.StatusRequest, {"request_id": request_id}),
        _Message(
            m.StatusReply,
            {
                "request_id": request_id,
                "state": _Str(),
                "frames_processed": count,
                "last_seq": seq,
                "parameters": _Map(_Scalar()),
                "message": _Str(),
                "uptime_s": _Float(lo=0.0),
                "source": _Str(),
                "frame_age_s": time_or_nil,
                "frames_received": count,
                "frames_tracked": count,
                "frames_dropped": count,
                "frames_rejected": count,
                "rejected_by_kind": _Map(count),
                "messages_malformed": count,
                "latency_ms_median": time_or_nil,
                "latency_ms_p99": time_or_nil,
                "tracking_ms_median": time_or_nil,
                "confidence": _Optional(_Float(lo=0.0)),
                "lost_streak": count,
                "reinitialisations": count,
                "discontinuities": count,
            },
        ),
        _Message(m.ErrorReply, {"code": _Str(), "message": _Str(), "request_id": request_id}),
        _Message(
            m.Heartbeat,
            {"source": _Str(), "seq": _Int(lo=0), "timestamp_s": timestamp, "period_s": _Float(positive=True)},
        ),
    ]
    return {s.cls: s for s in schemas}


_SCHEMAS = _schemas()

#: Type tag -> message class, for every message that can travel.
MESSAGE_TYPES: dict[str, type] = {cls.__name__: cls for cls in _SCHEMAS}


# ---------------------------------------------------------------------------
# Public functions


def encode(msg, *, depth_scale: float | None = None, inline_max_bytes: int = INLINE_MAX_BYTES) -> list:
    """Encode a message into frames: ``[header, buffer, ...]``.

    msg : an instance of a class in ``MESSAGE_TYPES``
    depth_scale : for an RGBDFrame (also nested), send depth as uint16 with this many
        units per metre (1000 = millimetres, 5000 = TUM); None sends float32 metres.
        Depth rounds to the nearest unit; depth beyond 65535 units is refused.
    inline_max_bytes : arrays up to this size go inside the header, larger ones as
        buffer frames; 0 sends every non-empty array as a frame, a huge value gives
        a single frame.

    Returns a list of ``bytes`` (header) and ``memoryview`` (buffers, zero-copy views
    on the message's arrays: do not modify the arrays until the frames are sent).
    Raises ProtocolError (a ValueError) when a value cannot be represented on the wire.
    """
    schema = _SCHEMAS.get(type(msg))
    if schema is None:
        raise ProtocolError(f"encode: {type(msg).__name__} is not a message type; expected one of {sorted(MESSAGE_TYPES)}")
    if depth_scale is not None and not (math.isfinite(depth_scale) and depth_scale > 0):
        raise ProtocolError(f"encode: depth_scale must be a positive number, got {depth_scale}")
    if isinstance(inline_max_bytes, bool) or not isinstance(inline_max_bytes, int) or inline_max_bytes < 0:
        raise ProtocolError(f"encode: inline_max_bytes must be a non-negative integer, got {inline_max_bytes!r}")
    out = _Out(inline_max_bytes, None if depth_scale is None else float(depth_scale))
    fields = schema.encode(msg, out, type(msg).__name__)
    header = msgpack.packb({"type": type(msg).__name__, "version": m.SCHEMA_VERSION, "fields": fields}, use_bin_type=True)
    return [header, *out.frames]


def _unique_pairs(pairs: list) -> dict:
    """msgpack map hook: a duplicate key would silently shadow a field, so refuse it."""
    result = dict(pairs)
    if len(result) != len(pairs):
        seen = set()
        dup = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise ProtocolError(f"duplicate map key {_short(dup)}")
    return result


def _refuse_ext(code: int, data: bytes):
    raise ProtocolError(f"msgpack extension type {code} is not allowed")


def _unpack_header(header, limits: Limits) -> tuple[_Message, dict]:
    try:
        top = msgpack.unpackb(
            header,
            raw=False,
            strict_map_key=True,
            object_pairs_hook=_unique_pairs,
            ext_hook=_refuse_ext,
            max_array_len=limits.max_items,
            max_map_len=limits.max_items,
        )
    except ProtocolError:
        raise
    except Exception as e:  # msgpack signals bad input with several exception types
        raise ProtocolError(_one_line(f"header: not valid msgpack ({type(e).__name__}: {e})")) from None
    if not isinstance(top, dict) or set(top) != {"type", "version", "fields"}:
        got = sorted(map(str, top)) if isinstance(top, dict) else type(top).__name__
        raise ProtocolError(f"header: expected a map with keys type, version, fields; got {_short(got)}")
    version = top["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version != m.SCHEMA_VERSION:
        raise ProtocolError(f"header.version: unsupported schema version {_short(version)}; this decoder speaks {m.SCHEMA_VERSION}")
    cls = MESSAGE_TYPES.get(top["type"]) if isinstance(top["type"], str) else None
    if cls is None:
        raise ProtocolError(f"header.type: unknown message type {_short(top['type'])}")
    return _SCHEMAS[cls], top["fields"]


def _views(frames: Sequence, limits: Limits) -> list[memoryview]:
    if len(frames) == 0:
        raise ProtocolError("message has no frames; expected a header frame")
    if len(frames) > limits.max_frames:
        raise ProtocolError(f"message has {len(frames)} frames, over the limit of {limits.max_frames}")
    try:
        views = [memoryview(f).cast("B") for f in frames]
    except TypeError as e:
        raise ProtocolError(_one_line(f"frames must be byte buffers ({e})")) from None
    total = sum(v.nbytes for v in views)
    if total > limits.max_message_bytes:
        raise ProtocolError(f"message of {total} bytes exceeds the limit of {limits.max_message_bytes}")
    return views


def peek_type(frames: Sequence, limits: Limits = DEFAULT_LIMITS) -> type:
    """The message class named by a message's header, checking only the header's envelope.

    Cheap (no array is touched): lets a receiver route or drop messages before
    decoding them. Raises ProtocolError as ``decode`` would for the header.
    """
    schema, _ = _unpack_header(_views(frames, limits)[0], limits)
    return schema.cls


def decode(frames: Sequence, limits: Limits = DEFAULT_LIMITS):
    """Decode frames (bytes, memoryview, zmq.Frame or any byte buffer) into a message.

    Validates everything: sizes against ``limits`` first, then the header, type tag,
    schema version, field names and types, array dtypes, shapes and buffer sizes, and
    the message's own constructor checks. Every frame after the header must be
    referenced by exactly one array. An RGBDFrame's depth is returned as float32
    metres with 0 where missing, whatever it travelled as.

    Raises ProtocolError, and only ProtocolError, for any bad input.
    """
    try:
        views = _views(frames, limits)
        schema, fields = _unpack_header(views[0], limits)
        inp = _In(views, limits)
        msg = schema.decode(fields, inp, schema.cls.__name__)
        unused = sorted(set(range(1, len(views))) - inp.used)
        if unused:
            raise ProtocolError(f"{schema.cls.__name__}: frame {unused[0]} is not referenced by any array")
        return msg
    except ProtocolError:
        raise
    except Exception as e:
        # The contract is that bad input never raises anything else; reaching this is a
        # decoder bug, logged with its traceback so it gets fixed.
        log.exception("internal decoder error")
        raise ProtocolError(_one_line(f"internal decoder error ({type(e).__name__}: {e})")) from None
