"""Pictures of an estimate: the mesh drawn over the RGB frame (as the paper's Fig. 6).

Pure drawing on arrays; saving them is the caller's business.
"""

from __future__ import annotations

import cv2
import numpy as np

from ipc.messages import MeshEstimate
from perception.geometry import project, unique_edges


def draw_mesh(rgb: np.ndarray, estimate: MeshEstimate, K: np.ndarray, thickness: int = 1) -> np.ndarray:
    """The estimate's edges over a copy of ``rgb`` (H, W, 3) uint8: interior edges yellow,
    boundary vertices blue, and a status line (confidence, lost). Returns (H, W, 3) uint8 RGB."""
    out = np.ascontiguousarray(rgb.copy())
    uv = project(estimate.vertices, K)
    edges = unique_edges(estimate.faces)
    ok = np.all(np.isfinite(uv[edges]).reshape(len(edges), -1), axis=1)
    lines = np.rint(uv[edges[ok]] * 16).astype(np.int32)  # 4 bits of sub-pixel precision
    colour = (255, 60, 60) if estimate.lost else (255, 230, 0)
    cv2.polylines(out, list(lines), False, colour, thickness, cv2.LINE_AA, shift=4)
    for u, v in uv[estimate.boundary]:
        if np.isfinite(u) and np.isfinite(v):
            cv2.circle(out, (int(round(u)), int(round(v))), 2, (40, 90, 255), -1, cv2.LINE_AA)
    text = f"#{estimate.seq}  conf {estimate.confidence:.2f}{'  LOST' if estimate.lost else ''}  {estimate.timing_ms:.0f} ms"
    outlined_text(out, text, (8, 20))
    return out


#: The font of the pictures' labels (``outlined_text``, ``text_width_px``).
FONT = cv2.FONT_HERSHEY_SIMPLEX


def text_width_px(text: str, scale: float = 0.55) -> int:
    """Width in pixels of ``text`` as ``outlined_text`` draws it at ``scale``."""
    return int(cv2.getTextSize(text, FONT, scale, 1)[0][0])


def outlined_text(rgb: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.55) -> None:
    """Draw white text with a black outline into ``rgb`` (H, W, 3) uint8, in place.

    The outline is the same text drawn black one pixel to each side: OpenCV advances each
    letter by the stroke thickness too, so a thicker black copy under the white one would
    drift right along the line and show as a second, offset label.
    """
    x, y = origin
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                cv2.putText(rgb, text, (x + dx, y + dy), FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(rgb, text, (x, y), FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)


def ply_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """An ASCII PLY of a triangle mesh: vertices (N, 3) float, faces (M, 3) int."""
    head = (f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    body = "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices)
    body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    return (head + body).encode()
