"""How the gripper holding a cloth has turned since the last frame.

A robot turning its wrist turns the cloth hanging from it. The camera sees that poorly: a
hanging cloth turned a quarter turn shows the camera its edge, then its other face, and
the parts it hides have nothing to follow but the tracker's prediction. The robot knows the
turn from its own kinematics; it sends the orientation of the gripper holding each held
point with every frame (``RGBDFrame.held_quats_xyzw``), and the tracker predicts the cloth
turned with it about the held point (``HeldTurns.turn``, ``Turn.apply``).

Only a cloth held by one gripper is turned: one held by two does not turn rigidly with
either of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ipc.messages import RGBDFrame

#: Turns smaller than this (radians) are no turn: the prediction is left exactly as it was.
MIN_TURN_RAD = 1e-6


@dataclass(frozen=True)
class Turn:
    """A rotation ``R`` (3, 3) about the point ``pivot_m`` (3,), camera frame, metres."""

    R: np.ndarray
    pivot_m: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) ``points`` (N, 3) turned by ``R`` about ``pivot_m``."""
        return (np.asarray(points, dtype=np.float64) - self.pivot_m) @ self.R.T + self.pivot_m


class HeldTurns:
    """Remembers the grippers' orientations frame to frame and gives the turn between two.

    ``turn(frame)`` is asked once per frame, in order; ``forget()`` when the mesh changes
    (its vertex ids name other points then).
    """

    def __init__(self):
        self._last: dict[int, np.ndarray] = {}  # held vertex -> its gripper's quaternion, last frame

    def forget(self) -> None:
        self._last = {}

    def turn(self, frame: RGBDFrame) -> Turn | None:
        """The turn of the one gripper whose orientation ``frame`` gives, since the last
        frame given to this method, about the point it holds now; None when ``frame`` gives
        no orientation or more than one, when the last frame gave none for the same vertex,
        or when the gripper did not turn."""
        quats = frame.held_quats_xyzw
        last, self._last = self._last, {}
        if quats is None:
            return None
        rows = np.flatnonzero(np.all(np.isfinite(quats), axis=1))
        self._last = {int(frame.held_vertices[r]): quats[r] for r in rows}
        if rows.size != 1 or int(frame.held_vertices[rows[0]]) not in last:
            return None
        row = int(rows[0])
        rotation = Rotation.from_quat(quats[row]) * Rotation.from_quat(last[int(frame.held_vertices[row])]).inv()
        if rotation.magnitude() < MIN_TURN_RAD:
            return None
        return Turn(rotation.as_matrix(), frame.held_points_m[row].copy())
