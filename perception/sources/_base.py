"""The common shape of frame sources, and the paced publish loop they share.

A source is an iterable of ``ipc.RGBDFrame``: ``frames()`` yields one pass (a file or a
fixed number of simulated frames ends; a device does not). ``publish_frames`` sends a
source's frames to any callable, paced in real time by the frames' timestamps, at a
fixed rate, or as fast as possible, and optionally starts over at the end. It knows
nothing of sockets: ``perception.sources.run_publisher`` puts it on a ZeroMQ publisher.
"""

from __future__ import annotations

import abc
import dataclasses
import importlib
import inspect
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from ipc.messages import RGBDFrame

log = logging.getLogger(__name__)

#: Frame period assumed between two passes of a looped one-frame source: the toolkit's
#: nominal 30 Hz (sim scenes and the sensors' default mode).
NOMINAL_PERIOD_S = 1.0 / 30.0


class SourceError(RuntimeError):
    """A source cannot deliver frames (missing optional SDK, no device, device timeout,
    unusable recording); the message is one line naming what was wrong."""


def optional_import(module: str, extra: str, feature: str):
    """Import an optional SDK only when the feature that needs it is used.

    module : import name, e.g. "pyrealsense2"
    extra : the clothkit extra that installs it, e.g. "realsense"
    feature : what needs it, for the message
    raises SourceError naming the install command when the module is missing, and what it
    could not load when it is installed but does not load (a system library it needs, such
    as libusb-1.0 for pyrealsense2, or the Azure Kinect SDK for pyk4a)
    """
    try:
        return importlib.import_module(module)
    except ImportError as e:
        top = module.split(".")[0]
        if isinstance(e, ModuleNotFoundError) and e.name in (top, module):
            raise SourceError(f"{feature} needs the Python module {module!r}, which is not installed; install it "
                              f"from the clothkit checkout with: pip install -e '.[{extra}]'") from None
        raise SourceError(f"{feature} needs the Python module {module!r}, which is installed but does not load "
                          f"({e}); install the system libraries it needs (the README's paragraph on real sensors)") from None


def refuse_device_options(source: type, owns: str, given: dict, recording) -> None:
    """Raise ValueError naming the device options in ``given`` (name -> value) that differ from
    their defaults in ``source``'s constructor: a ``recording`` has its own (``owns``, e.g.
    "size, frame rate and device"), and an option that would be ignored is refused instead."""
    defaults = inspect.signature(source.__init__).parameters
    changed = [f"{k}={v!r}" for k, v in given.items() if v != defaults[k].default]
    if changed:
        raise ValueError(f"{source.__name__}: a recording has its own {owns}; got {', '.join(changed)} with "
                         f"recording={str(recording)!r}")


class FrameSource(abc.ABC):
    """Where RGB-D frames come from.

    name : short name for logs and the publisher's heartbeats
    depth_scale : units per metre of the source's native depth quantisation (e.g. 1000 for
        millimetres), used to send depth as uint16 without loss; None sends float32 metres
    camera : ``ipc.CameraInfo`` of the frames, once known (None before the first frame
        for sources that learn it from the data)

    ``frames()`` yields ``RGBDFrame`` (rgb (H, W, 3) uint8 RGB, depth_m (H, W) float32
    metres registered to colour, 0 = no measurement). Each call of a finite source starts
    a new pass from its first frame; a device continues its stream. ``close()`` releases
    the device or files; sources are context managers.
    """

    name: str = "frames"
    depth_scale: float | None = None
    camera = None

    @abc.abstractmethod
    def frames(self) -> Iterator[RGBDFrame]:
        """One pass over the source's frames."""

    def close(self) -> None:  # noqa: B027 -- not abstract: a source that holds nothing needs no close
        """Release what the source holds; the default holds nothing."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class Pacing:
    """When to publish each frame.

    mode : "realtime" keeps the spacing of the frames' ``timestamp_s``; "rate" publishes
        at ``rate_hz``; "fast" publishes as soon as a frame is ready
    rate_hz : frames per second, > 0, for mode "rate" only

    A frame that is ready late is published at once and the schedule restarts from it:
    lateness is never made up with a burst of frames.
    """

    mode: str = "realtime"
    rate_hz: float | None = None

    MODES = ("realtime", "rate", "fast")

    def __post_init__(self):
        if self.mode not in self.MODES:
            raise ValueError(f"Pacing.mode: expected one of {self.MODES}, got {self.mode!r}")
        if self.mode == "rate":
            if self.rate_hz is None or not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
                raise ValueError(f"Pacing.rate_hz: expected a positive number for mode 'rate', got {self.rate_hz!r}")
        elif self.rate_hz is not None:
            raise ValueError(f"Pacing.rate_hz: only for mode 'rate', got {self.rate_hz!r} with mode {self.mode!r}")


#: The default pacing: the spacing of the frames' timestamps.
REALTIME = Pacing()


class _Schedule:
    """Publication times of successive frames under a Pacing, on a monotonic clock."""

    def __init__(self, pacing: Pacing):
        self.pacing = pacing
        self._anchor_wall: float | None = None
        self._anchor_stamp = 0.0
        self._count = 0

    def due(self, stamp_s: float, now: float) -> float:
        """Wall time (clock seconds) at which the frame stamped ``stamp_s`` is due."""
        mode = self.pacing.mode
        if mode == "fast":
            return now
        if self._anchor_wall is None:
            self._restart(stamp_s, now)
        if mode == "realtime":
            offset = stamp_s - self._anchor_stamp
        else:
            offset = self._count / self.pacing.rate_hz
        due = self._anchor_wall + offset
        if due < now or offset < 0:
            # Late (a slow source) or a timestamp that went back: schedule from here.
            self._restart(stamp_s, now)
            due = now
        self._count += 1
        return due

    def _restart(self, stamp_s: float, now: float) -> None:
        self._anchor_wall, self._anchor_stamp, self._count = now, stamp_s, 0


def publish_frames(
    source: FrameSource,
    publish: Callable[[RGBDFrame], None],
    *,
    pacing: Pacing = REALTIME,
    loop: bool = False,
    max_frames: int | None = None,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
    wait: Callable[[float], bool] | None = None,
) -> int:
    """Send the frames of ``source`` to ``publish``, paced, until the end or ``stop``.

    source : a FrameSource
    publish : called with each RGBDFrame, e.g. ``ipc.transport.Publisher.publish``
    pacing : see Pacing
    loop : start a new pass when the source ends (not for devices, which never end);
        ``seq`` and ``timestamp_s`` continue from the previous pass (one mean frame
        period on), so that subscribers see a stream that only moves forward
    max_frames : stop after this many frames (None: no limit)
    stop : set it (from another thread or a signal handler) to stop within one wait
    clock, wait : seconds on a monotonic clock, and a function that waits that many
        seconds and returns True if stopped (default ``stop.wait``); tests pass fakes
    returns the number of frames published
    """
    if max_frames is not None and max_frames < 0:
        raise ValueError(f"publish_frames: max_frames must be >= 0, got {max_frames}")
    if max_frames == 0:
        return 0
    stop = stop if stop is not None else threading.Event()
    wait = wait if wait is not None else stop.wait
    schedule = _Schedule(pacing)
    published = 0
    resume = None  # (seq, timestamp_s) the next pass's first frame is renumbered to
    while True:
        seq_offset, time_offset, first, last, count = 0, 0.0, None, None, 0
        for i, frame in enumerate(source.frames()):
            if stop.is_set():
                return published
            if resume is not None:
                if i == 0:
                    seq_offset, time_offset = resume[0] - frame.seq, resume[1] - frame.timestamp_s
                frame = dataclasses.replace(frame, seq=frame.seq + seq_offset, timestamp_s=frame.timestamp_s + time_offset)
            delay = schedule.due(frame.timestamp_s, clock()) - clock()
            if delay > 0 and wait(delay):
                return published
            publish(frame)
            published += 1
            if max_frames is not None and published >= max_frames:
                return published
            if first is None:
                first = frame
            last = frame
            count += 1
        if not loop or stop.is_set():
            return published
        if last is None:
            log.warning("%s: a pass yielded no frame; not looping", source.name)
            return published
        period = (last.timestamp_s - first.timestamp_s) / (count - 1) if count > 1 else NOMINAL_PERIOD_S
        log.info("%s: end of pass after %d frames; starting over", source.name, count)
        resume = (last.seq + 1, last.timestamp_s + period)
