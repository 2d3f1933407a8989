"""The wire types of message fields: how each field of an ``ipc.messages`` dataclass travels.

A message dataclass declares, for each field, the wire type it travels as, with ``field``
(``dataclasses.field`` plus the type in the metadata); ``ipc.codec`` derives every
message's schema from those declarations, so a field is declared once. A wire type
(``Spec``) encodes a value to the msgpack value the wire carries and decodes (and checks)
it back: integers with bounds, finite floats, bools, strings, parameter scalars, nil-able
values, lists, maps, NumPy arrays (inline or as buffer frames, docs/protocol.md section
3.2) and nested messages. Values that the message constructors check (shapes, ranges of
the numerical fields) are left to them; a wire type checks what the wire needs: msgpack
type, dtype, size, finiteness. Every failure is a ``ProtocolError`` with one line naming
the field. NumPy only: msgpack itself is the codec's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DEFAULT_LIMITS",
    "DTYPES",
    "INLINE_MAX_BYTES",
    "Array",
    "Bool",
    "Float",
    "Int",
    "Limits",
    "List",
    "Map",
    "Message",
    "Nested",
    "Optional",
    "ProtocolError",
    "Scalar",
    "Spec",
    "Str",
    "field",
]

class ProtocolError(ValueError):
    """A message that breaks the wire protocol; the text is one line naming what was wrong.

    ``request_id`` : the message's ``request_id`` when ``decode`` could read a valid one
    from its header despite the error, else 0 (an error reply carries it)."""

    request_id: int = 0


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


def _short(value, limit: int = 60) -> str:
    """repr of a received value cut to ``limit`` characters, so an error stays one short line."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _one_line(text: str, limit: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ---------------------------------------------------------------------------
# Encoding and decoding state


class Outgoing:
    """What encoding one message accumulates: the buffer frames, plus the sender's options."""

    def __init__(self, inline_max_bytes: int, depth_scale: float | None):
        self.frames: list = []
        self.inline_max_bytes = inline_max_bytes
        self.depth_scale = depth_scale


class Incoming:
    """The received frames and limits while decoding one message; tracks frames used."""

    def __init__(self, frames: Sequence[memoryview], limits: Limits):
        self.frames = frames
        self.limits = limits
        self.used: set[int] = set()


def field(spec: Spec, **kwargs) -> dataclasses.Field:
    """A message dataclass field that travels as ``spec``; ``kwargs`` as ``dataclasses.field``
    (``default``, ``default_factory``); without a default the field is required on the wire."""
    return dataclasses.field(metadata={"wire": spec}, **kwargs)


def spec_of(f: dataclasses.Field) -> Spec | None:
    """The wire type a dataclass field was declared with (``field``), or None."""
    return f.metadata.get("wire")


# ---------------------------------------------------------------------------
# Field specifications: the wire type of each field. Values that the message
# constructors check (shapes, ranges of the numerical fields) are left to them;
# a spec checks what the wire needs: msgpack type, dtype, size, finiteness.


class Spec:
    """How one field travels: ``encode`` gives the msgpack value, ``decode`` checks and reverses it."""

    def encode(self, value, out: Outgoing, where: str):
        raise NotImplementedError

    def decode(self, obj, inp: Incoming, where: str):
        raise NotImplementedError


class Int(Spec):
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


class Float(Spec):
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


class Bool(Spec):
    """msgpack bool."""

    def encode(self, value, out, where):
        if not isinstance(value, (bool, np.bool_)):
            raise ProtocolError(f"{where}: expected a bool, got {type(value).__name__}")
        return bool(value)

    def decode(self, obj, inp, where):
        if not isinstance(obj, bool):
            raise ProtocolError(f"{where}: expected a bool, got {type(obj).__name__}")
        return obj


class Str(Spec):
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


class Scalar(Spec):
    """A parameter value: bool, int (int64), finite float or str, each kept as its type."""

    _int, _float, _bool, _str = Int(), Float(), Bool(), Str()

    def _pick(self, value, where) -> Spec:
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


class Optional(Spec):
    """``inner`` or nil."""

    def __init__(self, inner: Spec):
        self.inner = inner

    def encode(self, value, out, where):
        return None if value is None else self.inner.encode(value, out, where)

    def decode(self, obj, inp, where):
        return None if obj is None else self.inner.decode(obj, inp, where)


class List(Spec):
    """msgpack array of ``item``; a tuple in memory."""

    def __init__(self, item: Spec):
        self.item = item

    def encode(self, value, out, where):
        return [self.item.encode(v, out, f"{where}[{i}]") for i, v in enumerate(value)]

    def decode(self, obj, inp, where):
        if not isinstance(obj, list):
            raise ProtocolError(f"{where}: expected an array, got {type(obj).__name__}")
        return tuple(self.item.decode(v, inp, f"{where}[{i}]") for i, v in enumerate(obj))


class Map(Spec):
    """msgpack map, str -> ``value``; a dict in memory."""

    def __init__(self, value: Spec):
        self.value = value

    def encode(self, value, out, where):
        if not isinstance(value, dict):
            raise ProtocolError(f"{where}: expected a dict, got {type(value).__name__}")
        return {Str().encode(k, out, where): self.value.encode(v, out, f"{where}[{k!r}]") for k, v in value.items()}

    def decode(self, obj, inp, where):
        if not isinstance(obj, dict):
            raise ProtocolError(f"{where}: expected a map, got {type(obj).__name__}")
        result = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise ProtocolError(f"{where}: expected string keys, got {_short(k)}")
            result[Str().decode(k, inp, where)] = self.value.decode(v, inp, f"{where}[{_short(k, 40)}]")
        return result


class Array(Spec):
    """An array map with one of ``dtypes`` and ``ndim`` dimensions; a bool array travels as uint8
    (0 and 1) where uint8 is allowed."""

    _KEYS = ({"dtype", "shape", "data"}, {"dtype", "shape", "frame"})

    def __init__(self, dtypes: tuple[str, ...], ndim: int):
        self.dtypes, self.ndim = dtypes, ndim

    def encode(self, value, out, where):
        arr = np.asarray(value)
        if arr.dtype == np.bool_ and "uint8" in self.dtypes:
            arr = arr.view(np.uint8)  # a mask travels as 0 and 1, viewed without a copy
        name = next((n for n in self.dtypes
                     if DTYPES[n].kind == arr.dtype.kind and DTYPES[n].itemsize == arr.dtype.itemsize), None)
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
            raise ProtocolError(f"{where}: declared shape {shape} needs {nbytes} bytes, over the limit of "
                                f"{inp.limits.max_array_bytes}")
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


class Message(Spec):
    """A message as a map of its fields, nested or at the top of the header.

    fields : name -> spec, in wire order; dataclass fields without a default are required
    to_wire : optional, message -> dict of the values to encode (for wire-only fields)
    from_wire : optional, (decoded fields, where) -> constructor keyword arguments
    """

    def __init__(self, cls: type, fields: dict[str, Spec], to_wire: Callable | None = None, from_wire: Callable | None = None):
        self.cls, self.fields = cls, fields
        self.to_wire, self.from_wire = to_wire, from_wire
        self.required = {
            f.name for f in dataclasses.fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
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
            if not isinstance(name, str):  # a key packed as bin names no field, whatever it spells
                raise ProtocolError(f"{where}: field names are str, got a {type(name).__name__} key {_short(name)}")
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


class Nested(Spec):
    """A field holding another message: it travels as that message's map of fields. A
    declaration only: ``ipc.codec`` puts the message's schema in its place."""

    def __init__(self, cls: type):
        self.cls = cls
