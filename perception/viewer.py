"""A live view of the perception service in Rerun (optional ``rerun-sdk``, extra "viewer")."""

from __future__ import annotations

import importlib

import numpy as np

from ipc.messages import MeshEstimate, RGBDFrame
from perception.geometry import backproject


class RerunViewer:
    """Live view of the service in Rerun (optional ``rerun-sdk`` >= 0.23, extra "viewer").

    target : "spawn" starts a Rerun viewer window; any other string is a path where the
        recording is saved (.rrd), for machines without a display

    Logged per frame on timeline "frame" (the frame's seq), in the camera's optical frame
    (right, down, forward): ``camera`` (pinhole), ``camera/rgb``, ``camera/depth``
    (metres), ``points`` (the depth image back-projected, every ``POINT_STRIDE``-th pixel,
    coloured) and ``mesh`` (the estimate's triangles).
    """

    POINT_STRIDE = 4  # a 640x480 frame gives ~19k points: enough to judge the fit, light to send

    def __init__(self, target: str = "spawn"):
        try:
            rr = importlib.import_module("rerun")
        except ImportError as e:
            raise RuntimeError(f"the live viewer needs the Python module 'rerun' ({e}); "
                               "install it from the clothkit checkout with: pip install -e '.[viewer]'") from None
        self._rr = rr
        rr.init("clothkit perception", spawn=(target == "spawn"))
        if target != "spawn":
            rr.save(target)
        rr.log("/", rr.ViewCoordinates.RDF, static=True)

    def show(self, frame: RGBDFrame, estimate: MeshEstimate | None) -> None:
        """Log ``frame`` and, if given, the estimate tracked on it."""
        rr = self._rr
        cam = frame.camera
        rr.set_time("frame", sequence=frame.seq)
        rr.log("camera", rr.Pinhole(image_from_camera=cam.K, width=cam.width, height=cam.height))
        rr.log("camera/rgb", rr.Image(frame.rgb))
        rr.log("camera/depth", rr.DepthImage(frame.depth_m, meter=1.0))
        s = self.POINT_STRIDE
        depth = frame.depth_m[::s, ::s]
        rows, cols = np.nonzero(np.isfinite(depth) & (depth > 0))
        z = depth[rows, cols].astype(np.float64)
        u, v = cols * s, rows * s
        points = backproject(np.column_stack([u, v]), z, cam.K)
        rr.log("points", rr.Points3D(points, colors=frame.rgb[v, u]))
        if estimate is not None:
            rr.log("mesh", rr.Mesh3D(vertex_positions=estimate.vertices, triangle_indices=estimate.faces))

    def close(self) -> None:
        self._rr.disconnect()
