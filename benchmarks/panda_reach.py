"""Which of the unfold task's motions a Franka Panda reaches, from the drawn arms' mounts and from its own.

    python benchmarks/panda_reach.py [--poses 100] [--seed 1]

Gripper poses drawn at random (seeded) for each kind of motion of the left arm
(``sim.laundry.unfold``; the right one is its mirror image), the table top at 0.77 m:
grasps on the near half of the table (a corner 0-12 cm above it, the gripper pointing down
within 23 degrees, turned any way about its approach), the top of a lift (0.75-0.95 m above
the table, anywhere over its near half), and second grasps in the air (a hanging cloth's
corner 0.3-0.8 m above the table, approached from any side within 17 degrees of level).
Each is solved by ``sim.panda.PandaArm`` on each mount; the table gives the share reached.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from perception.geometry import rigid_transform  # noqa: E402
from sim.laundry.unfold import UnfoldConfig, shoulders  # noqa: E402
from sim.panda import PandaArm  # noqa: E402

TABLE_TOP_M = 0.7665
DOWN = np.column_stack([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def poses(n: int, rng: np.random.Generator) -> dict[str, list[np.ndarray]]:
    """``n`` poses of each kind of motion (module docstring), world frame."""
    def pointing_down() -> np.ndarray:
        return Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix() \
            @ Rotation.from_euler("x", rng.uniform(0.0, 0.4)).as_matrix() @ DOWN

    def near_half(low: float, high: float) -> list[float]:
        return [rng.uniform(-0.35, 0.0), rng.uniform(-0.3, 0.3), TABLE_TOP_M + rng.uniform(low, high)]

    out: dict[str, list[np.ndarray]] = {"grasp on the table": [], "top of the lift": [], "second grasp in the air": []}
    for _ in range(n):
        out["grasp on the table"].append(rigid_transform(pointing_down(), near_half(0.0, 0.12)))
        out["top of the lift"].append(rigid_transform(pointing_down(), near_half(0.75, 0.95)))
        yaw = rng.uniform(-np.pi, np.pi)
        z = np.array([np.cos(yaw), np.sin(yaw), rng.uniform(-0.3, 0.3)])
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        out["second grasp in the air"].append(rigid_transform(np.column_stack([x, np.cross(z, x), z]),
                                                    [rng.uniform(-0.35, 0.1), rng.uniform(-0.2, 0.2),
                                                     TABLE_TOP_M + rng.uniform(0.3, 0.8)]))
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python benchmarks/panda_reach.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--poses", type=int, default=100, help="poses of each kind (default 100)")
    p.add_argument("--seed", type=int, default=1)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    drawn = poses(args.poses, np.random.default_rng(args.seed))
    print(f"| mount (left arm's shoulder) | {' | '.join(drawn)} |")
    print("| --- |" + " --- |" * len(drawn))
    for name, arm in (("the drawn arms'", "drawn"), ("the Panda's (the unfold trials' with --arm panda)", "panda")):
        shoulder, _ = shoulders(TABLE_TOP_M, UnfoldConfig(), arm)
        with PandaArm.at_shoulder(shoulder, [0.0, 0.0, TABLE_TOP_M]) as panda:
            shares = [np.mean([panda.solve(T).reachable for T in group]) for group in drawn.values()]
        where = f"{shoulder[0]:+.2f}, {shoulder[1]:.2f}, table + {shoulder[2] - TABLE_TOP_M:.2f} m"
        print(f"| {name} ({where}) | " + " | ".join(f"{100 * s:.0f} %" for s in shares) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
