"""Recorded RGB-D sequences on disk: the only module that knows the folder format.

Layout (the recorded sequence folder; the offline command and the sim recorder use it)::

    SEQ/
      rgb.txt, depth.txt        TUM RGB-D lists: "timestamp relative/path" a line, '#' comments
      rgb/*.png, depth/*.png    8-bit colour; uint16 depth, metres = value / depth_scale, 0 = missing
      camera_intrinsic.json     Open3D PinholeCameraIntrinsic: {"width", "height",
                                "intrinsic_matrix": 9 numbers, column-major}, optional
                                "depth_scale" (default 5000, TUM's, with a warning:
                                millimetres need 1000)
      groundtruth_mesh.npz      simulation only: vertices (T, V, 3) float32 camera frame,
                                faces (F, 3) int, uv (V, 2) material coordinates

Colour and depth images are paired by nearest timestamp, as TUM's ``associate.py``:
candidate pairs closer than 0.02 s are taken greedily, closest first, each image used
once, then ordered by colour timestamp.

Reading: ``open_sequence(path)`` checks the lists, the intrinsics, the first pair of
images and the ground truth, and raises ``SequenceError`` (a ValueError) with a
one-line message naming the file and the problem; later frames are checked as they
are read. It warns of what it cannot check: a depth scale taken by default, and frames
so far apart that their timestamps are unlikely to be seconds. Writing: ``SequenceWriter``.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ipc.messages import CameraInfo, RGBDFrame

log = logging.getLogger(__name__)

DEFAULT_DEPTH_SCALE = 5000.0
MAX_TIME_DIFFERENCE_S = 0.02
INTRINSICS_FILE = "camera_intrinsic.json"
GROUNDTRUTH_FILE = "groundtruth_mesh.npz"


class SequenceError(ValueError):
    """A recorded sequence is missing, incomplete or malformed; the message is one line."""


def _number(value, what: str, where: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SequenceError(f"{where}: {what} must be a finite number, got {value!r}")
    return float(value)


def read_intrinsics(path) -> tuple[CameraInfo, float | None]:
    """Read an Open3D ``camera_intrinsic.json``.

    path : the JSON file
    returns (CameraInfo with K row-major, depth_scale in depth PNG units per metre, or None
    when the file gives none)
    raises SequenceError naming the file
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceError(f"{path}: file not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{path}: unreadable ({exc.__class__.__name__})") from None
    except json.JSONDecodeError as exc:
        raise SequenceError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise SequenceError(f"{path}: expected a JSON object, got {type(data).__name__}")
    for key in ("width", "height", "intrinsic_matrix"):
        if key not in data:
            raise SequenceError(f"{path}: missing key {key!r}")
    width, height = data["width"], data["height"]
    if isinstance(width, bool) or isinstance(height, bool) or not isinstance(width, int) or not isinstance(height, int) \
            or width <= 0 or height <= 0:
        raise SequenceError(f"{path}: width and height must be positive integers, got {width!r} and {height!r}")
    matrix = data["intrinsic_matrix"]
    if not isinstance(matrix, list) or len(matrix) != 9:
        got = len(matrix) if isinstance(matrix, list) else type(matrix).__name__
        raise SequenceError(f"{path}: intrinsic_matrix must be a list of 9 numbers, got {got}")
    values = [_number(v, "every intrinsic_matrix entry", path) for v in matrix]
    K = np.array(values, dtype=np.float64).reshape(3, 3).T  # stored column-major
    if np.any(K[2, :2] != 0) or K[2, 2] != 1:
        hint = " (it looks row-major: cx, cy belong in entries 7 and 8)" if K[0, 2] == 0 and K[1, 2] == 0 else ""
        raise SequenceError(f"{path}: intrinsic_matrix is not a column-major pinhole matrix "
                            f"[fx, 0, 0, 0, fy, 0, cx, cy, 1]{hint}")
    depth_scale = None
    if "depth_scale" in data:
        depth_scale = _number(data["depth_scale"], "depth_scale", path)
        if depth_scale <= 0:
            raise SequenceError(f"{path}: depth_scale must be positive, got {depth_scale}")
    try:
        camera = CameraInfo(width=width, height=height, K=K)
    except ValueError as exc:
        raise SequenceError(f"{path}: {exc}") from None
    return camera, depth_scale


def write_intrinsics(path, camera: CameraInfo, depth_scale: float = DEFAULT_DEPTH_SCALE) -> None:
    """Write ``camera`` and ``depth_scale`` as Open3D ``camera_intrinsic.json`` (K column-major).

    The layout has no place for distortion, so a camera with non-zero ``D`` is refused.
    """
    if camera.D.size and np.any(camera.D != 0):
        raise ValueError(f"write_intrinsics: {INTRINSICS_FILE} cannot hold distortion, got D={camera.D.tolist()}; "
                         "undistort the images first")
    data = {
        "width": camera.width,
        "height": camera.height,
        "intrinsic_matrix": [float(v) for v in camera.K.T.ravel()],
        "depth_scale": float(depth_scale),
    }
    Path(path).write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def read_file_list(path) -> tuple[np.ndarray, list[str]]:
    """Read a TUM list (``rgb.txt``/``depth.txt``): "timestamp relative/path" per line.

    returns (timestamps (N,) float64 seconds, relative paths), in file order
    raises SequenceError naming the file and line
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceError(f"{path}: file not found")
    stamps: list[float] = []
    files: list[str] = []
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SequenceError(f"{path}: unreadable ({exc.__class__.__name__})") from None
    for lineno, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.replace(",", " ").split()
        if len(parts) != 2:
            raise SequenceError(f"{path}:{lineno}: expected 'timestamp path', got {text!r}")
        try:
            stamp = float(parts[0])
        except ValueError:
            raise SequenceError(f"{path}:{lineno}: timestamp {parts[0]!r} is not a number") from None
        if not math.isfinite(stamp):
            raise SequenceError(f"{path}:{lineno}: timestamp {parts[0]!r} is not finite")
        stamps.append(stamp)
        files.append(parts[1])
    if not stamps:
        raise SequenceError(f"{path}: lists no images")
    arr = np.array(stamps)
    unique, counts = np.unique(arr, return_counts=True)
    if np.any(counts > 1):
        raise SequenceError(f"{path}: timestamp {unique[counts > 1][0]:.6f} is listed more than once")
    return arr, files


def associate(first_s: np.ndarray, second_s: np.ndarray, max_difference_s: float = MAX_TIME_DIFFERENCE_S) -> np.ndarray:
    """Pair timestamps as TUM's ``associate.py``.

    first_s : (N,) float seconds; second_s : (M,) float seconds
    returns (P, 2) int64 index pairs (into first_s, second_s), sorted by first timestamp;
    candidates differ by less than ``max_difference_s`` and are taken closest first,
    each timestamp at most once
    """
    a = np.asarray(first_s, dtype=np.float64).ravel()
    b = np.asarray(second_s, dtype=np.float64).ravel()
    order_b = np.argsort(b, kind="stable")
    sorted_b = b[order_b]
    lo = np.searchsorted(sorted_b, a - max_difference_s, side="left")
    hi = np.searchsorted(sorted_b, a + max_difference_s, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(len(a)), counts)
    ib = order_b[np.repeat(lo, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)]
    diff = np.abs(a[ia] - b[ib])
    keep = diff < max_difference_s
    ia, ib, diff = ia[keep], ib[keep], diff[keep]
    used_a = np.zeros(len(a), bool)
    used_b = np.zeros(len(b), bool)
    pairs = []
    # closest first; ties broken by the timestamps themselves, as sorting (diff, a, b) tuples does
    for k in np.lexsort((b[ib], a[ia], diff)):
        i, j = ia[k], ib[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    out = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return out[np.argsort(a[out[:, 0]], kind="stable")]


def _read_image(path: Path, depth: bool, camera: CameraInfo) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        if not path.is_file():
            raise SequenceError(f"{path}: file not found")
        raise SequenceError(f"{path}: unreadable image")
    if img.shape[0] != camera.height or img.shape[1] != camera.width:
        raise SequenceError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, but {INTRINSICS_FILE} says "
                            f"{camera.width}x{camera.height}")
    return image_as_read(img, path, depth)


def image_as_read(img: np.ndarray, where, depth: bool, error: type[Exception] = SequenceError) -> np.ndarray:
    """An image decoded by OpenCV (``cv2.IMREAD_UNCHANGED``) as the sequence holds it: depth
    (H, W) uint16 as it is; colour (H, W, 3) uint8 RGB (grey repeated, BGR(A) converted).
    raises ``error`` naming ``where`` for any other kind of image"""
    if depth:
        if img.ndim != 2 or img.dtype != np.uint16:
            channels = 1 if img.ndim == 2 else img.shape[2]
            raise error(f"{where}: expected a 16-bit single-channel depth image, got {img.dtype} with "
                        f"{channels} channel(s)")
        return img
    if img.dtype != np.uint8:
        raise error(f"{where}: expected an 8-bit colour image, got {img.dtype}")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _read_mask(path: Path, camera: CameraInfo) -> np.ndarray:
    """(H, W) bool from an 8-bit PNG (any channel non-zero), checked against the camera's size."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SequenceError(f"{path}: not a readable image")
    if img.ndim == 3:
        img = img.max(axis=2)
    if img.shape != (camera.height, camera.width):
        raise SequenceError(f"{path}: size {img.shape[1]}x{img.shape[0]} differs from the camera's "
                            f"{camera.width}x{camera.height}")
    return img > 0


def _read_groundtruth(path: Path, n_frames: int) -> dict:
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as exc:
        raise SequenceError(f"{path}: unreadable ({exc.__class__.__name__})") from None
    for key in ("vertices", "faces", "uv"):
        if key not in data:
            raise SequenceError(f"{path}: missing key {key!r}")
    v, f, uv = data["vertices"], data["faces"], data["uv"]
    if v.ndim != 3 or v.shape[2] != 3 or v.dtype.kind != "f":
        raise SequenceError(f"{path}: vertices must be a float (T, V, 3) array, got {v.dtype} {v.shape}")
    if v.shape[0] != n_frames:
        raise SequenceError(f"{path}: vertices has {v.shape[0]} frames, the sequence has {n_frames}")
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
        raise SequenceError(f"{path}: faces must be an integer (F, 3) array, got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= v.shape[1]):
        raise SequenceError(f"{path}: faces refer to vertices outside [0, {v.shape[1]})")
    if uv.shape != (v.shape[1], 2):
        raise SequenceError(f"{path}: uv must have shape ({v.shape[1]}, 2), got {uv.shape}")
    return data


@dataclass(frozen=True)
class Sequence:
    """An opened sequence folder (use ``open_sequence``).

    path : the folder
    camera : CameraInfo of colour and depth (registered)
    depth_scale : depth PNG units per metre
    timestamps : (N,) float64 seconds, colour timestamp of each paired frame
    rgb_files, depth_files : N paths each
    groundtruth : None, or a dict of arrays from groundtruth_mesh.npz: ``vertices``
        (N, V, 3) float32 metres camera frame, ``faces`` (F, 3) int, ``uv`` (V, 2)
    """

    path: Path
    camera: CameraInfo
    depth_scale: float
    timestamps: np.ndarray
    rgb_files: tuple
    depth_files: tuple
    groundtruth: dict | None = None

    def __len__(self) -> int:
        return len(self.timestamps)

    def __iter__(self):
        for i in range(len(self)):
            yield self.frame(i)

    def frame(self, i: int, occluder_dir: Path | None = None) -> RGBDFrame:
        """Frame ``i`` (0 <= i < len) as an RGBDFrame: rgb (H, W, 3) uint8 RGB, depth_m (H, W)
        float32 metres (0 = missing), timestamp_s of the colour image, seq = i.

        occluder_dir : a folder of known-occluder masks, one 8-bit PNG per frame named as the
            frame's depth image, non-zero on the occluder; the frame's ``occluder_mask`` (None
            for a frame whose PNG is absent: no occluder known)"""
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < len(self):
            raise IndexError(f"frame index {i!r} out of range for a sequence of {len(self)} frames")
        rgb = _read_image(self.rgb_files[i], depth=False, camera=self.camera)
        raw = _read_image(self.depth_files[i], depth=True, camera=self.camera)
        depth_m = raw.astype(np.float32) / np.float32(self.depth_scale)
        occluder = None
        if occluder_dir is not None:
            path = Path(occluder_dir) / self.depth_files[i].name
            occluder = _read_mask(path, self.camera) if path.exists() else None
        return RGBDFrame(rgb=rgb, depth_m=depth_m, camera=self.camera, timestamp_s=float(self.timestamps[i]), seq=int(i),
                         occluder_mask=occluder)


def _listed_paths(root: Path, list_file: Path, relative: list[str]) -> list[Path]:
    out = []
    for rel in relative:
        p = root / rel
        if not p.is_file():
            raise SequenceError(f"{list_file}: listed image {rel} does not exist")
        out.append(p)
    return out


#: Median spacing of a sequence's frames, seconds, beyond which its timestamps are likely not
#: seconds (milliseconds since the epoch are a common mistake: 33 ms frames would play 33 s
#: apart when paced by their timestamps).
MAX_LIKELY_SPACING_S = 5.0


def _warn_default_depth_scale(intrinsics: Path, raw_depth: np.ndarray) -> None:
    """Say that ``intrinsics`` gives no depth_scale and TUM's is taken, with the median depth
    of the first frame ``raw_depth`` (uint16) that gives, and with millimetres: a recording in
    millimetres read at TUM's 5000 units per metre lies five times too near."""
    measured = raw_depth[raw_depth > 0]
    median = float(np.median(measured)) if measured.size else float("nan")
    log.warning("%s has no depth_scale: taking TUM's %g units per metre (the first frame's median depth is "
                "then %.2f m; %.2f m in millimetres, which need \"depth_scale\": 1000)", intrinsics,
                DEFAULT_DEPTH_SCALE, median / DEFAULT_DEPTH_SCALE, median / 1000.0)


def _warn_unlikely_spacing(list_file: Path, timestamps: np.ndarray) -> None:
    """Say so when the frames of ``list_file`` lie more than ``MAX_LIKELY_SPACING_S`` apart (median)."""
    if len(timestamps) < 2:
        return
    spacing = float(np.median(np.diff(timestamps)))
    if spacing > MAX_LIKELY_SPACING_S:
        log.warning("%s: frames %.3g s apart (median): paced by their timestamps, they play that far apart "
                    "(TUM timestamps are seconds; milliseconds would want dividing by 1000)", list_file, spacing)


def open_sequence(path) -> Sequence:
    """Open and check a recorded sequence folder.

    path : the folder (str or Path)
    returns Sequence
    raises SequenceError (a ValueError) with a one-line message naming the file and problem
    """
    root = Path(path)
    if not root.is_dir():
        raise SequenceError(f"{root}: not a directory" if root.exists() else f"{root}: no such directory")
    rgb_stamps, rgb_rel = read_file_list(root / "rgb.txt")
    depth_stamps, depth_rel = read_file_list(root / "depth.txt")
    camera, depth_scale = read_intrinsics(root / INTRINSICS_FILE)
    pairs = associate(rgb_stamps, depth_stamps)
    if len(pairs) == 0:
        raise SequenceError(f"{root}: no rgb/depth pairs within {MAX_TIME_DIFFERENCE_S} s "
                            f"({len(rgb_stamps)} rgb, {len(depth_stamps)} depth images)")
    rgb_files = _listed_paths(root, root / "rgb.txt", [rgb_rel[i] for i in pairs[:, 0]])
    depth_files = _listed_paths(root, root / "depth.txt", [depth_rel[j] for j in pairs[:, 1]])
    if len(pairs) < min(len(rgb_stamps), len(depth_stamps)):
        log.warning("%s: %d rgb and %d depth images, %d pairs within %.2f s", root, len(rgb_stamps),
                    len(depth_stamps), len(pairs), MAX_TIME_DIFFERENCE_S)
    # check the first pair now, so a wrong size or format fails at open, not mid-run
    _read_image(rgb_files[0], depth=False, camera=camera)
    first_depth = _read_image(depth_files[0], depth=True, camera=camera)
    if depth_scale is None:
        depth_scale = DEFAULT_DEPTH_SCALE
        _warn_default_depth_scale(root / INTRINSICS_FILE, first_depth)
    timestamps = rgb_stamps[pairs[:, 0]]
    _warn_unlikely_spacing(root / "rgb.txt", timestamps)
    gt_path = root / GROUNDTRUTH_FILE
    groundtruth = _read_groundtruth(gt_path, len(pairs)) if gt_path.exists() else None
    return Sequence(path=root, camera=camera, depth_scale=depth_scale, timestamps=timestamps,
                    rgb_files=tuple(rgb_files), depth_files=tuple(depth_files), groundtruth=groundtruth)


class SequenceWriter:
    """Write frames into a sequence folder that ``open_sequence`` reads back.

    path : folder to create (may exist, but must not already hold rgb.txt)
    camera : CameraInfo every written frame must have
    depth_scale : depth PNG units per metre (5000: 0.2 mm steps up to 13.1 m)

    ``write(frame)`` stores the images at once; ``close(groundtruth=None)`` writes the
    lists, the intrinsics and the ground truth. As a context manager it closes on a
    normal exit; after an exception it writes no lists, so the unfinished folder is
    rejected by ``open_sequence`` instead of being read as a shorter sequence.
    """

    def __init__(self, path, camera: CameraInfo, depth_scale: float = DEFAULT_DEPTH_SCALE):
        if not isinstance(camera, CameraInfo):
            raise ValueError(f"SequenceWriter: expected CameraInfo, got {type(camera).__name__}")
        if not (math.isfinite(depth_scale) and depth_scale > 0):
            raise ValueError(f"SequenceWriter: depth_scale must be a positive number, got {depth_scale}")
        self.path = Path(path)
        if (self.path / "rgb.txt").exists():
            raise ValueError(f"SequenceWriter: {self.path} already holds a sequence (rgb.txt exists)")
        if camera.D.size and np.any(camera.D != 0):
            raise ValueError(f"SequenceWriter: {INTRINSICS_FILE} cannot hold distortion, got D={camera.D.tolist()}")
        self.camera = camera
        self.depth_scale = float(depth_scale)
        (self.path / "rgb").mkdir(parents=True, exist_ok=True)
        (self.path / "depth").mkdir(parents=True, exist_ok=True)
        self._stamps: list[float] = []
        self._closed = False
        self._clipped = 0

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None and not self._closed:
            self.close()

    def __len__(self) -> int:
        return len(self._stamps)

    def write(self, frame: RGBDFrame) -> None:
        """Store one frame: rgb/<timestamp>.png (8-bit) and depth/<timestamp>.png (uint16).

        Depth is rounded to 1/depth_scale m; NaN and depths beyond 65535/depth_scale are
        written as 0 (missing). Timestamps must increase.
        """
        if self._closed:
            raise ValueError("SequenceWriter.write: the writer is closed")
        if not isinstance(frame, RGBDFrame):
            raise ValueError(f"SequenceWriter.write: expected RGBDFrame, got {type(frame).__name__}")
        cam = frame.camera
        if (cam.width, cam.height) != (self.camera.width, self.camera.height) or not np.allclose(cam.K, self.camera.K):
            raise ValueError("SequenceWriter.write: the frame's camera differs from the sequence's "
                             f"({cam.width}x{cam.height}, fx={cam.fx:.6g} vs {self.camera.width}x{self.camera.height}, "
                             f"fx={self.camera.fx:.6g})")
        stamp = frame.timestamp_s
        if self._stamps and stamp <= self._stamps[-1]:
            raise ValueError(f"SequenceWriter.write: timestamps must increase, got {stamp:.6f} after {self._stamps[-1]:.6f}")
        name = f"{stamp:.6f}.png"
        depth = np.nan_to_num(frame.depth_m, nan=0.0).astype(np.float64) * self.depth_scale
        too_far = depth > 65535.0
        self._clipped += int(too_far.sum())
        raw = np.where(too_far, 0.0, np.rint(depth)).astype(np.uint16)
        ok = cv2.imwrite(str(self.path / "rgb" / name), cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
        ok &= cv2.imwrite(str(self.path / "depth" / name), raw)
        if not ok:
            raise OSError(f"{self.path}: could not write frame images for timestamp {stamp:.6f}")
        self._stamps.append(stamp)

    def close(self, groundtruth: dict | None = None) -> None:
        """Write rgb.txt, depth.txt, camera_intrinsic.json and, if given, groundtruth_mesh.npz.

        groundtruth : dict with ``vertices`` (T, V, 3) float metres camera frame (T = frames
        written), ``faces`` (F, 3) int, ``uv`` (V, 2); stored as float32, int64, float32
        """
        if self._closed:
            raise ValueError("SequenceWriter.close: already closed")
        if not self._stamps:
            raise ValueError("SequenceWriter.close: no frames written")
        if groundtruth is not None:
            gt = self._check_groundtruth(groundtruth)
            np.savez_compressed(self.path / GROUNDTRUTH_FILE, **gt)
        write_intrinsics(self.path / INTRINSICS_FILE, self.camera, self.depth_scale)
        for kind, title in (("rgb", "color images"), ("depth", "depth maps")):
            lines = [f"# {title}", f"# file: '{self.path.name}'", "# timestamp filename"]
            lines += [f"{s:.6f} {kind}/{s:.6f}.png" for s in self._stamps]
            (self.path / f"{kind}.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
        if self._clipped:
            log.warning("%s: %d depth pixels beyond %.2f m written as missing", self.path, self._clipped,
                        65535.0 / self.depth_scale)
        self._closed = True
        log.info("%s: %d frames written", self.path, len(self._stamps))

    def _check_groundtruth(self, groundtruth: dict) -> dict:
        for key in ("vertices", "faces", "uv"):
            if key not in groundtruth:
                raise ValueError(f"SequenceWriter.close: groundtruth lacks {key!r}")
        v = np.asarray(groundtruth["vertices"], dtype=np.float32)
        f = np.asarray(groundtruth["faces"])
        uv = np.asarray(groundtruth["uv"], dtype=np.float32)
        if v.ndim != 3 or v.shape[2] != 3 or v.shape[0] != len(self._stamps):
            raise ValueError(f"SequenceWriter.close: groundtruth vertices must be ({len(self._stamps)}, V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
            raise ValueError(f"SequenceWriter.close: groundtruth faces must be an integer (F, 3) array, got {f.dtype} {f.shape}")
        if uv.shape != (v.shape[1], 2):
            raise ValueError(f"SequenceWriter.close: groundtruth uv must be ({v.shape[1]}, 2), got {uv.shape}")
        return {"vertices": v, "faces": f.astype(np.int64), "uv": uv}


def read_mask(path: Path, shape: tuple[int, int], what: str = "init mask") -> np.ndarray:
    """(H, W) bool mask from an 8-bit PNG, non-zero on the object; raises ValueError (one line)
    starting with ``what`` (the mask's name to the user, e.g. the option that gave it) and ``path``."""
    if not path.is_file():
        raise ValueError(f"{what} {path}: no such file")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{what} {path}: not a readable image")
    if img.ndim == 3:
        img = img.max(axis=2)
    if img.shape != shape:
        raise ValueError(f"{what} {path}: size {img.shape[1]}x{img.shape[0]} differs from the frames' "
                         f"{shape[1]}x{shape[0]}")
    mask = img > 0
    if not mask.any():
        raise ValueError(f"{what} {path}: empty (no non-zero pixel)")
    return mask
