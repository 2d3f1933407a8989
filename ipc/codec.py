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

The schema of every message is derived from its dataclass (``ipc.messages.MESSAGES``):
the fields in their declared order, each with the wire type it declares (``ipc.wire``).
The one field that exists on the wire only is an ``RGBDFrame``'s ``depth_scale`` (depth
sent as uint16 units, section 6 of the protocol).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence

import msgpack
import numpy as np

from ipc import messages as m
from ipc import wire
from ipc.wire import (
    DEFAULT_LIMITS,
    DTYPES,
    INLINE_MAX_BYTES,
    Incoming,
    Limits,
    Message,
    Outgoing,
    ProtocolError,
    _one_line,
    _short,
)

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



# ---------------------------------------------------------------------------
# Depth: float32 metres, or uint16 with depth_scale units per metre.

_UINT16_MAX = np.iinfo(np.uint16).max


def _rgbd_to_wire(frame: m.RGBDFrame, out: Outgoing) -> dict:
    values = {f.name: getattr(frame, f.name) for f in dataclasses.fields(frame)}
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
            f"RGBDFrame.depth_m: {far / scale:.3f} m exceeds the uint16 range at depth_scale {scale:g} "
            f"(max {_UINT16_MAX / scale:.3f} m)"
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


def _resolved(spec: wire.Spec, schemas: dict) -> wire.Spec:
    """``spec`` with each nested message (``wire.Nested``) replaced by that message's schema."""
    if isinstance(spec, wire.Nested):
        return schemas[spec.cls]
    if isinstance(spec, wire.Optional):
        return wire.Optional(_resolved(spec.inner, schemas))
    if isinstance(spec, wire.List):
        return wire.List(_resolved(spec.item, schemas))
    if isinstance(spec, wire.Map):
        return wire.Map(_resolved(spec.value, schemas))
    return spec


def _schema(cls: type, schemas: dict) -> Message:
    """The schema of one message class, from its fields' declared wire types (in field order)."""
    fields = {}
    for f in dataclasses.fields(cls):
        spec = wire.spec_of(f)
        if spec is None:
            raise TypeError(f"{cls.__name__}.{f.name}: no wire type declared (ipc.wire.field)")
        fields[f.name] = _resolved(spec, schemas)
        if cls is m.RGBDFrame and f.name == "depth_m":
            fields["depth_scale"] = wire.Optional(wire.Float(positive=True))  # on the wire only, after depth_m
    if cls is m.RGBDFrame:
        return Message(cls, fields, to_wire=_rgbd_to_wire, from_wire=_rgbd_from_wire)
    return Message(cls, fields)


def _schemas() -> dict[type, Message]:
    schemas: dict[type, Message] = {}
    for cls in m.MESSAGES:  # a nested message comes before the messages holding it
        schemas[cls] = _schema(cls, schemas)
    return schemas


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
    out = Outgoing(inline_max_bytes, None if depth_scale is None else float(depth_scale))
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


def _readable_request_id(fields) -> int:
    """The ``request_id`` of a message that failed to decode, when its header's fields hold
    a valid one (so that the error reply can carry it); else 0."""
    rid = fields.get("request_id") if isinstance(fields, dict) else None
    ok = isinstance(rid, int) and not isinstance(rid, bool) and 0 <= rid < 2**63
    return rid if ok else 0


def _unpack_header(header, limits: Limits) -> tuple[Message, dict]:
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
        why = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
        raise ProtocolError(_one_line(f"header: not valid msgpack ({why})")) from None
    if not isinstance(top, dict) or set(top) != {"type", "version", "fields"}:
        got = sorted(map(str, top)) if isinstance(top, dict) else type(top).__name__
        raise ProtocolError(f"header: expected a map with keys type, version, fields; got {_short(got)}")
    version = top["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version != m.SCHEMA_VERSION:
        raise ProtocolError(f"header.version: unsupported schema version {_short(version)}; "
                            f"this decoder speaks {m.SCHEMA_VERSION}")
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
    fields = None
    try:
        views = _views(frames, limits)
        schema, fields = _unpack_header(views[0], limits)
        inp = Incoming(views, limits)
        msg = schema.decode(fields, inp, schema.cls.__name__)
        unused = sorted(set(range(1, len(views))) - inp.used)
        if unused:
            raise ProtocolError(f"{schema.cls.__name__}: frame {unused[0]} is not referenced by any array")
        return msg
    except ProtocolError as e:
        e.request_id = _readable_request_id(fields)
        raise
    except Exception as e:
        # The contract is that bad input never raises anything else; reaching this is a
        # decoder bug, logged with its traceback so it gets fixed.
        log.exception("internal decoder error")
        raise ProtocolError(_one_line(f"internal decoder error ({type(e).__name__}: {e})")) from None
