"""The sim recorder: a scene written as a recorded sequence folder, with its ground truth.

The folder is the toolkit's recorded-sequence layout (``perception.sequence``: rgb.txt,
depth.txt, rgb/, depth/, camera_intrinsic.json) plus ``groundtruth_mesh.npz``: the
cloth's vertices in the camera frame at every written frame, (T, V, 3) float32 metres, its
faces (F, 3) and its material coordinates ``uv`` (V, 2), metres on the flat cloth (u right,
v down from the top-left of its bounding box). A scene with occluders also gets
``occluder_masks/``: one 8-bit PNG per frame, named as the frame's depth image, 255 where
the drawn occluder is seen and 0 elsewhere (the input of the offline command's
``--occluder-masks``). Command line: ``python -m launch_scripts.record_scene``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from perception.sequence import SequenceWriter, read_file_list
from sim.scene import Scene

log = logging.getLogger(__name__)

#: The folder of a sequence that holds the occluder masks.
OCCLUDER_MASKS = "occluder_masks"


def record_sequence(scene: Scene, out_dir: Path, n_frames: int, frame_step: int = 1, progress: bool = False) -> int:
    """Run ``scene`` from its current frame for ``n_frames`` simulated frames and write every
    ``frame_step``-th of them (from the first) to ``out_dir`` with its ground truth.

    Frames keep their true timestamps (index / fps). Every frame is rendered, kept or not,
    so that the kept frames equal those of a full-rate recording (the noise stream
    advances with each rendering). A scene with ``has_occluders`` true also gets its
    occluder masks (all 0 in a twin, which draws none). Returns the frames written.
    """
    vertices, occluder_masks = [], []
    with_occluders = bool(getattr(scene, "has_occluders", False))
    with SequenceWriter(out_dir, scene.camera) as writer:
        for k in tqdm(range(n_frames), desc=scene.name, unit="frame", disable=not progress):
            if k:
                scene.step()
            frame = scene.render()
            if k % frame_step:
                continue
            writer.write(frame)
            vertices.append(scene.cloth_vertices_cam().astype(np.float32))
            if with_occluders:
                occluder_masks.append(scene.occluder_mask())
        writer.close(groundtruth={"vertices": np.stack(vertices), "faces": scene.faces, "uv": scene.uv_m})
    if occluder_masks:
        write_occluder_masks(Path(out_dir), occluder_masks)
    return len(vertices)


def write_occluder_masks(seq_dir: Path, masks: list) -> None:
    """Write ``masks`` ((H, W) bool, one per frame in depth.txt's order) as 8-bit PNGs (255 on the
    occluder) into SEQ/occluder_masks/, each named as its frame's depth image."""
    _, depth_files = read_file_list(seq_dir / "depth.txt")
    if len(depth_files) != len(masks):
        raise ValueError(f"write_occluder_masks: {len(masks)} masks for {len(depth_files)} frames in {seq_dir}")
    folder = seq_dir / OCCLUDER_MASKS
    folder.mkdir(exist_ok=True)
    for rel, mask in zip(depth_files, masks, strict=True):
        path = folder / Path(rel).name
        if not cv2.imwrite(str(path), np.where(mask, 255, 0).astype(np.uint8)):
            raise OSError(f"{path}: could not write the occluder mask")
