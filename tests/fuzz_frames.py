"""Hostile but decodable input for the perception service's core: frames, masks, parameters.

``FrameFuzzer(seed, defaults)`` yields a reproducible stream of events for a ``PerceptionCore``:
frames of a rendered sheet (tests.render) mixed with frames whose depth is huge, tiny, noise,
NaN but for one pixel, at the edges of the plausible range; intrinsics from a focal length of
1e-9 to 1e12 pixels, principal points far outside the image, extreme distortion; sizes from
1 x 1 to 300 x 300 changing from frame to frame; initialisation masks of the wrong size,
single pixels and full frames; and parameter changes to random values, in range or not, and back to ``defaults``.
Used by tests/unit/test_service_frame_fuzz.py and benchmarks/fuzz_services.py.
"""

from __future__ import annotations

import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.parameters import PARAMETER_RANGES
from tests.render import frame_of, grid_surface, plane_points, texture

CAMERA = CameraInfo.from_fov(160, 120, np.deg2rad(45))
SIZE = (0.6, 0.45)
CENTRE = np.array([0.0, 0.0, 1.3])


def sheet_frames(n: int = 6) -> list[RGBDFrame]:
    """``n`` frames of a textured sheet sliding sideways 5 mm a frame, 1.3 m from CAMERA."""
    uv, faces = grid_surface(*SIZE, 31, 24)
    tex = texture(np.random.default_rng(7))
    return [frame_of(plane_points(uv, CENTRE + [0.005 * k, 0.0, 0.0], SIZE), uv, faces, tex, CAMERA, SIZE, t=k / 30,
                     seq=k, noise_m=0.001, rng=np.random.default_rng(k)) for k in range(n)]


class FrameFuzzer:
    """Reproducible hostile events; see the module docstring.

    ``events(n)`` yields n tuples ``("frame", RGBDFrame)``, ``("initialise", mask or None)``
    or ``("parameters", dict)``.
    """

    def __init__(self, seed: int, defaults: dict, frames: list[RGBDFrame] | None = None):
        self.rng = np.random.default_rng(seed)
        self.defaults = defaults  # parameter values a controller goes back to
        self.good = frames if frames is not None else sheet_frames()
        self._changed: set = set()

    def events(self, n: int):
        for i in range(n):
            roll = self.rng.random()
            if roll < 0.08:
                yield "initialise", self.mask()
            elif roll < 0.11:
                yield "parameters", self.parameters()
            else:
                yield "frame", self.frame(i)

    # -- pieces -----------------------------------------------------------------------------

    def camera(self, h: int, w: int) -> CameraInfo:
        rng = self.rng
        f = 10.0 ** rng.uniform(-9, 12) if rng.random() < 0.5 else w / (2 * np.tan(np.deg2rad(rng.uniform(0.05, 179.9) / 2)))
        aspect = 10.0 ** rng.uniform(-1.5, 1.5) if rng.random() < 0.3 else 1.0
        cx = rng.choice([w / 2, -w, 2 * w, -1e6, 1e6, rng.uniform(-2 * w, 3 * w)])
        cy = rng.choice([h / 2, -h, 2 * h, -1e6, 1e6, rng.uniform(-2 * h, 3 * h)])
        D = rng.normal(0.0, 10.0 ** rng.uniform(-3, 3), rng.choice([0, 4, 5, 8]))
        return CameraInfo(width=w, height=h, K=np.array([[f, 0.0, cx], [0.0, f * aspect, cy], [0.0, 0.0, 1.0]]), D=D)

    def depth(self, base: np.ndarray) -> np.ndarray:
        rng = self.rng
        h, w = base.shape
        kind = rng.integers(7)
        if kind == 0:  # a few huge or tiny values among good ones
            out = base.copy()
            out[rng.random((h, w)) < rng.uniform(0.0, 0.5)] = rng.choice([1e30, 3e38, 1e-30, 1e-6, 5e-4, 1e4, 101.0])
            return out
        if kind == 1:  # one measured pixel
            out = np.full((h, w), np.nan, np.float32)
            out[rng.integers(h), rng.integers(w)] = rng.uniform(0.5, 3.0)
            return out
        if kind == 2:  # everything at one value, at or past the edges of the plausible range
            return np.full((h, w), rng.choice([1e-30, 1e-3, 0.0011, 99.9, 100.0, 1e30, 0.0]), np.float32)
        if kind == 3:  # noise anywhere in the plausible range, with holes
            out = rng.uniform(1e-3, 100.0, (h, w)).astype(np.float32)
            out[rng.random((h, w)) < 0.3] = 0.0
            return out
        if kind == 4:  # the scene scaled as by a wrong depth_scale
            return (base * np.float32(10.0 ** rng.uniform(-4, 4))).astype(np.float32)
        if kind == 5:  # NaN holes
            out = base.copy()
            out[rng.random((h, w)) < rng.uniform(0.5, 1.0)] = np.nan
            return out
        return base

    def frame(self, seq: int) -> RGBDFrame:
        rng = self.rng
        base = self.good[seq % len(self.good)]
        depth, rgb, camera = base.depth_m, base.rgb, base.camera
        kind = rng.integers(5)
        if kind == 0:  # another size, and a camera to go with it
            h, w = int(rng.integers(1, 300)), int(rng.integers(1, 300))
            camera = self.camera(h, w) if rng.random() < 0.5 else CameraInfo.from_fov(w, h, rng.uniform(0.1, 2.5))
            depth = rng.uniform(0.3, 5.0, (h, w)).astype(np.float32)
            rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        elif kind == 1:
            camera = self.camera(*depth.shape)
        elif kind == 2:
            depth = self.depth(depth)
        held = {}
        if rng.random() < 0.2:  # what a robot says it holds: vertices the mesh may not have, points far or near
            k = int(rng.integers(1, 4))
            held = {"held_vertices": rng.integers(0, 800, k).astype(np.int32),
                    "held_points_m": rng.normal(0.0, 1.0, (k, 3)) * 10.0 ** rng.uniform(-3, 4)}
            turns = np.random.default_rng(seq)  # its own stream: the frames drawn above stay as they were
            if turns.random() < 0.5:  # and how its grippers turn: any orientation, or none known for a point
                quats = turns.normal(0.0, 1.0, (k, 4))
                quats /= np.linalg.norm(quats, axis=1, keepdims=True)
                quats[turns.random(k) < 0.3] = np.nan
                held["held_quats_xyzw"] = quats
        return RGBDFrame(rgb=rgb, depth_m=depth, camera=camera, timestamp_s=seq / 30.0, seq=seq, **held)

    def mask(self) -> np.ndarray | None:
        rng = self.rng
        kind = rng.integers(4)
        if kind == 0:
            return None
        h, w = self.good[0].depth_m.shape
        if kind == 1:  # another size than the frames'
            h, w = int(rng.integers(1, 50)), int(rng.integers(1, 50))
        mask = np.zeros((h, w), np.uint8)
        if kind == 2:
            mask[rng.integers(h), rng.integers(w)] = 1
        else:
            mask[:] = 1
        return mask

    def parameters(self) -> dict:
        rng = self.rng
        if self._changed and rng.random() < 0.5:  # back to the defaults, as a controller undoing a change
            out = {name: self.defaults[name] for name in sorted(self._changed)}
            self._changed.clear()
            return out
        names = sorted(PARAMETER_RANGES)
        out = {}
        for name in rng.choice(names, size=int(rng.integers(1, 4)), replace=False):
            allowed = PARAMETER_RANGES[str(name)]
            ends = [allowed.lo, allowed.hi, allowed.hi * 10 + 1, rng.uniform(allowed.lo, allowed.hi)]
            value = ends[int(rng.integers(len(ends)))]
            out[str(name)] = int(value) if isinstance(allowed.lo, int) and isinstance(allowed.hi, int) else float(value)
        self._changed.update(out)
        return out
