"""Frames replayed from a recorded sequence folder (its layout: ``perception.sequence``)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from ipc.messages import RGBDFrame
from perception.sequence import open_sequence
from perception.sources._base import FrameSource


class SequenceSource(FrameSource):
    """Plays a sequence folder read with ``perception.sequence.open_sequence``.

    path : the folder; raises ``perception.sequence.SequenceError`` (a ValueError, one
        line) if it is missing or malformed

    Frames: seq = index in the sequence, timestamp_s = the colour image's timestamp,
    depth in metres from the uint16 PNGs; ``depth_scale`` is the sequence's, so the wire
    carries exactly the recorded depth units.
    """

    def __init__(self, path: str | Path):
        self.sequence = open_sequence(path)
        self.name = f"sequence:{Path(path).name}"
        self.camera = self.sequence.camera
        self.depth_scale = self.sequence.depth_scale

    def __len__(self) -> int:
        return len(self.sequence)

    def frames(self) -> Iterator[RGBDFrame]:
        for i in range(len(self.sequence)):
            yield self.sequence.frame(i)
