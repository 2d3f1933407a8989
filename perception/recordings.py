"""Public RGB-D recordings of deforming objects: read in their own formats, written as sequence folders.

Formats (``FORMATS``), each read by one function that returns a ``Recording``:

- ``deformable_tracking``: the layout of the public repository
  catherinetaylor2/DeformableTracking (a grey foam tube bent by two hands, Kinect v1):
  ``Frames/NNNN.png`` 8-bit colour and ``depthMatrices/NNNN.yml`` OpenCV FileStorage YAML
  with one ``depth`` matrix of 16-bit unsigned millimetres (``dt: w``), registered to the
  colour image and already cut by its authors to a band around the object (zero elsewhere).
  The layout has no intrinsics file: its ``src/pointcloud.cpp`` back-projects with the
  Kinect v1 defaults fx = fy = 525, cx = 319.5, cy = 239.5 (``KINECT_V1_K``), no distortion.
- ``deepdeform``: the layout of the DeepDeform dataset (Bozic et al., CVPR 2020), as in the
  ``example_data`` of the public repository DeformableFriends/NeuralTracking: a sequence
  folder with ``color/%06d.jpg``, ``depth/%06d.png`` (uint16 millimetres, registered),
  ``intrinsics.txt`` (4x4, K in the top-left 3x3), optional ``mask/%06d_<object>.png``
  (16-bit, non-zero on the object), and ground truth for some frame pairs:
  ``scene_flow/<object>_<source>_<target>.sflow`` (3D motion, metres) and
  ``optical_flow/...oflow`` (pixels), binary: three little-endian uint32 (width, height,
  channels), then float32 values in (channels, height, width) order, non-finite = unknown.

- ``rgbd_tracking``: the ``examples/images/<sequence>`` folders of the public repository
  agpetit/RGBDTracking (a SOFA plugin; ``imagesInteraction``: a person pushes, squeezes and
  lifts a plush squirrel and a foam brain on a desk, 1000 frames of a DepthSense DS325 at
  320x240): ``img1NNNNNN.png`` colour and ``depthfileNNNNNN.txt`` depth, binary despite
  its name: three little-endian int32 (OpenCV type, 5 = float32; width; height), then float32
  metres, NaN where unknown, registered to colour. Its ``depth1``/``depth2`` PNGs are 8-bit
  pictures of the depth and are not read. The intrinsics are those its scene
  ``examples/Tracking_RGBD_FEMDef.scn`` gives for these images, fx = fy = 275, cx = 160,
  cy = 120 (``RGBD_TRACKING_K``). ``imgseg1NNNNNN.png`` is the authors' segmentation, of the
  foam brain with the hand touching it; only frame 0's, where nothing touches the brain, is
  taken as a reference mask (the brain's).

None of the layouts has timestamps: frame number n gets ``n / 30`` s (the sensors run at 30 Hz).

A source is a folder or a bare git directory (as the search tool's ``fetch`` leaves it);
a git directory is read at its HEAD with ``git cat-file``, file by file, so a snapshot
that lacks its largest files still converts as long as the frames are there.

``write_sequence(recording, OUT)`` writes the sequence folder (``perception.sequence``'s
layout, depth PNGs in the source's own units) and, beside it:

- ``reference_masks/<name>.png``: 8-bit, 255 on the object, one per frame that has one,
  named as that frame's depth image; ``reference_masks.json`` says for each whether it
  was ``annotated`` (the dataset's) or ``derived`` (see ``carry_mask``) or, for masks made
  later by ``perception.reference_masks``, how.
- ``groundtruth_flow.npz`` (if the source has scene flow): ``source`` and ``target`` (P,)
  int64 frame positions in the sequence (0-based, ``rgb.txt`` order); ``scene_flow_m``
  (P, H, W, 3) float32, metres, camera frame: where the surface point seen at each source
  pixel moves by the target frame; ``optical_flow_px`` (P, H, W, 2) float32, the same
  points' image motion (du, dv) in pixels; NaN where unknown.
- ``recording.json``: format, source, commit, frame numbers and what was assumed.

``RecordingError`` (a ValueError) carries a one-line message naming the file and problem.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame
from perception.sequence import SequenceWriter, image_as_read, open_sequence

log = logging.getLogger(__name__)

FRAME_RATE_HZ = 30.0
KINECT_V1_K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
RGBD_TRACKING_K = np.array([[275.0, 0.0, 160.0], [0.0, 275.0, 120.0], [0.0, 0.0, 1.0]])
RGBD_TRACKING_SIZE = (320, 240)
#: OpenCV's type number of a single-channel float32 matrix
CV_32F = 5
MILLIMETRES_PER_METRE = 1000.0
MASKS_DIR = "reference_masks"
MASKS_INDEX = "reference_masks.json"
FLOW_FILE = "groundtruth_flow.npz"
RECORDING_FILE = "recording.json"
DATA_ENV = "CLOTHKIT_DATA"
DEFAULT_DATA_ROOT = Path("/work/data")


def data_root() -> Path:
    """Where converted recordings live (never inside the repository): the folder named by the
    environment variable CLOTHKIT_DATA, else /work/data."""
    return Path(os.environ.get(DATA_ENV) or DEFAULT_DATA_ROOT)


class RecordingError(ValueError):
    """A source recording is missing, incomplete or malformed; the message is one line."""


# -- where the files come from ----------------------------------------------------------


class SourceTree:
    """Read-only files of a source: a folder, or a bare git directory at HEAD.

    ``files`` lists every file as a POSIX path relative to the root; ``read(path)``
    returns its bytes or raises RecordingError naming it.
    """

    def __init__(self, root: Path, files: list[str], reader: Callable[[str], bytes], commit: str | None):
        self.root = root
        self.files = sorted(files)
        self.commit = commit
        self._reader = reader

    @classmethod
    def open(cls, path) -> SourceTree:
        root = Path(path)
        if not root.exists():
            raise RecordingError(f"{root}: no such file or directory")
        if not root.is_dir():
            raise RecordingError(f"{root}: not a directory (expected a folder or a bare git directory)")
        if (root / "HEAD").is_file() and (root / "objects").is_dir():
            return cls._git(root)
        files = [p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()]
        return cls(root, files, lambda rel: cls._read_file(root, rel), None)

    @staticmethod
    def _read_file(root: Path, rel: str) -> bytes:
        try:
            return (root / rel).read_bytes()
        except OSError as exc:
            raise RecordingError(f"{root / rel}: unreadable ({exc.__class__.__name__})") from None

    @classmethod
    def _git(cls, root: Path) -> SourceTree:
        git = shutil.which("git")
        if git is None:
            raise RecordingError(f"{root}: is a git directory, and reading it needs git on PATH")

        def run(*args: str) -> bytes:
            done = subprocess.run([git, "--git-dir", str(root), *args], capture_output=True, check=False)
            if done.returncode != 0:
                reason = done.stderr.decode(errors="replace").strip().splitlines()
                raise RecordingError(f"{root}: git {args[0]} failed: {reason[-1] if reason else done.returncode}")
            return done.stdout

        commit = run("rev-parse", "HEAD").decode().strip()
        listing = run("ls-tree", "-r", "-z", "--name-only", "--full-tree", commit).decode()

        def read(rel: str) -> bytes:
            try:
                return run("cat-file", "blob", f"{commit}:{rel}")
            except RecordingError:
                raise RecordingError(f"{root}:{rel}: not readable from the git directory "
                                     "(missing from the snapshot?)") from None

        return cls(root, [f for f in listing.split("\0") if f], read, commit)

    def read(self, rel: str) -> bytes:
        return self._reader(rel)

    def where(self, rel: str) -> str:
        """How to name ``rel`` in a message."""
        return f"{self.root}:{rel}" if self.commit else str(self.root / rel)

    def under(self, folder: str) -> list[str]:
        """Files directly in ``folder`` (relative paths, sorted)."""
        prefix = folder.rstrip("/") + "/" if folder not in ("", ".") else ""
        return [f for f in self.files if f.startswith(prefix) and "/" not in f[len(prefix):]]


# -- what a reader returns ----------------------------------------------------------------


@dataclass(frozen=True)
class SourceFrame:
    """One frame of a source recording, loaded on demand.

    number : the frame's number in the source (file name); timestamp_s = number / 30
    load() : (rgb (H, W, 3) uint8 RGB, depth (H, W) uint16 in the recording's depth units)
    """

    number: int
    timestamp_s: float
    load: Callable[[], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class FlowPair:
    """Ground-truth motion from frame position ``source`` to ``target`` (0-based positions in
    ``Recording.frames``): scene_flow_m (H, W, 3) float32 metres, camera frame;
    optical_flow_px (H, W, 2) float32 pixels or None; NaN where unknown."""

    source: int
    target: int
    scene_flow_m: np.ndarray
    optical_flow_px: np.ndarray | None = None


@dataclass
class Recording:
    """A source recording, ready to write as a sequence folder.

    camera : CameraInfo of colour and depth (registered)
    depth_scale : depth units per metre of the source's 16-bit depth (1000 = millimetres)
    frames : SourceFrame list in time order
    masks : frame position -> (H, W) bool object mask annotated by the dataset
    flows : ground-truth FlowPair list
    provenance : facts for recording.json (source, commit, assumptions)
    """

    format: str
    camera: CameraInfo
    depth_scale: float
    frames: list[SourceFrame]
    masks: dict[int, np.ndarray] = field(default_factory=dict)
    flows: list[FlowPair] = field(default_factory=list)
    provenance: dict = field(default_factory=dict)


# -- decoding -----------------------------------------------------------------------------


def _decode_image(data: bytes, where: str, depth: bool) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RecordingError(f"{where}: not a readable image")
    return image_as_read(img, where, depth, error=RecordingError)


def _check_size(img: np.ndarray, camera: CameraInfo, where: str) -> np.ndarray:
    if img.shape[:2] != (camera.height, camera.width):
        raise RecordingError(f"{where}: image is {img.shape[1]}x{img.shape[0]}, expected "
                             f"{camera.width}x{camera.height}")
    return img


def read_opencv_yaml_matrix(data: bytes, key: str, where: str) -> np.ndarray:
    """The matrix ``key`` of an OpenCV FileStorage document (YAML or XML) given as bytes."""
    try:
        fs = cv2.FileStorage(data.decode("utf-8"), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (UnicodeDecodeError, cv2.error):
        raise RecordingError(f"{where}: not an OpenCV FileStorage document") from None
    try:
        node = fs.getNode(key)
        mat = None if node.empty() else node.mat()
    finally:
        fs.release()
    if mat is None:
        raise RecordingError(f"{where}: no matrix named {key!r}")
    return mat


def _header(data: bytes, dtype: str, where: str) -> tuple[int, int, int]:
    """The three 4-byte integers (``dtype``, e.g. ``"<u4"``) a binary image file starts with."""
    if len(data) < 12:
        raise RecordingError(f"{where}: too short for its 12-byte header ({len(data)} bytes)")
    a, b, c = (int(v) for v in np.frombuffer(data[:12], dtype))
    return a, b, c


def read_binary_flow(data: bytes, channels: int, camera: CameraInfo, where: str) -> np.ndarray:
    """A DeepDeform ``.sflow``/``.oflow`` image as (H, W, channels) float32, NaN where unknown."""
    width, height, got = _header(data, "<u4", where)
    if got != channels:
        raise RecordingError(f"{where}: expected {channels} channels, the header says {got}")
    if (width, height) != (camera.width, camera.height):
        raise RecordingError(f"{where}: flow is {width}x{height}, the frames are {camera.width}x{camera.height}")
    expected = 12 + 4 * width * height * channels
    if len(data) != expected:
        raise RecordingError(f"{where}: expected {expected} bytes for {width}x{height}x{channels} floats, "
                             f"got {len(data)}")
    flow = np.frombuffer(data[12:], "<f4").reshape(channels, height, width).transpose(1, 2, 0).astype(np.float32)
    return np.where(np.isfinite(flow).all(axis=2, keepdims=True), flow, np.float32(np.nan))


def _numbered(files: list[str], pattern: str, where: str) -> dict[int, str]:
    rx = re.compile(pattern)
    out: dict[int, str] = {}
    for f in files:
        m = rx.fullmatch(PurePosixPath(f).name)
        if m:
            out[int(m.group(1))] = f
    if not out:
        raise RecordingError(f"{where}: no files named like {pattern!r}")
    return out


def _pair_numbers(colour: dict[int, str], depth: dict[int, str], tree: SourceTree) -> list[int]:
    missing = sorted(set(colour) ^ set(depth))
    if missing:
        n = missing[0]
        have, lack = (colour[n], "depth") if n in colour else (depth[n], "colour")
        raise RecordingError(f"{tree.where(have)}: frame {n} has no {lack} image "
                             f"({len(missing)} frame(s) lack a partner)")
    return sorted(colour)


# -- deformable_tracking ------------------------------------------------------------------


def read_deformable_tracking(tree: SourceTree) -> Recording:
    """catherinetaylor2/DeformableTracking: ``Frames/NNNN.png`` + ``depthMatrices/NNNN.yml`` (mm),
    Kinect v1 intrinsics. Its ``SegmentedImages`` (GrabCut output that includes parts of the
    person's shirt, frames 0-50 only) are not reference masks and are not converted."""
    colour = _numbered(tree.under("Frames"), r"(\d+)\.png", tree.where("Frames/"))
    depth = _numbered(tree.under("depthMatrices"), r"(\d+)\.yml", tree.where("depthMatrices/"))
    numbers = _pair_numbers(colour, depth, tree)
    first = _decode_image(tree.read(colour[numbers[0]]), tree.where(colour[numbers[0]]), depth=False)
    camera = CameraInfo(width=first.shape[1], height=first.shape[0], K=KINECT_V1_K)
    if (camera.width, camera.height) != (640, 480):
        raise RecordingError(f"{tree.where(colour[numbers[0]])}: expected 640x480 Kinect v1 frames, "
                             f"got {camera.width}x{camera.height}")

    def loader(n: int):
        def load():
            rgb = _check_size(_decode_image(tree.read(colour[n]), tree.where(colour[n]), depth=False),
                              camera, tree.where(colour[n]))
            where = tree.where(depth[n])
            d = read_opencv_yaml_matrix(tree.read(depth[n]), "depth", where)
            if d.dtype != np.uint16 or d.ndim != 2:
                raise RecordingError(f"{where}: expected a single-channel uint16 depth matrix (dt: w), got "
                                     f"{d.dtype} with shape {d.shape}")
            return rgb, _check_size(d, camera, where)
        return load

    frames = [SourceFrame(n, n / FRAME_RATE_HZ, loader(n)) for n in numbers]
    provenance = dict(
        depth_units="millimetres (uint16 'depth' matrix, dt: w), registered to colour, zero outside "
                    "the authors' depth band around the object",
        intrinsics="Kinect v1 defaults from the source's src/pointcloud.cpp: fx=fy=525, cx=319.5, cy=239.5",
        timestamps=f"nominal: frame number / {FRAME_RATE_HZ:g} Hz (the source has none)")
    return Recording("deformable_tracking", camera, MILLIMETRES_PER_METRE, frames, provenance=provenance)


# -- deepdeform -----------------------------------------------------------------------------


def _join(folder: str, name: str) -> str:
    return name if folder in ("", ".") else f"{folder}/{name}"


def _deepdeform_folder(tree: SourceTree, sequence: str | None) -> str:
    if sequence is not None:
        folder = sequence.strip("/")
        if _join(folder, "intrinsics.txt") not in tree.files:
            raise RecordingError(f"{tree.where(folder)}: not a DeepDeform sequence (no intrinsics.txt)")
        return folder
    folders = sorted(str(PurePosixPath(f).parent) for f in tree.files if PurePosixPath(f).name == "intrinsics.txt")
    folders = [f for f in folders if tree.under(_join(f, "color")) and tree.under(_join(f, "depth"))]
    if not folders:
        raise RecordingError(f"{tree.root}: no DeepDeform sequence (a folder with intrinsics.txt, color/, depth/)")
    if len(folders) > 1:
        shown = ", ".join(folders[:4]) + (", ..." if len(folders) > 4 else "")
        raise RecordingError(f"{tree.root}: holds {len(folders)} DeepDeform sequences ({shown}); choose one "
                             "with --sequence")
    return folders[0]


def _deepdeform_intrinsics(data: bytes, where: str) -> np.ndarray:
    try:
        M = np.array([[float(v) for v in line.split()] for line in data.decode().splitlines() if line.strip()])
    except (UnicodeDecodeError, ValueError):
        raise RecordingError(f"{where}: expected a 4x4 matrix of numbers") from None
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise RecordingError(f"{where}: expected a 4x4 matrix of numbers, got shape {M.shape}")
    K = M[:3, :3]
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[0, 1] != 0 or np.any(K[2] != [0, 0, 1]):
        raise RecordingError(f"{where}: the top-left 3x3 is not a pinhole matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]")
    return K


def read_deepdeform(tree: SourceTree, sequence: str | None = None) -> Recording:
    """A DeepDeform sequence folder: colour, depth (mm), intrinsics, masks, scene and optical flow.

    sequence : the sequence folder inside ``tree`` (e.g. ``example_data/train/seq258``);
        found by itself when the tree holds exactly one
    """
    folder = _deepdeform_folder(tree, sequence)
    colour = _numbered(tree.under(_join(folder, "color")), r"(\d+)\.(?:jpg|png)", tree.where(_join(folder, "color/")))
    depth = _numbered(tree.under(_join(folder, "depth")), r"(\d+)\.png", tree.where(_join(folder, "depth/")))
    numbers = _pair_numbers(colour, depth, tree)
    K = _deepdeform_intrinsics(tree.read(_join(folder, "intrinsics.txt")), tree.where(_join(folder, "intrinsics.txt")))
    first = _decode_image(tree.read(depth[numbers[0]]), tree.where(depth[numbers[0]]), depth=True)
    camera = CameraInfo(width=first.shape[1], height=first.shape[0], K=K)
    position = {n: i for i, n in enumerate(numbers)}

    def loader(n: int):
        def load():
            rgb = _decode_image(tree.read(colour[n]), tree.where(colour[n]), depth=False)
            d = _decode_image(tree.read(depth[n]), tree.where(depth[n]), depth=True)
            return _check_size(rgb, camera, tree.where(colour[n])), _check_size(d, camera, tree.where(depth[n]))
        return load

    masks: dict[int, np.ndarray] = {}
    objects = set()
    for f in tree.under(_join(folder, "mask")):
        m = re.fullmatch(r"(\d+)_(.+)\.png", PurePosixPath(f).name)
        if not m:
            continue
        n = int(m.group(1))
        if n not in position:
            log.warning("%s: mask of frame %d, which has no colour and depth images; skipped", tree.where(f), n)
            continue
        img = _decode_mask(tree.read(f), camera, tree.where(f))
        masks[position[n]] = masks.get(position[n], np.zeros_like(img)) | img  # every object of the frame
        objects.add(m.group(2))

    flows = []
    for f in tree.under(_join(folder, "scene_flow")):
        m = re.fullmatch(r"(.+)_(\d+)_(\d+)\.sflow", PurePosixPath(f).name)
        if not m:
            continue
        src, tgt = int(m.group(2)), int(m.group(3))
        if src not in position or tgt not in position:
            log.warning("%s: flow between frames %d and %d, which are not both in the recording; skipped",
                        tree.where(f), src, tgt)
            continue
        scene = read_binary_flow(tree.read(f), 3, camera, tree.where(f))
        oflow_path = _join(folder, f"optical_flow/{PurePosixPath(f).stem}.oflow")
        optical = read_binary_flow(tree.read(oflow_path), 2, camera, tree.where(oflow_path)) \
            if oflow_path in tree.files else None
        flows.append(FlowPair(position[src], position[tgt], scene, optical))

    frames = [SourceFrame(n, n / FRAME_RATE_HZ, loader(n)) for n in numbers]
    provenance = dict(
        sequence=folder, objects=sorted(objects),
        depth_units="millimetres (uint16 PNG), registered to colour",
        intrinsics=_join(folder, "intrinsics.txt"),
        timestamps=f"nominal: frame number / {FRAME_RATE_HZ:g} Hz (the source has none)")
    return Recording("deepdeform", camera, MILLIMETRES_PER_METRE, frames, masks, flows, provenance)


# -- rgbd_tracking -------------------------------------------------------------------------


def read_float_depth(data: bytes, camera: CameraInfo, where: str) -> np.ndarray:
    """Depth of an RGBDTracking ``depthfile*.txt`` as uint16 millimetres (0: unknown)."""
    kind, w, h = _header(data, "<i4", where)
    if kind != CV_32F:
        raise RecordingError(f"{where}: expected OpenCV type {CV_32F} (float32), got {kind}")
    if (w, h) != (camera.width, camera.height):
        raise RecordingError(f"{where}: expected {camera.width}x{camera.height}, got {w}x{h}")
    if len(data) < 12 + 4 * w * h:
        raise RecordingError(f"{where}: expected {w}x{h} float32 values, got {(len(data) - 12) // 4}")
    metres = np.frombuffer(data[12:12 + 4 * w * h], "<f4").reshape(h, w)
    ok = np.isfinite(metres) & (metres > 0)
    return np.round(np.where(ok, metres, 0.0) * MILLIMETRES_PER_METRE).clip(0, 65535).astype(np.uint16)


def read_rgbd_tracking(tree: SourceTree, sequence: str | None = None) -> Recording:
    """An ``examples/images/<sequence>`` folder of agpetit/RGBDTracking (see the module docstring).

    sequence : the folder inside ``tree`` (default: ``examples/images/imagesInteraction`` when
        the tree holds it, else the tree's top level)
    """
    folder = (sequence or "").strip("/")
    if sequence is None and tree.under("examples/images/imagesInteraction"):
        folder = "examples/images/imagesInteraction"
    files = tree.under(folder)
    colour = _numbered(files, r"img1(\d+)\.png", tree.where(_join(folder, "")))
    depth = _numbered(files, r"depthfile(\d+)\.txt", tree.where(_join(folder, "")))
    numbers = _pair_numbers(colour, depth, tree)
    camera = CameraInfo(width=RGBD_TRACKING_SIZE[0], height=RGBD_TRACKING_SIZE[1], K=RGBD_TRACKING_K)

    def loader(n: int):
        def load():
            rgb = _check_size(_decode_image(tree.read(colour[n]), tree.where(colour[n]), depth=False),
                              camera, tree.where(colour[n]))
            return rgb, read_float_depth(tree.read(depth[n]), camera, tree.where(depth[n]))
        return load

    masks = {}
    first_mask = _join(folder, f"imgseg1{numbers[0]:06d}.png")
    if first_mask in tree.files:
        masks[0] = _decode_mask(tree.read(first_mask), camera, tree.where(first_mask))
    frames = [SourceFrame(n, n / FRAME_RATE_HZ, loader(n)) for n in numbers]
    provenance = dict(
        sequence=folder or ".",
        depth_units="millimetres, rounded from the source's float32 metres, registered to colour",
        intrinsics="fx=fy=275, cx=160, cy=120, from the source's examples/Tracking_RGBD_FEMDef.scn",
        annotated_mask="frame 0's imgseg (the authors' segmentation: the foam brain, nothing touching it)",
        timestamps=f"nominal: frame number / {FRAME_RATE_HZ:g} Hz (the source has none)")
    return Recording("rgbd_tracking", camera, MILLIMETRES_PER_METRE, frames, masks, provenance=provenance)


def _decode_mask(data: bytes, camera: CameraInfo, where: str) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RecordingError(f"{where}: not a readable image")
    if img.ndim == 3:
        img = img.max(axis=2)
    return _check_size(img, camera, where) > 0


FORMATS: dict[str, Callable[..., Recording]] = {
    "deformable_tracking": read_deformable_tracking,
    "deepdeform": read_deepdeform,
    "rgbd_tracking": read_rgbd_tracking,
}


def read_recording(fmt: str, source, **options) -> Recording:
    """Read ``source`` (a folder or bare git directory) in format ``fmt`` (a key of FORMATS)."""
    if fmt not in FORMATS:
        raise RecordingError(f"unknown recording format {fmt!r}; known: {', '.join(sorted(FORMATS))}")
    tree = source if isinstance(source, SourceTree) else SourceTree.open(source)
    recording = FORMATS[fmt](tree, **options)
    recording.provenance = dict(source=str(tree.root), commit=tree.commit, **recording.provenance)
    return recording


# -- derived masks --------------------------------------------------------------------------


def carry_mask(mask: np.ndarray, optical_flow_px: np.ndarray, close_px: int = 7) -> np.ndarray:
    """The object mask of a flow pair's target frame, from the source frame's mask.

    mask : (H, W) bool in the source frame; optical_flow_px : (H, W, 2) float32 (du, dv),
    NaN where unknown. Every masked source pixel with known flow lands at its rounded target
    pixel; a closing of ``close_px`` fills the gaps between them where the cloth stretched.
    Parts of the object that only the target frame shows are missing. Returns (H, W) bool.
    """
    h, w = mask.shape
    known = mask & np.isfinite(optical_flow_px).all(axis=2)
    rows, cols = np.nonzero(known)
    u = np.rint(cols + optical_flow_px[rows, cols, 0]).astype(np.int64)
    v = np.rint(rows + optical_flow_px[rows, cols, 1]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros((h, w), np.uint8)
    out[v[inside], u[inside]] = 1
    kernel = np.ones((close_px, close_px), np.uint8)  # square: a disc leaves gaps open along straight edges
    return cv2.morphologyEx(out, cv2.MORPH_CLOSE, kernel).astype(bool)


# -- writing ----------------------------------------------------------------------------------


def write_sequence(recording: Recording, out, max_frames: int | None = None, progress=None) -> Path:
    """Write ``recording`` as a sequence folder ``out`` with its reference masks, ground-truth
    flow and recording.json (see the module docstring). Returns ``out``.

    max_frames : convert only the first frames (flows and masks beyond are dropped, with a log line)
    progress : optional callable wrapping the frame iterable (e.g. tqdm)
    """
    out = Path(out)
    if (out / "rgb.txt").exists():
        raise RecordingError(f"{out}: already holds a sequence (rgb.txt exists); choose a new folder")
    frames = recording.frames if max_frames is None else recording.frames[:max_frames]
    if not frames:
        raise RecordingError("the recording has no frames")
    scale = np.float32(recording.depth_scale)
    writer = SequenceWriter(out, recording.camera, depth_scale=recording.depth_scale)
    iterable = progress(frames) if progress is not None else frames
    for position, src in enumerate(iterable):
        rgb, depth = src.load()
        depth_m = depth.astype(np.float32) / scale
        writer.write(RGBDFrame(rgb=rgb, depth_m=depth_m, camera=recording.camera, timestamp_s=src.timestamp_s,
                               seq=position))
    writer.close()
    seq = open_sequence(out)
    n = len(frames)
    flows = [p for p in recording.flows if p.source < n and p.target < n]
    masks = {i: m for i, m in recording.masks.items() if i < n}
    if len(flows) < len(recording.flows) or len(masks) < len(recording.masks):
        log.info("%s: %d flow pair(s) and %d mask(s) beyond frame %d not written", out,
                 len(recording.flows) - len(flows), len(recording.masks) - len(masks), n)
    kinds = {i: "annotated" for i in masks}
    for pair in flows:
        if pair.target not in masks and pair.source in masks and pair.optical_flow_px is not None:
            masks[pair.target] = carry_mask(masks[pair.source], pair.optical_flow_px)
            kinds[pair.target] = (f"derived: the annotated mask of frame {pair.source} carried by the "
                                  "ground-truth optical flow")
    if masks:
        write_reference_masks(seq, masks, kinds)
    if flows:
        write_groundtruth_flow(out, flows, recording.camera)
    info = dict(format=recording.format, frames=n, frame_numbers=[f.number for f in frames],
                camera=dict(width=recording.camera.width, height=recording.camera.height,
                            K=recording.camera.K.tolist()),
                depth_scale=recording.depth_scale, flow_pairs=len(flows), reference_masks=len(masks),
                **recording.provenance)
    (out / RECORDING_FILE).write_text(json.dumps(info, indent=2) + "\n", encoding="utf-8")
    log.info("%s: %d frames, %d reference masks, %d flow pairs", out, n, len(masks), len(flows))
    return out


def write_reference_masks(seq, masks: dict[int, np.ndarray], kinds: dict[int, str]) -> None:
    """Write ``masks`` (frame position -> (H, W) bool) as ``reference_masks/<depth name>.png``
    (255 on the object) and merge ``kinds`` (position -> how it was made) into the index."""
    folder = Path(seq.path) / MASKS_DIR
    folder.mkdir(exist_ok=True)
    index_path = Path(seq.path) / MASKS_INDEX
    index = json.loads(index_path.read_text(encoding="utf-8")) if index_path.is_file() else {}
    for i, mask in sorted(masks.items()):
        name = Path(seq.depth_files[i]).name
        if mask.shape != (seq.camera.height, seq.camera.width):
            raise ValueError(f"reference mask of frame {i}: shape {mask.shape} differs from the frames'")
        if not cv2.imwrite(str(folder / name), mask.astype(np.uint8) * 255):
            raise OSError(f"{folder / name}: could not write")
        index[name] = kinds[i]
    index_path.write_text(json.dumps(dict(sorted(index.items())), indent=2) + "\n", encoding="utf-8")


def read_reference_masks(seq) -> dict[int, np.ndarray]:
    """Frame position -> (H, W) bool reference mask, for the frames of ``seq`` (a
    ``perception.sequence.Sequence``) that have ``reference_masks/<depth name>.png``."""
    folder = Path(seq.path) / MASKS_DIR
    out = {}
    if not folder.is_dir():
        return out
    for i, depth_file in enumerate(seq.depth_files):
        path = folder / Path(depth_file).name
        if path.is_file():
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if img is None or img.shape != (seq.camera.height, seq.camera.width):
                raise RecordingError(f"{path}: unreadable or not {seq.camera.width}x{seq.camera.height}")
            out[i] = img > 0
    return out


def write_groundtruth_flow(out, flows: list[FlowPair], camera: CameraInfo) -> None:
    """``groundtruth_flow.npz`` in ``out`` (keys in the module docstring)."""
    h, w = camera.height, camera.width
    optical = [p.optical_flow_px if p.optical_flow_px is not None else np.full((h, w, 2), np.nan, np.float32)
               for p in flows]
    np.savez_compressed(Path(out) / FLOW_FILE,
                        source=np.array([p.source for p in flows], np.int64),
                        target=np.array([p.target for p in flows], np.int64),
                        scene_flow_m=np.stack([p.scene_flow_m for p in flows]).astype(np.float32),
                        optical_flow_px=np.stack(optical).astype(np.float32))


def read_groundtruth_flow(seq) -> list[FlowPair]:
    """The FlowPair list of ``groundtruth_flow.npz`` in a sequence folder (empty without one)."""
    path = Path(seq.path) / FLOW_FILE
    if not path.is_file():
        return []
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as exc:
        raise RecordingError(f"{path}: unreadable ({exc.__class__.__name__})") from None
    for key in ("source", "target", "scene_flow_m", "optical_flow_px"):
        if key not in data:
            raise RecordingError(f"{path}: missing key {key!r}")
    n, h, w = len(seq), seq.camera.height, seq.camera.width
    P = len(data["source"])
    if data["scene_flow_m"].shape != (P, h, w, 3) or data["optical_flow_px"].shape != (P, h, w, 2):
        raise RecordingError(f"{path}: flow arrays must be ({P}, {h}, {w}, 3) and ({P}, {h}, {w}, 2), got "
                             f"{data['scene_flow_m'].shape} and {data['optical_flow_px'].shape}")
    pairs = np.stack([data["source"], data["target"]], axis=1) if P else np.zeros((0, 2), int)
    if pairs.size and (pairs.min() < 0 or pairs.max() >= n):
        raise RecordingError(f"{path}: frame positions outside [0, {n})")
    return [FlowPair(int(s), int(t), data["scene_flow_m"][k], data["optical_flow_px"][k])
            for k, (s, t) in enumerate(pairs)]
