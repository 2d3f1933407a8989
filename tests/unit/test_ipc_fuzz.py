"""Decoder fuzz: whatever the bytes, decode returns a valid message or raises ProtocolError.

Seeded (numpy Generator), so a failure reproduces. Inputs: random bytes, every
truncation of valid headers, byte flips, buffer frames cut, grown, dropped and added,
and structure-aware mutations that replace one node of a valid header with a hostile
value (wrong types, NaN and infinities, huge integers, absurd shapes, wrong versions,
unknown types, ext types). A decoder bug caught by its own safety net ("internal
decoder error") fails the test too.
"""

import copy

import msgpack
import numpy as np
import pytest

from ipc import messages as m
from ipc.codec import Limits, ProtocolError, decode, encode
from ipc.examples import example_messages

SEED = 20261122
LIMITS = Limits(max_message_bytes=2**20, max_array_bytes=2**16)


def corpus() -> list[list[bytes]]:
    """Valid encodings of every example, in every framing and depth encoding."""
    out = []
    for msg in example_messages().values():
        for inline in (0, 64, 2**20):
            out.append([bytes(f) for f in encode(msg, inline_max_bytes=inline)])
        if isinstance(msg, m.RGBDFrame):
            out.append([bytes(f) for f in encode(msg, depth_scale=1000, inline_max_bytes=0)])
    return out


CORPUS = corpus()


def check(frames) -> bool:
    """Decode; True if decoded (and the result re-encodes), False on ProtocolError."""
    try:
        msg = decode(frames, LIMITS)
    except ProtocolError as e:
        assert "internal decoder error" not in str(e), str(e)
        assert "\n" not in str(e)
        return False
    # Whatever decodes must be a valid message that travels again.
    decode(encode(msg), LIMITS)
    return True


def hostile_values(rng: np.random.Generator) -> list:
    big = int(rng.integers(2**31, 2**62))
    return [
        None, True, False, 0, -1, 2**63 - 1, -(2**63), 2**64 - 1, big, -big,
        0.5, float("nan"), float("inf"), float("-inf"), 1e308, -0.0,
        "", "x" * int(rng.integers(1, 300)), "RGBDFrame", "uint16", "float64", "int64", "object", "<f8",
        b"", bytes(rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8)),
        [], [big, big, big], [2**40, 2**40, 3], [-1, 4, 3], [3, 4], [0, 0], [1.5, 2], [True, 2],
        {}, {"dtype": "uint8", "shape": [2**31, 2**31, 3], "frame": 1},
        {"dtype": "float64", "shape": [1, 3], "data": b"\x00" * 7},
        {"dtype": "uint8", "shape": [1], "frame": 99}, {"a": 1}, {1: 2}, [[[[[]]]]],
        msgpack.ExtType(1, b"\x80\x04N."), msgpack.Timestamp(1, 0),
    ]  # fmt: skip


def paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from paths(v, prefix + (i,))


def replaced(obj, path, value):
    if not path:
        return value
    obj = copy.deepcopy(obj)
    node = obj
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return obj


def test_random_bytes():
    rng = np.random.default_rng(SEED)
    decoded = 0
    for _ in range(3000):
        n_frames = int(rng.integers(1, 4))
        frames = [rng.bytes(int(rng.integers(0, 200))) for _ in range(n_frames)]
        decoded += check(frames)
    assert decoded == 0


def test_random_bytes_after_a_valid_prefix():
    rng = np.random.default_rng(SEED + 1)
    for _ in range(2000):
        head = CORPUS[int(rng.integers(len(CORPUS)))][0]
        cut = int(rng.integers(0, len(head)))
        check([head[:cut] + rng.bytes(int(rng.integers(1, 40)))])


def test_every_truncation_of_every_header():
    for frames in CORPUS:
        head = frames[0]
        for cut in range(len(head)):
            assert not check([head[:cut], *frames[1:]])


def test_byte_flips():
    rng = np.random.default_rng(SEED + 2)
    for _ in range(4000):
        frames = list(CORPUS[int(rng.integers(len(CORPUS)))])
        head = bytearray(frames[0])
        for _ in range(int(rng.integers(1, 4))):
            head[int(rng.integers(len(head)))] = int(rng.integers(256))
        check([bytes(head), *frames[1:]])


def test_buffer_frames_cut_grown_dropped_added():
    rng = np.random.default_rng(SEED + 3)
    multi = [f for f in CORPUS if len(f) > 1]
    for frames in multi:
        for i in range(1, len(frames)):
            buf = frames[i]
            for variant in (buf[:-1], buf + b"\x00", b"", buf[: len(buf) // 2]):
                assert not check([*frames[:i], variant, *frames[i + 1 :]])
            assert not check(frames[:i] + frames[i + 1 :])
        assert not check([*frames, rng.bytes(8)])
        if len({len(f) for f in frames[1:]}) == len(frames) - 1 > 1:  # buffers of distinct sizes, swapped
            assert not check([frames[0], *frames[1:][::-1]])


def test_structured_mutations():
    rng = np.random.default_rng(SEED + 4)
    tops = [(msgpack.unpackb(f[0], strict_map_key=False), f) for f in CORPUS]
    outcomes = {True: 0, False: 0}
    for _ in range(4000):
        top, frames = tops[int(rng.integers(len(tops)))]
        all_paths = list(paths(top))
        path = all_paths[int(rng.integers(len(all_paths)))]
        values = hostile_values(rng)
        mutant = replaced(top, path, values[int(rng.integers(len(values)))])
        if rng.random() < 0.2 and isinstance(mutant, dict):  # also drop or add a key somewhere at the top
            mutant = dict(mutant)
            if mutant and rng.random() < 0.5:
                mutant.pop(list(mutant)[int(rng.integers(len(mutant)))])
            else:
                mutant["unexpected"] = 1
        try:
            head = msgpack.packb(mutant, use_bin_type=True)
        except (OverflowError, ValueError, TypeError):
            continue  # not representable in msgpack at all
        outcomes[check([head, *frames[1:]])] += 1
    # Most mutations must be refused; the few accepted are harmless ones (e.g. a new frame_id).
    assert outcomes[False] > 10 * outcomes[True]


V = m.SCHEMA_VERSION


@pytest.mark.parametrize("version", [0, 1, V - 1, V + 1, -1, 2**64 - 1, float(V), str(V), None, [V]])
def test_wrong_versions(version):
    for frames in CORPUS[:: len(CORPUS) // 8]:
        top = msgpack.unpackb(frames[0])
        top["version"] = version
        with pytest.raises(ProtocolError, match="header.version: unsupported schema version"):
            decode([msgpack.packb(top), *frames[1:]], LIMITS)


@pytest.mark.parametrize("type_tag", ["", "Foo", "rgbdframe", "RGBDFrame ", "__class__", "ndarray", 3, None, b"RGBDFrame"])
def test_unknown_types(type_tag):
    top = msgpack.unpackb(CORPUS[0][0])
    top["type"] = type_tag
    with pytest.raises(ProtocolError, match="header.type: unknown message type"):
        decode([msgpack.packb(top, use_bin_type=True), *CORPUS[0][1:]], LIMITS)


@pytest.mark.parametrize("shape", [[2**62, 2**62, 3], [2**64 - 1, 1, 3], [2**16, 2**16, 3], [0, 2**63, 3]])
def test_absurd_declared_shapes_allocate_nothing(shape):
    frames = [bytes(f) for f in encode(example_messages()[m.RGBDFrame], inline_max_bytes=0)]
    top = msgpack.unpackb(frames[0])
    top["fields"]["rgb"]["shape"] = shape
    with pytest.raises(ProtocolError, match=r"RGBDFrame\.rgb: declared (uint8 )?shape"):
        decode([msgpack.packb(top), *frames[1:]], LIMITS)


def test_deep_nesting():
    deep = b"\x91" * 5000 + b"\x00"  # [[[[...[0]...]]]]
    head = (b"\x83" + msgpack.packb("type") + msgpack.packb("StatusRequest") + msgpack.packb("version")
            + msgpack.packb(m.SCHEMA_VERSION) + msgpack.packb("fields"))
    assert not check([deep])
    assert not check([head + deep])
    assert not check([head + b"\x81" + msgpack.packb("request_id") + deep])
