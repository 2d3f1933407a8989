"""Frames from a simulated cloth scene (``sim.scenes``) seen by its virtual RGB-D camera."""

from __future__ import annotations

import logging
from collections.abc import Iterator

from ipc.messages import RGBDFrame
from perception.sources._base import FrameSource

log = logging.getLogger(__name__)


class SimSource(FrameSource):
    """A registered scene (``sim.scenes.SCENES``) stepping at 30 Hz and rendering each frame.

    scene : scene name, e.g. "poster_bend"
    seed : int >= 0; the same seed gives the same frames
    noise : add the sensor noise model to the rendered frames
    width, height : image size, pixels
    n_frames : frames per pass (None: never ends)
    occluders : draw the scene's occluders (a swept bar, a robot's gripper and arm); False
        sends the scene's twin, the same cloth motion with nothing in front of it
    known_occluders : each frame carries ``occluder_mask``, the exact mask of the drawn
        occluders, as a robot that knows where its own gripper and arm are would send it

    Frames: seq = frame index from 0, timestamp_s = index / 30 s, float32 depth (exact
    rendering, so ``depth_scale`` is None). A new pass resets the scene to ``seed``.
    PyBullet is imported when the source is made, not with this package.
    """

    def __init__(self, scene: str, seed: int = 0, noise: bool = True, width: int = 640, height: int = 480,
                 n_frames: int | None = None, occluders: bool = True, known_occluders: bool = False):
        from sim.scenes import make_scene

        if n_frames is not None and n_frames < 1:
            raise ValueError(f"SimSource.n_frames: expected a positive number or None, got {n_frames}")
        self.name = f"sim:{scene}"
        self.seed = seed
        self.n_frames = n_frames
        self._scene = make_scene(scene, seed=seed, noise=noise, width=width, height=height, occluders=occluders,
                                 known_occluders=known_occluders)
        self.camera = self._scene.camera
        self._fresh = True

    @property
    def script_frames(self) -> int:
        """Frames the scene's script is written for (60 for the paper's scenes)."""
        return self._scene.n_frames

    def frames(self) -> Iterator[RGBDFrame]:
        scene = self._scene
        if not self._fresh:
            scene.reset(self.seed)
        self._fresh = False
        k = 0
        while self.n_frames is None or k < self.n_frames:
            if k:
                scene.step()
            yield scene.render()
            k += 1

    def close(self) -> None:
        self._scene.close()
