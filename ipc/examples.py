"""One example of every message type, the worked example of docs/protocol.md, and a client.

``example_messages()`` builds a small, deterministic instance of every message class:
tests round-trip them, and an implementer in another language can encode them to get
test vectors. Running this module prints the byte-level worked example (a request and
its reply, as frames, hex dumps and annotated msgpack) that docs/protocol.md embeds, and
with ``adjacent`` the example exchange of adjacent corners (headers written as JSON)::

    python -m ipc.examples > /tmp/example.md
    python -m ipc.examples adjacent > /tmp/adjacent.md

``request_with_retries`` is a request/reply client written with nothing but pyzmq and the
codec, step by step as docs/protocol.md section 12 describes it for any language: it
recovers from a lost reply, a dead server and a request libzmq refuses as oversize (no reply
comes; see docs/protocol.md section 7) by closing its socket and opening a new one.
"""

from __future__ import annotations

import io
import math

import msgpack
import numpy as np

from ipc import codec
from ipc import messages as m

__all__ = ["adjacent_corners_example", "example_messages", "request_with_retries", "worked_example"]


def example_messages() -> dict[type, object]:
    """Message class -> a deterministic instance with every optional part filled in."""
    camera = m.CameraInfo(
        width=4,
        height=3,
        K=np.array([[5.0, 0.0, 2.0], [0.0, 5.0, 1.5], [0.0, 0.0, 1.0]]),
        D=np.array([0.1, -0.05, 0.0, 0.0, 0.01]),
    )
    depth = np.array([[0.0, 1.0, 1.25, 2.5], [0.5, np.nan, 0.75, 3.0], [1.5, 1.5, 0.0, 0.001]], dtype=np.float32)
    rgb = np.arange(camera.height * camera.width * 3, dtype=np.uint8).reshape(camera.height, camera.width, 3)
    # A flat 2 x 2 square of four vertices and two triangles, 0.1 m wide, 1 m away.
    canonical = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.1, 0.1, 0.0]])
    estimate = m.MeshEstimate(
        vertices=canonical + [0.0, 0.0, 1.0],
        faces=np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32),
        boundary=np.array([0, 1, 2, 3], dtype=np.int32),
        canonical=canonical,
        timestamp_s=12.5,
        seq=42,
        energies={"smoothness": 0.25, "depth": 1.5, "total": 1.75},
        iterations=10,
        confidence=0.9,
        lost=False,
        timing_ms=3.5,
        visible=np.array([True, True, False, True]),
    )
    s = math.sqrt(0.5)
    corner = m.GraspPlan(
        position=np.array([0.0, 0.0, 1.0]),
        approach=np.array([0.0, 0.0, 1.0]),
        quat_xyzw=np.array([0.0, 0.0, s, s]),
        opening_width_m=0.04,
        score=0.8,
        vertex_id=0,
        kind="corner",
        timestamp_s=12.5,
    )
    boundary = m.GraspPlan(
        position=np.array([0.05, 0.0, 1.0]),
        approach=np.array([0.0, 0.0, 1.0]),
        quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
        opening_width_m=0.03,
        score=0.5,
        vertex_id=1,
        kind="boundary",
        timestamp_s=12.5,
    )
    # The corners next to vertex 0 of the square, held: vertex 1 going forward along the
    # outline (0, 1, 3, 2), vertex 2 going backward; both one side, 0.1 m, away. Grasps
    # approach against the surface normal with the fingers closing across the corner's
    # bisector. Vertex 2 is not visible in the estimate, and lies outside the workspace,
    # so it scores 0; vertex 1 scores (clearance 0.95 + confidence 0.9 + visible 1) / 3.
    c, s8 = math.cos(math.pi / 8), math.sin(math.pi / 8)
    ahead = m.AdjacentCorner(
        plan=m.GraspPlan(position=np.array([0.1, 0.0, 1.0]), approach=np.array([0.0, 0.0, 1.0]),
                         quat_xyzw=np.array([0.0, 0.0, c, s8]), opening_width_m=0.04, score=0.95, vertex_id=1,
                         kind="corner", timestamp_s=12.5),
        side=1, material_distance_m=0.1, visible=1.0, reachable=True,
    )
    behind = m.AdjacentCorner(
        plan=m.GraspPlan(position=np.array([0.0, 0.1, 1.0]), approach=np.array([0.0, 0.0, 1.0]),
                         quat_xyzw=np.array([0.0, 0.0, -s8, c]), opening_width_m=0.04, score=0.0, vertex_id=2,
                         kind="corner", timestamp_s=12.5),
        side=-1, material_distance_m=0.1, visible=0.0, reachable=False,
    )
    mask = np.zeros((camera.height, camera.width), dtype=np.uint8)
    mask[1:, 1:3] = 255
    frame = m.RGBDFrame(rgb=rgb, depth_m=depth, camera=camera, timestamp_s=12.5, seq=42, occluder_mask=mask > 0,
                        held_vertices=np.array([0], np.int32), held_points_m=np.array([[0.0, 0.0, 1.0]]),
                        held_quats_xyzw=np.array([[1.0, 0.0, 0.0, 0.0]]))
    examples = [
        camera,
        frame,
        estimate,
        corner,
        m.GraspRequest(request_id=3, max_candidates=2, kinds=("corner", "boundary"), estimate=estimate),
        m.GraspPlanReply(request_id=3, candidates=(corner, boundary), estimate_seq=42),
        ahead,
        m.AdjacentCornersRequest(request_id=21, held_vertex=0, max_candidates=2),
        m.AdjacentCornersReply(request_id=21, estimate_seq=42, held_vertex=0, held_outline_vertex=0,
                               candidates=(ahead, behind)),
        m.InitialiseRequest(request_id=7, mask=mask,
                            background=m.RGBDFrame(rgb=rgb, depth_m=np.nan_to_num(depth), camera=camera,
                                                   timestamp_s=2.0, seq=1),
                            seq=43),
        m.OccluderMaskRequest(request_id=11, mask=mask, seq=42),
        m.ResetRequest(request_id=8),
        m.SetParametersRequest(request_id=9, parameters={"lambda_d": 0.6, "max_iterations": 20, "use_depth": True,
                                                         "features": "sift"}),
        m.StatusRequest(request_id=10),
        m.StatusReply(
            request_id=10,
            state="tracking",
            frames_processed=120,
            last_seq=42,
            parameters={"lambda_d": 0.6, "max_iterations": 20},
            message="frame 17: no valid depth pixel (all 0 or NaN)",
            uptime_s=61.5,
            source="live",
            frame_age_s=0.03125,
            frames_received=150,
            frames_tracked=121,
            frames_dropped=26,
            frames_rejected=3,
            rejected_by_kind={"no_depth": 2, "camera_changed": 1},
            messages_malformed=1,
            latency_ms_median=41.25,
            latency_ms_p99=87.5,
            tracking_ms_median=38.0,
            confidence=0.875,
            lost_streak=0,
            reinitialisations=1,
            discontinuities=1,
        ),
        m.ErrorReply(code="invalid", message="InitialiseRequest.mask: expected shape (480, 640), got (3, 4)", request_id=7),
        m.Heartbeat(source="perception", seq=5, timestamp_s=1700000000.25, period_s=1.0),
    ]
    return {type(x): x for x in examples}


# ---------------------------------------------------------------------------
# The worked example


def _hexdump(data: bytes) -> str:
    """xxd-style lines: offset, 16 bytes in hex, printable ASCII."""
    lines = []
    for off in range(0, len(data), 16):
        chunk = data[off : off + 16]
        hexes = " ".join(f"{b:02x}" for b in chunk)
        text = "".join(chr(b) if 32 <= b < 127 else "." for b in chunk)
        lines.append(f"{off:08x}  {hexes:<47}  {text}")
    return "\n".join(lines)


_FORMATS = {
    0xC0: "nil", 0xC2: "false", 0xC3: "true", 0xC4: "bin 8", 0xC5: "bin 16", 0xC6: "bin 32",
    0xCA: "float 32", 0xCB: "float 64", 0xCC: "uint 8", 0xCD: "uint 16", 0xCE: "uint 32",
    0xCF: "uint 64", 0xD0: "int 8", 0xD1: "int 16", 0xD2: "int 32", 0xD3: "int 64",
    0xD9: "str 8", 0xDA: "str 16", 0xDB: "str 32", 0xDC: "array 16", 0xDD: "array 32",
    0xDE: "map 16", 0xDF: "map 32",
}  # fmt: skip


def _format_name(first: int) -> str:
    """The msgpack format family of an item from its first byte (msgpack spec names)."""
    for lo, hi, name in (
        (0x00, 0x7F, "positive fixint"),
        (0x80, 0x8F, "fixmap"),
        (0x90, 0x9F, "fixarray"),
        (0xA0, 0xBF, "fixstr"),
        (0xE0, 0xFF, "negative fixint"),
    ):
        if lo <= first <= hi:
            return name
    return _FORMATS[first]


def _annotate(data: bytes) -> str:
    """One line per msgpack item of ``data``: offset, its bytes (head, cut when long), meaning."""
    unpacker = msgpack.Unpacker(io.BytesIO(data), raw=False)
    lines: list[str] = []

    def item(depth: int) -> None:
        start = unpacker.tell()
        first = data[start]
        if first <= 0x7F or first >= 0xE0 or 0xA0 <= first <= 0xBF or first in range(0xC0, 0xDC):
            value = unpacker.unpack()
            meaning = f"{len(value)} bytes" if isinstance(value, bytes) else repr(value)
            emit(start, unpacker.tell(), depth, f"{_format_name(first)}: {meaning}")
        elif 0x80 <= first <= 0x8F or first in (0xDE, 0xDF):
            n = unpacker.read_map_header()
            emit(start, unpacker.tell(), depth, f"{_format_name(first)}: map of {n} key/value pairs")
            for _ in range(2 * n):
                item(depth + 1)
        else:  # fixarray, array 16, array 32: the only kinds left in msgpack
            n = unpacker.read_array_header()
            emit(start, unpacker.tell(), depth, f"{_format_name(first)}: array of {n} items")
            for _ in range(n):
                item(depth + 1)

    def emit(start: int, end: int, depth: int, meaning: str) -> None:
        raw = " ".join(f"{b:02x}" for b in data[start:end])
        if len(raw) > 41:
            raw = raw[:38] + "..."
        lines.append(f"{start:04x}  {raw:<41}  {'  ' * depth}{meaning}")

    item(0)
    return "\n".join(lines)


def _frames_markdown(title: str, frames: list) -> str:
    parts = [f"**{title}**: {len(frames)} frame(s)\n"]
    for i, frame in enumerate(frames):
        data = bytes(frame)
        what = "header" if i == 0 else "buffer"
        parts.append(f"Frame {i} ({what}, {len(data)} bytes):\n\n```\n{_hexdump(data)}\n```\n")
        if i == 0:
            parts.append(f"Frame 0 item by item (offset, bytes, meaning):\n\n```\n{_annotate(data)}\n```\n")
    return "\n".join(parts)


def worked_example() -> str:
    """Markdown of a request (InitialiseRequest with a 3 x 4 mask and background sent as
    buffer frames) and its reply (StatusReply), generated by running the codec."""
    examples = example_messages()
    request = examples[m.InitialiseRequest]
    # From a service started idle (--no-auto-init) 2.5 s ago: frames came in, none was
    # tracked, so the measurements of estimates are nil.
    reply = m.StatusReply(request_id=request.request_id, state="initialising", parameters={"lambda_d": 0.6},
                          uptime_s=2.5, source="live", frame_age_s=0.03125, frames_received=42)
    # inline_max_bytes=0 sends the 12-byte mask as a buffer frame, to show the framing.
    request_frames = codec.encode(request, inline_max_bytes=0)
    reply_frames = codec.encode(reply)
    return "\n".join(
        [
            "<!-- generated by `python -m ipc.examples`; tests/unit/test_ipc_protocol_doc.py checks it -->",
            f"Request: `InitialiseRequest(request_id={request.request_id}, mask=<(3, 4) uint8 {request.mask.tolist()}>, "
            f"background=<RGBDFrame, 3 x 4, seq {request.background.seq}>, seq={request.seq})`",
            "",
            _frames_markdown("Request", request_frames),
            f"Reply: `{reply!r}`",
            "",
            _frames_markdown("Reply", reply_frames),
            "<!-- end of generated example -->",
        ]
    )


def _readable(value, indent: int = 0) -> str:
    """A decoded msgpack value written as JSON, except that an inline array's ``data`` (bin)
    is shown as its byte count and the numbers it holds."""
    pad = "  " * indent
    if isinstance(value, dict):
        if set(value) == {"dtype", "shape", "data"}:
            numbers = np.frombuffer(value["data"], dtype=np.dtype(value["dtype"]).newbyteorder("<")).tolist()
            return (f'{{"dtype": "{value["dtype"]}", "shape": {value["shape"]}, '
                    f'"data": <bin, {len(value["data"])} bytes: {", ".join(repr(x) for x in numbers)}>}}')
        items = [f'{pad}  "{k}": {_readable(v, indent + 1)}' for k, v in value.items()]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}" if items else "{}"
    if isinstance(value, list):
        if not value:
            return "[]"
        items = [f"{pad}  {_readable(v, indent + 1)}" for v in value]
        return "[\n" + ",\n".join(items) + f"\n{pad}]"
    return "null" if value is None else "true" if value is True else "false" if value is False else \
        f'"{value}"' if isinstance(value, str) else repr(value)


def adjacent_corners_example() -> str:
    """Markdown of an AdjacentCornersRequest and its AdjacentCornersReply, each header
    (frame 0, every array inline) decoded and written as JSON, generated by running the codec."""
    examples = example_messages()
    parts = ["<!-- generated by `python -m ipc.examples adjacent`; tests/unit/test_ipc_protocol_doc.py checks it -->"]
    for title, msg in (("Request", examples[m.AdjacentCornersRequest]), ("Reply", examples[m.AdjacentCornersReply])):
        frames = codec.encode(msg)
        header = msgpack.unpackb(frames[0], raw=False)
        parts.append(f"{title}: {len(frames)} frame(s), the header of {len(frames[0])} bytes:\n\n"
                     f"```\n{_readable(header)}\n```\n")
    parts.append("<!-- end of generated adjacent-corners example -->")
    return "\n".join(parts)


# ---------------------------------------------------------------------------
# A client, as docs/protocol.md section 12 describes it


def request_with_retries(endpoint: str, frames: list, *, timeout_s: float = 1.0, attempts: int = 3, curve_keys=None):
    """Send one request's frames to a REP service and return the reply's frames ("lazy pirate").

    endpoint : e.g. ``tcp://robot-pc:5562``
    frames : the request as ``codec.encode`` gives it (header, then buffers)
    timeout_s, attempts : wait this long for each reply; send at most this many times
    curve_keys : None, or (client public key, client secret key, server public key), each a
        40-byte Z85 key
    returns the reply's frames (decode them with ``codec.decode``)
    raises TimeoutError after ``attempts`` attempts without a reply

    A REQ socket cannot send twice without a reply in between, so after a timeout the socket
    is closed (linger 0: the unsent request is dropped) and a new one connects. A reply that
    comes too late goes to the closed socket and is lost, which is harmless: every request
    of the protocol can be repeated. This is also how a client recovers from a request with
    a frame larger than the server's ``ZMQ_MAXMSGSIZE``: libzmq drops the connection before
    the server sees the request, no reply comes, and the next request, on a new connection,
    is answered.
    """
    import zmq  # here only: the rest of this module needs no ZeroMQ

    context = zmq.Context.instance()
    for _ in range(attempts):
        sock = context.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        if curve_keys is not None:
            sock.curve_publickey, sock.curve_secretkey, sock.curve_serverkey = curve_keys
        sock.connect(endpoint)
        try:
            sock.send_multipart(frames)
            if sock.poll(int(1000 * timeout_s), zmq.POLLIN):
                return sock.recv_multipart()
        finally:
            sock.close(linger=0)
    raise TimeoutError(f"{endpoint}: no reply after {attempts} attempts of {timeout_s:g} s")


if __name__ == "__main__":
    import sys

    which = sys.argv[1:] or ["worked"]
    if which not in (["worked"], ["adjacent"]):
        sys.exit("usage: python -m ipc.examples [worked | adjacent]")
    sys.stdout.write((worked_example() if which == ["worked"] else adjacent_corners_example()) + "\n")
