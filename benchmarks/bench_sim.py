"""Measure the simulation: stretch while hanging, render time, recording time.

    python benchmarks/bench_sim.py [--scene poster_bend] [--frames 60] [--renders 30]

It also times a moving occluder (``occluder_sweep``) drawn as the scenes draw it, with
``sim.raster``, against the same occluder mesh as a PyBullet visual body, which makes the
TinyRenderer redraw the whole room in every frame, in the same run.

Prints one line per figure, with the machine's core count (medians; speed is measured
here, never asserted in tests).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from perception.sequence import SequenceWriter  # noqa: E402
from sim.cloth_mesh import edge_strain, rectangle_cloth, tshirt_cloth  # noqa: E402
from sim.physics import ClothMaterial, ClothPhysics  # noqa: E402
from sim.scenes import PAPER_SCENES, make_scene  # noqa: E402


def hanging_strain(kind: str, seconds: float = 1.0) -> np.ndarray:
    """(E,) edge strain of a cloth hung by two grippers for ``seconds``: a 0.6 x 0.45 m
    poster by its top corners, or a T-shirt by its shoulders, default material."""
    if kind == "poster":
        mesh, held = rectangle_cloth(0.6, 0.45, spacing_m=0.025), ("top_left", "top_right")
    else:
        mesh, held = tshirt_cloth(spacing_m=0.03), ("left_shoulder", "right_shoulder")
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


def moving_occluder_render_ms(renders: int, seed: int = 0) -> tuple[float, float, float]:
    """Median exact render time (ms) of ``occluder_sweep`` frames while its occluder sweeps:
    (drawn with sim.raster, the same frame without it, the same mesh as a PyBullet body moved
    each frame). Only rendering is timed, not physics; at most one render per frame of the script."""
    with make_scene("occluder_sweep", seed=seed, noise=False) as drawn, \
            make_scene("occluder_sweep", seed=seed, noise=False, occluders=False) as pybullet_drawn:
        spec = drawn.spec
        first = spec.occluders(0.0)
        p = pybullet_drawn.physics.pybullet
        client = pybullet_drawn.physics.client
        shape = p.createVisualShape(p.GEOM_MESH, vertices=first.points.tolist(), indices=first.faces.ravel().tolist(),
                                    rgbaColor=[*(first.colours[0] / 255.0), 1.0], physicsClientId=client)
        body = p.createMultiBody(0.0, -1, shape, [0.0, 0.0, 0.0], physicsClientId=client)
        times = {"raster": [], "none": [], "pybullet": []}
        for _ in range(min(renders, drawn.n_frames)):
            drawn.step()
            pybullet_drawn.step()
            shift = spec.occluders(drawn.time_s).points[0] - first.points[0]
            p.resetBasePositionAndOrientation(body, shift.tolist(), [0.0, 0.0, 0.0, 1.0], physicsClientId=client)
            for key, render in (("raster", drawn.render), ("pybullet", pybullet_drawn.render)):
                start = time.perf_counter()
                render()
                times[key].append(time.perf_counter() - start)
            drawn.draw_occluders = False
            start = time.perf_counter()
            drawn.render()
            times["none"].append(time.perf_counter() - start)
            drawn.draw_occluders = True
    return tuple(1000.0 * float(np.median(times[key])) for key in ("raster", "none", "pybullet"))


def handled_render_ms(name: str, renders: int, seed: int = 0) -> tuple[float, float]:
    """Median exact render time (ms) of a handled scene's frames, (with its occluders drawn, the
    same frame without them), over at most one render per frame of its script."""
    times = {True: [], False: []}
    with make_scene(name, seed=seed, noise=False) as scene:
        for _ in range(min(renders, scene.n_frames)):
            scene.step()
            for drawn in (True, False):
                scene.draw_occluders = drawn
                start = time.perf_counter()
                scene.render()
                times[drawn].append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times[True])), 1000.0 * float(np.median(times[False]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python benchmarks/bench_sim.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=PAPER_SCENES, default="poster_bend")
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

    raster, none, redraw = moving_occluder_render_ms(args.renders)
    out.write(f"render occluder_sweep 640x480 while the occluder moves (median of {args.renders}): {raster:.1f} ms "
              f"with it drawn by sim.raster, {none:.1f} ms without it, {redraw:.1f} ms with the same mesh as a "
              "PyBullet body (the room redrawn every frame)\n")
    for name in ("gripper_corner_move", "table_lift"):
        drawn, clear = handled_render_ms(name, args.renders)
        out.write(f"render {name} 640x480 (median of {args.renders}): {drawn:.1f} ms with the gripper and arm drawn, "
                  f"{clear:.1f} ms without\n")

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
