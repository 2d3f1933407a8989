"""Measure the simulation: stretch while hanging, render time, recording time.

    python -m sim.benchmark [--scene poster_bend] [--frames 60] [--renders 30]

Prints one line per figure, with the machine's core count (DESIGN.md "Measuring":
medians, never timed assertions in tests).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

from perception.sequence import SequenceWriter
from sim.cloth_mesh import edge_strain, rectangle_mesh, tshirt_mesh
from sim.physics import ClothMaterial, ClothPhysics
from sim.scenes import SCENES, make_scene


def hanging_strain(kind: str, seconds: float = 1.0) -> np.ndarray:
    """(E,) edge strain of a cloth hung by two grippers for ``seconds``: a 0.6 x 0.45 m
    poster by its top corners, or a T-shirt by its shoulders, default material."""
    if kind == "poster":
        mesh, held = rectangle_mesh(0.6, 0.45, spacing_m=0.025), ("top_left", "top_right")
    else:
        mesh, held = tshirt_mesh(spacing_m=0.03), ("left_shoulder", "right_shoulder")
    with ClothPhysics() as physics:
        verts = mesh.layout_points([-0.3, 0.0, 1.5], right=[1, 0, 0], down=[0, 0, -1])
        physics.add_cloth(mesh, verts, ClothMaterial())
        for name in held:
            at = verts[mesh.landmarks[name]]
            physics.add_gripper(at).close_on(physics.nodes_near(at, 0.03))
        physics.advance(seconds)
        return edge_strain(physics.cloth_vertices(), mesh.edges(), mesh.rest_lengths())


def _median_ms(fn, n: int) -> float:
    times = []
    for _ in range(n):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.benchmark", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=sorted(SCENES), default="poster_bend")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--renders", type=int, default=30)
    args = parser.parse_args(argv)
    out = sys.stdout
    out.write(f"cores: {os.cpu_count()}\n")

    for kind in ("poster", "tshirt"):
        s = hanging_strain(kind)
        out.write(f"hanging {kind} (1 s, two grippers): edge strain mean {100 * s.mean():.2f} %, "
                  f"p95 {100 * np.percentile(s, 95):.2f} %, max {100 * s.max():.1f} %\n")

    with make_scene(args.scene, seed=0, noise=False) as scene:
        for _ in range(10):
            scene.step()
        camera = scene.virtual_camera
        texture = scene.spec.texture_rgb
        rigid = _median_ms(lambda: camera.render_rigid(scene.physics), 5)
        exact = _median_ms(lambda: camera.render(scene.physics, texture), args.renders)
        scene.noise = True
        noisy = _median_ms(scene.render, args.renders)
        step = _median_ms(scene.step, 10)
    out.write(f"render {args.scene} 640x480: {exact:.1f} ms exact, {noisy:.1f} ms with sensor noise "
              f"(median of {args.renders}); PyBullet redrawing the rigid scene alone: {rigid:.1f} ms\n")
    out.write(f"physics {args.scene}: {step:.1f} ms per 1/30 s frame (8 steps)\n")

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp, make_scene(args.scene, seed=0, noise=True) as scene, \
            SequenceWriter(os.path.join(tmp, "seq"), scene.camera) as writer:
        vertices = []
        for frame in scene.frames(args.frames):
            writer.write(frame)
            vertices.append(scene.cloth_vertices_cam().astype(np.float32))
        writer.close(groundtruth={"vertices": np.stack(vertices), "faces": scene.faces, "uv": scene.uv_m})
    out.write(f"record {args.scene} {args.frames} frames 640x480 with noise: {time.perf_counter() - start:.1f} s\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
