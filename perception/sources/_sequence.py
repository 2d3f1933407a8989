"""Frames replayed from a recorded sequence folder (its layout: ``perception.sequence``)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

from ipc.messages import RGBDFrame
from perception.sequence import SequenceError, open_sequence
from perception.sources._base import FrameSource

log = logging.getLogger(__name__)


class SequenceSource(FrameSource):
    """Plays a sequence folder read with ``perception.sequence.open_sequence``.

    path : the folder; raises ``perception.sequence.SequenceError`` (a ValueError, one
        line) if it is missing or malformed

    Frames: seq = index in the sequence, timestamp_s = the colour image's timestamp,
    depth in metres from the uint16 PNGs; ``depth_scale`` is the sequence's, so the wire
    carries exactly the recorded depth units. A frame whose images cannot be read (a
    truncated PNG, another size than the first) is skipped with a warning naming the file,
    as a camera drops a frame, and counted in ``skipped``: the stream goes on.
    """

    def __init__(self, path: str | Path):
        self.sequence = open_sequence(path)
        self.name = f"sequence:{Path(path).name}"
        self.camera = self.sequence.camera
        self.depth_scale = self.sequence.depth_scale
        self.skipped = 0

    def __len__(self) -> int:
        return len(self.sequence)

    def frames(self) -> Iterator[RGBDFrame]:
        for i in range(len(self.sequence)):
            try:
                frame = self.sequence.frame(i)
            except SequenceError as e:
                self.skipped += 1
                log.warning("%s: frame %d skipped: %s", self.name, i, e)
                continue
            yield frame
