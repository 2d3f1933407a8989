"""The one interface of a simulated scene, whatever its script: a cloth in a PyBullet world
seen by a virtual RGB-D camera, with its ground truth.

``ClothScene`` (``sim.scenes``: the paper's scenes and the handled ones) and
``LaundryScene`` (``sim.laundry``: the grasping trials' cloth on a table) both implement
``Scene``; everything that runs a scene (``sim.frame_source.SceneSource``, the recorder,
tracker evaluation, the trials) needs no more than this. A new scene implements it too
(docs/architecture.md, "Adding a scene").

Frames: ``render`` returns an ``ipc.RGBDFrame`` (rgb (H, W, 3) uint8, depth_m (H, W)
float32 metres along the optical axis, 0 where nothing is measured) of the scene's
``camera``, with ``seq`` = ``frame_index`` and ``timestamp_s`` = ``time_s``. Ground truth
is in the camera's optical frame (x right, y down, z forward), metres.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from sim.noise import add_colour_noise, add_depth_noise


@runtime_checkable
class Scene(Protocol):
    """A simulated cloth scene (see the module docstring).

    name : short name for logs and a frame source's heartbeats
    camera : CameraInfo of the rendered frames
    fps : frames per simulated second
    frame_index : the current frame, 0 after construction and ``reset``
    """

    name: str
    camera: CameraInfo
    frame_index: int

    @property
    def fps(self) -> float:
        """Frames per simulated second."""

    @property
    def time_s(self) -> float:
        """Time of the current frame, seconds after frame 0."""

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 faces of the cloth mesh."""

    @property
    def uv_m(self) -> np.ndarray:
        """(V, 2) float64 material coordinates of the cloth's vertices, metres on the flat cloth."""

    def reset(self) -> None:
        """Back to frame 0 of the same scene: the frames that follow are the same again."""

    def step(self) -> None:
        """Advance one frame period (1 / ``fps`` s)."""

    def render(self) -> RGBDFrame:
        """The current frame as the sensor sees it."""

    def cloth_mask(self) -> np.ndarray:
        """(H, W) bool, where the last ``render`` saw the cloth (exact, before noise)."""

    def cloth_vertices_cam(self) -> np.ndarray:
        """(V, 3) float64 the cloth's vertices now, metres, camera optical frame."""

    def cloth_vertices_world(self) -> np.ndarray:
        """(V, 3) float64 the cloth's vertices now, metres, world frame (z up)."""

    def close(self) -> None:
        """Release the physics world (idempotent)."""


class PhysicsScene:
    """What ``ClothScene`` and ``LaundryScene`` share: a cloth in a ``sim.physics.ClothPhysics``
    world seen by a ``sim.camera.VirtualCamera``, and sensor noise from a seeded stream.

    A subclass sets ``spec`` (with ``spec.cloth``, a ``sim.cloth_mesh.ClothMesh``),
    ``physics``, ``virtual_camera``, ``frame_index``, ``noise``, ``noise_model`` and
    ``_noise_rng`` when it builds its world, and implements the rest of ``Scene``.
    """

    fps: float = 30.0

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect PyBullet (idempotent)."""
        if getattr(self, "physics", None) is not None:
            self.physics.close()
            self.physics = None

    @property
    def time_s(self) -> float:
        """Time of the current frame, seconds after frame 0."""
        return self.frame_index / self.fps

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 cloth faces, counter-clockwise seen from the cloth's front."""
        return self.spec.cloth.faces

    @property
    def uv_m(self) -> np.ndarray:
        """(V, 2) float64 material coordinates of the cloth vertices, metres (``ClothMesh.uv_m``)."""
        return self.spec.cloth.uv_m

    def cloth_vertices_world(self) -> np.ndarray:
        """(V, 3) float64 cloth vertices now, metres, world frame."""
        return self.physics.cloth_vertices()

    def cloth_vertices_cam(self) -> np.ndarray:
        """(V, 3) float64 cloth vertices now, metres, camera optical frame (the ground truth)."""
        return self.virtual_camera.world_to_camera(self.physics.cloth_vertices())

    def _sensed(self, rgb: np.ndarray, depth_m: np.ndarray,
                rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """An exact image as the sensor gives it: with depth and then colour noise when the
        scene has noise (``sim.noise``), drawn from ``rng`` (default: the scene's noise stream)."""
        if not self.noise:
            return rgb, depth_m
        rng = self._noise_rng if rng is None else rng
        depth_m = add_depth_noise(depth_m, self.camera.K, self.noise_model, rng)
        rgb = add_colour_noise(rgb, self.noise_model.colour_sigma, rng)
        return rgb, depth_m


def check_seed(seed) -> int:
    """``seed`` as an int >= 0 (never a bool), else ValueError naming what was received."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"expected a non-negative integer seed, got {seed!r}")
    return int(seed)
