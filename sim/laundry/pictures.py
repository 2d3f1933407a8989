"""Pictures of a trial: the plan drawn on the frame it was made from, and the grasp.

Pure drawing on (H, W, 3) uint8 RGB arrays; ``save_png`` is the only function that
writes. Colours: true corners green, the estimate's mesh yellow (``perception.overlay``),
grasp candidates orange, the executed grasp red with its approach arrow (from the
pre-grasp point to the grasp point).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ipc.messages import GraspPlan, MeshEstimate
from perception.geometry import project
from perception.overlay import draw_mesh, outlined_text, text_width_px

GREEN, ORANGE, RED = (40, 200, 60), (255, 150, 0), (230, 20, 20)


def _pixels(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 2) int pixel positions of camera-frame points (N, 3), metres; points behind map far away."""
    uv = project(np.asarray(points_cam, dtype=np.float64).reshape(-1, 3), K)
    return np.nan_to_num(uv, nan=-1e4).round().astype(np.int64).clip(-10000, 10000)


def caption(rgb: np.ndarray, text: str, row: int = 0) -> np.ndarray:
    """A copy of ``rgb`` with text at the bottom-left, its last line in ``row`` (0 lowest). Text
    wider than the picture is wrapped at spaces onto the rows above, so that a long verdict is
    read whole rather than cut at the picture's edge."""
    out = np.ascontiguousarray(rgb.copy())
    lines = _wrapped(text, out.shape[1] - 16)
    for k, line in enumerate(lines):
        outlined_text(out, line, (8, out.shape[0] - 10 - 22 * (row + len(lines) - 1 - k)))
    return out


def _wrapped(text: str, width_px: int) -> list[str]:
    """``text`` in lines no wider than ``width_px`` as ``outlined_text`` draws them (a single word
    wider than that stays whole on its line)."""
    lines: list[str] = []
    for word in text.split():
        wider = f"{lines[-1]} {word}" if lines else word
        if lines and text_width_px(wider) <= width_px:
            lines[-1] = wider
        else:
            lines.append(word)
    return lines or [""]


def draw_plan(rgb: np.ndarray, K: np.ndarray, plans: list[GraspPlan], corners_cam: np.ndarray,
              estimate: MeshEstimate | None = None, arrow_m: float = 0.10) -> np.ndarray:
    """The plan over a copy of the frame it was made from.

    rgb : (H, W, 3) uint8; K : (3, 3) intrinsics
    plans : candidates, best (the executed one) first, camera frame
    corners_cam : (C, 3) float metres, true corners in the camera frame at plan time
    estimate : the MeshEstimate planned on, drawn as its mesh when given
    arrow_m : length of the approach arrow, metres (from the pre-grasp side)
    """
    out = draw_mesh(rgb, estimate, K) if estimate is not None else np.ascontiguousarray(rgb.copy())
    for u, v in _pixels(corners_cam, K):
        cv2.circle(out, (int(u), int(v)), 7, GREEN, 2, cv2.LINE_AA)
    for plan in plans[1:]:
        u, v = _pixels(plan.position, K)[0]
        cv2.circle(out, (int(u), int(v)), 4, ORANGE, -1, cv2.LINE_AA)
    if plans:
        best = plans[0]
        start, tip = _pixels(np.stack([best.position - arrow_m * best.approach, best.position]), K)
        cv2.arrowedLine(out, tuple(int(c) for c in start), tuple(int(c) for c in tip), RED, 2, cv2.LINE_AA, tipLength=0.25)
        cv2.circle(out, tuple(int(c) for c in tip), 5, RED, -1, cv2.LINE_AA)
    return out


def draw_point(rgb: np.ndarray, K: np.ndarray, point_cam: np.ndarray, colour=RED) -> np.ndarray:
    """A copy of ``rgb`` with a ring at a camera-frame point (3,), metres."""
    out = np.ascontiguousarray(rgb.copy())
    u, v = _pixels(point_cam, K)[0]
    cv2.circle(out, (int(u), int(v)), 8, colour, 2, cv2.LINE_AA)
    return out


def strip(panels: list[np.ndarray]) -> np.ndarray:
    """Panels of one height side by side, (H, sum W, 3) uint8."""
    return np.concatenate([np.ascontiguousarray(p) for p in panels], axis=1)


def save_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB image as PNG, creating the folder; raises OSError naming the path if it cannot."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write {path}")
