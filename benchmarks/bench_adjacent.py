"""Adjacent-corners benchmark: how well ``material_distance_m`` measures a cloth's edges, and
what a request costs.

    python benchmarks/bench_adjacent.py [--spacing-m 0.02] [--runs 30]

Accuracy: rectangles of 0.5 x 0.35 m at 13 angles to the tracker's hexagonal lattice and 3
lattice phases, meshed as the tracker meshes an object (perception.mesh). For every corner
and each of its two adjacent corners it prints, in millimetres, the excess of the reported
``material_distance_m`` over the straight distance between the two corner vertices (the
sides are straight, so 0 is exact), beside the same for the length of the raw outline
(the path of mesh edges, which zigzags across the lattice rows), and the difference from
the rectangle's true side (the mesh's corner vertices lie inside the cloth's corners).

Speed: median time of ``GraspPlanner.adjacent_corners`` on a flat towel with a cached
analysis of its canonical mesh, beside its peer, ``GraspPlanner.plan`` for corner grasps on
the same estimate, for a coarse and a fine mesh. The machine's core count is printed.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from grasping import GraspPlanner
from ipc.messages import MeshEstimate
from perception.mesh import lattice_covering, lattice_to_xy, mesh_from_lattice, rectangle_mesh
from sim.cloth_mesh import points_in_polygon

SIDES_M = (0.5, 0.35)


def rectangle_estimate(angle_deg: float, phase_m: tuple[float, float], spacing_m: float) -> tuple[MeshEstimate, np.ndarray]:
    a = np.radians(angle_deg)
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    width, height = SIDES_M
    polygon = np.array([[0, 0], [width, 0], [width, height], [0, height]]) @ rotation.T + phase_m
    lattice = lattice_covering((polygon[:, 0].min(), polygon[:, 0].max()), (polygon[:, 1].min(), polygon[:, 1].max()),
                               spacing_m)
    mesh = mesh_from_lattice(lattice[points_in_polygon(lattice_to_xy(lattice, spacing_m), polygon)], spacing_m)
    canonical = mesh.canonical
    estimate = MeshEstimate(vertices=canonical + [0.0, 0.0, 1.0], faces=mesh.faces, boundary=mesh.boundary,
                            canonical=canonical)
    return estimate, polygon


def raw_outline_length(planner: GraspPlanner, estimate: MeshEstimate, held: int, corner: int, side: int) -> float:
    outline = planner._model_for(estimate).outline
    rows = [int(np.flatnonzero(outline.vertex_ids == v)[0]) for v in (held, corner)]
    perimeter = float(outline.perimeters_m[outline.loop_ids[rows[0]]])
    return float(np.mod(side * (outline.arclength_m[rows[1]] - outline.arclength_m[rows[0]]), perimeter))


def accuracy(spacing_m: float) -> None:
    excess, raw_excess, vs_side = [], [], []
    for angle_deg in range(0, 90, 7):
        for phase in [(0.0, 0.0), (0.007, 0.003), (0.013, 0.011)]:
            estimate, _ = rectangle_estimate(angle_deg, phase, spacing_m)
            planner = GraspPlanner()
            corners = planner.corners(estimate)
            if len(corners) != 4:
                print(f"angle {angle_deg} deg, phase {phase}: {len(corners)} corners found, skipped")
                continue
            for held in corners:
                for c in planner.adjacent_corners(estimate, int(held)).candidates:
                    straight = float(np.linalg.norm(estimate.canonical[held] - estimate.canonical[c.plan.vertex_id]))
                    side = min(SIDES_M, key=lambda s: abs(s - straight))
                    excess.append(c.material_distance_m - straight)
                    raw_excess.append(raw_outline_length(planner, estimate, int(held), c.plan.vertex_id, c.side) - straight)
                    vs_side.append(c.material_distance_m - side)
    print(f"material distance, {len(excess)} corner pairs, spacing {spacing_m * 1000:g} mm (mm: mean, min, max)")
    for name, values in (("excess over the corner-to-corner distance", excess),
                         ("same, raw outline (path of mesh edges)", raw_excess),
                         ("difference from the cloth's true side", vs_side)):
        v = 1000 * np.asarray(values)
        print(f"  {name:<45} {v.mean():7.2f} {v.min():7.2f} {v.max():7.2f}")


def median_ms(call, runs: int) -> float:
    """Median wall time of ``call()`` over ``runs`` calls, milliseconds."""
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times))


def speed(runs: int) -> None:
    print(f"speed, median of {runs} calls, {os.cpu_count()} cores, canonical analysis cached")
    for width, height, spacing in ((0.4, 0.3, 0.02), (0.6, 0.45, 0.008)):
        mesh = rectangle_mesh(width, height, spacing)
        canonical = mesh.canonical
        estimate = MeshEstimate(vertices=canonical - [width / 2, height / 2, -1.0], faces=mesh.faces,
                                boundary=mesh.boundary, canonical=canonical, visible=np.ones(len(canonical), bool))
        planner = GraspPlanner()
        held = int(planner.corners(estimate)[0])
        adjacent = median_ms(lambda: planner.adjacent_corners(estimate, held), runs)  # noqa: B023 (called here)
        peer = median_ms(lambda: planner.plan(estimate), runs)  # noqa: B023 (called here)
        print(f"  {len(canonical):5d} vertices: adjacent_corners {adjacent:6.2f} ms, corner plan (peer) {peer:6.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spacing-m", type=float, default=0.02, help="lattice spacing of the accuracy meshes, metres")
    parser.add_argument("--runs", type=int, default=30, help="calls timed per figure")
    args = parser.parse_args()
    accuracy(args.spacing_m)
    speed(args.runs)


if __name__ == "__main__":
    main()
