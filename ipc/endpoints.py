"""Default ZeroMQ endpoints of the toolkit's processes: the one place that names the ports.

Every default binds to the loopback interface only. To serve controllers on other
machines, bind to a routable address (e.g. ``tcp://0.0.0.0:5562``) and turn on CURVE
(``ipc.transport.CurveServer``); docs/protocol.md lists these ports too.

=================  ========================  ===========  ==========================================
constant           endpoint                  socket       traffic
=================  ========================  ===========  ==========================================
FRAMES             tcp://127.0.0.1:5560      PUB (bind)   RGBDFrame + Heartbeat, from a frame source
ESTIMATES          tcp://127.0.0.1:5561      PUB (bind)   MeshEstimate + Heartbeat, from perception
PERCEPTION_CONTROL tcp://127.0.0.1:5562      REP (bind)   Initialise/Reset/SetParameters/Status
                                                          requests -> StatusReply | ErrorReply
PLANNER            tcp://127.0.0.1:5563      REP (bind)   GraspRequest -> GraspPlanReply | ErrorReply,
                                                          AdjacentCornersRequest -> AdjacentCornersReply
                                                          | ErrorReply
=================  ========================  ===========  ==========================================
"""

from __future__ import annotations

LOOPBACK = "127.0.0.1"

FRAMES_PORT = 5560
ESTIMATES_PORT = 5561
PERCEPTION_CONTROL_PORT = 5562
PLANNER_PORT = 5563


def tcp(host: str, port: int | str) -> str:
    """``tcp://host:port``; ``port`` may be ``"*"`` to let the system pick a free port."""
    return f"tcp://{host}:{port}"


FRAMES = tcp(LOOPBACK, FRAMES_PORT)
ESTIMATES = tcp(LOOPBACK, ESTIMATES_PORT)
PERCEPTION_CONTROL = tcp(LOOPBACK, PERCEPTION_CONTROL_PORT)
PLANNER = tcp(LOOPBACK, PLANNER_PORT)


def check_endpoint(endpoint: str) -> str:
    """``endpoint`` when ZeroMQ can bind or connect it as given: ``ipc://``, ``inproc://``, or
    ``tcp://HOST:PORT`` with PORT in 0-65535 or ``*`` (ZeroMQ would take port 99999 as another
    port without a word). Raises ValueError naming what is wrong."""
    example = "such as tcp://127.0.0.1:5563"
    if endpoint.startswith(("ipc://", "inproc://")):
        return endpoint
    if not endpoint.startswith("tcp://"):
        raise ValueError(f"expected a ZeroMQ endpoint {example}, got {endpoint!r}")
    host, colon, port = endpoint[len("tcp://"):].rpartition(":")
    if not colon or not host or "]" in port:  # no port, or an IPv6 address without one: tcp://[::1]
        raise ValueError(f"expected tcp://HOST:PORT, {example}, got {endpoint!r}")
    if port != "*" and not (port.isdigit() and int(port) <= 65535):
        raise ValueError(f"expected a port in 0-65535 or *, got {port!r} in {endpoint!r}")
    return endpoint


def is_loopback(endpoint: str) -> bool:
    """True when ``endpoint`` cannot be reached from another machine: ``ipc://`` and
    ``inproc://``, or ``tcp://`` on a loopback address (127.0.0.0/8, ``localhost``, ``[::1]``,
    the interface ``lo``). A wildcard (``*``, ``0.0.0.0``), another address or an interface
    name is taken as reachable."""
    if endpoint.startswith(("ipc://", "inproc://")):
        return True
    if not endpoint.startswith("tcp://"):
        return False
    host = endpoint[len("tcp://"):].rpartition(":")[0]
    host = host.split(";")[-1]  # tcp://source;destination: the address bound is the last one
    return host in ("localhost", "lo", "[::1]", "::1") or host.startswith("127.")
