"""Messages, codec and ZeroMQ transport shared by every process of the toolkit.

- ``ipc.messages``: one frozen dataclass per message type (also exported here).
- ``ipc.codec``: msgpack wire format, ``encode``/``decode``/``ProtocolError``/``Limits``.
- ``ipc.transport``: Publisher, Subscriber, RequestClient, ReplyServer, CURVE keys.
  Not imported here, so that the numerical core can use the messages without zmq.
- ``ipc.endpoints``: default ports and endpoints (loopback).
- ``ipc.examples``: one example of every message; regenerates docs/protocol.md's example.

The wire format is specified in docs/protocol.md.
"""

from ipc.codec import Limits, ProtocolError, decode, encode
from ipc.messages import (
    SCHEMA_VERSION,
    AdjacentCorner,
    AdjacentCornersReply,
    AdjacentCornersRequest,
    CameraInfo,
    ErrorReply,
    GraspPlan,
    GraspPlanReply,
    GraspRequest,
    Heartbeat,
    InitialiseRequest,
    MeshEstimate,
    OccluderMaskRequest,
    ResetRequest,
    RGBDFrame,
    SetParametersRequest,
    StatusReply,
    StatusRequest,
)

__all__ = [
    "SCHEMA_VERSION",
    "AdjacentCorner",
    "AdjacentCornersReply",
    "AdjacentCornersRequest",
    "CameraInfo",
    "ErrorReply",
    "GraspPlan",
    "GraspPlanReply",
    "GraspRequest",
    "Heartbeat",
    "InitialiseRequest",
    "OccluderMaskRequest",
    "Limits",
    "MeshEstimate",
    "ProtocolError",
    "RGBDFrame",
    "ResetRequest",
    "SetParametersRequest",
    "StatusReply",
    "StatusRequest",
    "decode",
    "encode",
]
