"""A robot's parallel gripper with its wrist and a two-link arm, as a ``sim.solids`` mesh to draw.

The gripper's frame follows the grasp planner's and ``sim.grasp_execution``'s convention:
z is the approach direction (palm to fingertips), x the direction the fingers close along,
y = z x x, and the origin is where the fingertips close. In that frame:

- two fingers, boxes ``finger_length_m`` long from the fingertips (z = 0) back to the palm,
  their inner faces at x = -opening/2 and x = +opening/2;
- the palm, a box behind the fingers (z < -finger_length_m), as wide as the open fingers;
- the wrist, a cylinder straight back from the palm along -z.

Behind the wrist the arm reaches a shoulder (a fixed point of the world, the robot's
base) through an elbow: a forearm and an upper arm of fixed lengths, solved as a planar
two-link chain with the elbow bent upwards (towards world +z). A shoulder out of reach is
drawn with the arm stretched straight towards it. Without a shoulder, the forearm carries
straight on along -z.

Units: metres; frames: world z up; colours RGB in [0, 255].
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from perception.geometry import check_transform
from sim.solids import SolidMesh, box, capsule, cylinder, merge, sphere

log = logging.getLogger(__name__)


def elbow_position(wrist_world, shoulder_world, forearm_m: float, upper_arm_m: float,
                   up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(3,) float64 elbow of a planar two-link arm from the wrist to the shoulder, bent towards ``up``.

    wrist_world, shoulder_world : (3,) metres; forearm_m : wrist to elbow; upper_arm_m :
    elbow to shoulder. Out of reach (farther than the sum of the links): the elbow lies on
    the straight line to the shoulder. Closer than their difference: the arm folds fully.
    """
    w = np.asarray(wrist_world, dtype=np.float64).reshape(3)
    s = np.asarray(shoulder_world, dtype=np.float64).reshape(3)
    l1, l2 = float(forearm_m), float(upper_arm_m)
    if not (l1 > 0 and l2 > 0):
        raise ValueError(f"elbow_position: expected positive link lengths, got {forearm_m} and {upper_arm_m}")
    d_vec = s - w
    d = float(np.linalg.norm(d_vec))
    if d < 1e-9:
        raise ValueError("elbow_position: the wrist is at the shoulder")
    u = d_vec / d
    bend = np.asarray(up, dtype=np.float64) - (np.asarray(up, dtype=np.float64) @ u) * u
    if np.linalg.norm(bend) < 1e-6:  # reaching straight up or down: bend towards any side
        bend = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    bend /= np.linalg.norm(bend)
    cos_a = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
    return w + l1 * (cos_a * u + np.sqrt(1.0 - cos_a * cos_a) * bend)


@dataclass(frozen=True)
class GripperLook:
    """Sizes and colours of a drawn parallel gripper, wrist and arm (metres, RGB 0-255).

    finger_length_m, finger_width_m (along y), finger_thickness_m (along x)
    max_opening_m : opening of the open fingers; the palm is as wide
    palm_depth_m : along z; wrist_radius_m, wrist_length_m : the cylinder behind the palm
    forearm_length_m, upper_arm_length_m, arm_radius_m : the two links to the shoulder
    finger_rgb, body_rgb, arm_rgb : colours
    """

    finger_length_m: float = 0.05
    finger_width_m: float = 0.02
    finger_thickness_m: float = 0.012
    max_opening_m: float = 0.08
    palm_depth_m: float = 0.04
    wrist_radius_m: float = 0.035
    wrist_length_m: float = 0.08
    forearm_length_m: float = 0.30
    upper_arm_length_m: float = 0.35
    arm_radius_m: float = 0.045
    finger_rgb: tuple = (60, 60, 66)
    body_rgb: tuple = (200, 200, 205)
    arm_rgb: tuple = (235, 235, 238)

    def __post_init__(self):
        for name in ("finger_length_m", "finger_width_m", "finger_thickness_m", "max_opening_m", "palm_depth_m",
                     "wrist_radius_m", "wrist_length_m", "forearm_length_m", "upper_arm_length_m", "arm_radius_m"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"GripperLook.{name}: expected a positive number, got {value}")

    @classmethod
    def random(cls, rng: np.random.Generator) -> GripperLook:
        """Sizes and greys drawn from the range of common two-finger robot grippers and arms."""
        grey = rng.uniform(40, 90)
        light = rng.uniform(170, 240)
        tint = rng.uniform(-12, 12, 3)
        return cls(
            finger_length_m=rng.uniform(0.04, 0.065),
            finger_width_m=rng.uniform(0.015, 0.025),
            finger_thickness_m=rng.uniform(0.01, 0.016),
            max_opening_m=rng.uniform(0.06, 0.09),
            palm_depth_m=rng.uniform(0.035, 0.06),
            wrist_radius_m=rng.uniform(0.03, 0.04),
            wrist_length_m=rng.uniform(0.06, 0.1),
            forearm_length_m=rng.uniform(0.28, 0.36),
            upper_arm_length_m=rng.uniform(0.32, 0.42),
            arm_radius_m=rng.uniform(0.035, 0.05),
            finger_rgb=tuple(np.clip(grey + tint, 0, 255)),
            body_rgb=tuple(np.clip(light - 20 + tint, 0, 255)),
            arm_rgb=tuple(np.clip(light + tint, 0, 255)),
        )

    def hand(self, opening_m: float) -> SolidMesh:
        """Fingers, palm and wrist in the gripper frame, the fingers ``opening_m`` apart (clipped to
        [0, max_opening_m])."""
        opening = float(np.clip(opening_m, 0.0, self.max_opening_m))
        fl, fw, ft = self.finger_length_m, self.finger_width_m, self.finger_thickness_m
        parts = []
        for side in (-1.0, 1.0):
            T = np.eye(4)
            T[:3, 3] = (side * (0.5 * opening + 0.5 * ft), 0.0, -0.5 * fl)
            parts.append(box((0.5 * ft, 0.5 * fw, 0.5 * fl), self.finger_rgb, T))
        palm_half = (0.5 * self.max_opening_m + ft, 0.5 * fw + 0.01, 0.5 * self.palm_depth_m)
        T = np.eye(4)
        T[:3, 3] = (0.0, 0.0, -fl - 0.5 * self.palm_depth_m)
        parts.append(box(palm_half, self.body_rgb, T))
        back = -fl - self.palm_depth_m
        parts.append(cylinder((0.0, 0.0, back), (0.0, 0.0, back - self.wrist_length_m), self.wrist_radius_m,
                              self.body_rgb))
        return merge(parts)

    def wrist_end(self, T_world_gripper: np.ndarray) -> np.ndarray:
        """(3,) world point where the wrist meets the forearm."""
        T = check_transform("T_world_gripper", T_world_gripper)
        back = self.finger_length_m + self.palm_depth_m + self.wrist_length_m
        return T[:3, 3] - back * T[:3, 2]

    def mesh(self, T_world_gripper: np.ndarray, opening_m: float, shoulder_world=None) -> SolidMesh:
        """The gripper, its wrist and its arm, in the world frame.

        T_world_gripper : (4, 4) gripper frame (see the module docstring) to world
        opening_m : distance between the fingers' inner faces
        shoulder_world : (3,) where the arm is mounted, or None for a forearm straight back
        """
        T = check_transform("T_world_gripper", T_world_gripper)
        wrist = self.wrist_end(T)
        if shoulder_world is None:
            elbow = wrist - self.forearm_length_m * T[:3, 2]
            links = [(wrist, elbow)]
        else:
            shoulder = np.asarray(shoulder_world, dtype=np.float64).reshape(3)
            elbow = elbow_position(wrist, shoulder, self.forearm_length_m, self.upper_arm_length_m)
            reach = elbow + self.upper_arm_length_m * (shoulder - elbow) / max(np.linalg.norm(shoulder - elbow), 1e-9)
            links = [(wrist, elbow), (elbow, reach)]
        r = self.arm_radius_m
        parts = [self.hand(opening_m).transformed(T), sphere(wrist, 1.1 * self.wrist_radius_m, self.body_rgb)]
        parts += [capsule(a, b, r, self.arm_rgb) for a, b in links]
        return merge(parts)
