"""Put a frame source on a ZeroMQ publisher: the body of ``launch_scripts.publish_frames``."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from ipc.transport import HEARTBEAT_PERIOD_S, CurveServer, Publisher
from perception.sources._base import REALTIME, FrameSource, Pacing, publish_frames

log = logging.getLogger(__name__)


def run_publisher(
    source: FrameSource,
    endpoint: str,
    *,
    pacing: Pacing = REALTIME,
    loop: bool = False,
    max_frames: int | None = None,
    start_delay_s: float = 0.0,
    heartbeat_period_s: float = HEARTBEAT_PERIOD_S,
    stop: threading.Event | None = None,
    on_bound: Callable[[str], None] | None = None,
    curve: CurveServer | None = None,
) -> int:
    """Bind a Publisher on ``endpoint`` and publish the source's frames on it.

    endpoint : e.g. ``ipc.endpoints.FRAMES``, or ``tcp://127.0.0.1:*`` for a free port
    start_delay_s : seconds between binding and the first frame. A ZeroMQ publisher drops
        messages until each subscriber's subscription has arrived, so a short delay lets
        subscribers that are already waiting receive the first frame.
    heartbeat_period_s : seconds between heartbeats (subscribers call the source gone
        after three silent periods)
    on_bound : called with the endpoint actually bound, before the first frame
    curve : CurveServer to encrypt and accept only authorised subscribers, or None
    pacing, loop, max_frames, stop : as ``publish_frames``
    returns the number of frames published. The publisher's depth encoding follows
    ``source.depth_scale`` (uint16 units when set, float32 metres otherwise).
    """
    stop = stop if stop is not None else threading.Event()
    with Publisher(endpoint, source=source.name, heartbeat_period_s=heartbeat_period_s,
                   depth_scale=source.depth_scale, curve=curve) as publisher:
        if on_bound is not None:
            on_bound(publisher.endpoint)
        if start_delay_s > 0 and stop.wait(start_delay_s):
            return 0
        n = publish_frames(source, publisher.publish, pacing=pacing, loop=loop, max_frames=max_frames, stop=stop)
        log.info("%s: published %d frames on %s", source.name, n, publisher.endpoint)
        return n
