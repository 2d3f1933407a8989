"""A simulated scene as a frame source: what its virtual RGB-D camera sees, frame by frame.

``SceneSource`` is a ``perception.sources.FrameSource`` over any ``sim.scene.Scene``, so
simulated frames take the same path as a sensor's or a recording's: published by
``perception.sources.run_publisher`` (``python -m launch_scripts.publish_frames sim``) or
handed to any callable by ``perception.sources.publish_frames`` (the trials).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

from ipc.messages import RGBDFrame
from perception.sources import FrameSource
from sim.scene import Scene

log = logging.getLogger(__name__)


class SceneSource(FrameSource):
    """A scene stepping at its frame rate and rendering each frame.

    scene : a Scene at its frame 0; the source owns it (``close`` closes it)
    n_frames : frames per pass, >= 1 (None: the pass never ends)
    name : for logs and a publisher's heartbeats (default ``sim:`` and the scene's name)

    Frames: seq = frame index from 0, timestamp_s = index / fps, float32 depth (an exact
    rendering, so ``depth_scale`` is None). A pass after the first resets the scene, so
    every pass shows the same frames. Between two frames of a pass the scene is stepped
    only when the next frame is asked for: once a consumer stops taking frames, the scene
    stays at the last frame it was given.
    """

    def __init__(self, scene: Scene, n_frames: int | None = None, name: str | None = None):
        if n_frames is not None and n_frames < 1:
            raise ValueError(f"SceneSource.n_frames: expected a positive number or None, got {n_frames}")
        self.scene = scene
        self.n_frames = n_frames
        self.name = name if name is not None else f"sim:{scene.name}"
        self.camera = scene.camera
        self._fresh = True

    def frames(self) -> Iterator[RGBDFrame]:
        scene = self.scene
        if not self._fresh:
            scene.reset()
        self._fresh = False
        k = 0
        while self.n_frames is None or k < self.n_frames:
            if k:
                scene.step()
            yield scene.render()
            k += 1

    def close(self) -> None:
        self.scene.close()
