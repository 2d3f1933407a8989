"""Cloth textures generated in code (pure NumPy and OpenCV drawing, no files).

Images are (H, W, 3) uint8 RGB. Row 0 is the top of the cloth (``ClothMesh`` v = 0)
and column 0 its left edge (u = 0), so a texture spans the cloth's bounding box.
"""

from __future__ import annotations

import logging
import string

import cv2
import numpy as np

log = logging.getLogger(__name__)

_FONTS = (
    cv2.FONT_HERSHEY_SIMPLEX,
    cv2.FONT_HERSHEY_DUPLEX,
    cv2.FONT_HERSHEY_COMPLEX,
    cv2.FONT_HERSHEY_TRIPLEX,
)


def check_texture_size(width_px: int, height_px: int) -> tuple[int, int]:
    """Return (width_px, height_px) as ints >= 16 or raise ValueError naming them."""
    w, h = int(width_px), int(height_px)
    if w < 16 or h < 16:
        raise ValueError(f"texture size: expected at least 16x16 pixels, got {width_px}x{height_px}")
    return w, h


def _random_colour(rng: np.random.Generator, dark: bool) -> tuple[int, int, int]:
    """A saturated colour, dark or light, so shapes contrast with the background."""
    hue = rng.uniform(0, 180)
    sat = rng.uniform(120, 255)
    val = rng.uniform(20, 120) if dark else rng.uniform(170, 255)
    hsv = np.uint8([[[hue, sat, val]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])


def poster_texture(rng: np.random.Generator, width_px: int = 512, height_px: int = 384,
                   n_shapes: int = 60, n_words: int = 8) -> np.ndarray:
    """A printed, poster-like image rich in corners and blobs.

    Random filled and outlined rectangles, circles, triangles and short words of text
    on a pale background, with a few dark shapes among light ones so both bright and
    dark blobs exist at several scales (what SIFT and ORB detect). Shapes are sized
    relative to the image, so the pattern looks alike at any resolution.

    rng : numpy Generator, the only source of randomness
    width_px, height_px : image size; keep the aspect of the cloth it is mapped on
    n_shapes, n_words : how many shapes and words to draw
    returns (height_px, width_px, 3) uint8 RGB
    """
    w, h = check_texture_size(width_px, height_px)
    scale = min(w, h)
    background = np.array(_random_colour(rng, dark=False), dtype=np.float64)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (0.35 * background + 0.65 * 235).astype(np.uint8)
    # draw at 4x and shrink with area averaging: anti-aliased edges without blur
    ss = 4
    big = cv2.resize(img, (w * ss, h * ss), interpolation=cv2.INTER_NEAREST)
    for _ in range(int(n_shapes)):
        colour = _random_colour(rng, dark=rng.random() < 0.5)
        size = rng.uniform(0.03, 0.18) * scale * ss
        cx, cy = rng.uniform(0, w * ss), rng.uniform(0, h * ss)
        thickness = -1 if rng.random() < 0.7 else max(1, int(rng.uniform(0.005, 0.02) * scale * ss))
        kind = rng.integers(0, 3)
        if kind == 0:
            angle = rng.uniform(0, 180)
            box = cv2.boxPoints(((cx, cy), (size, size * rng.uniform(0.3, 1.0)), angle))
            _polygon(big, box, colour, thickness)
        elif kind == 1:
            cv2.circle(big, (int(cx), int(cy)), int(size / 2), colour, thickness, cv2.LINE_8)
        else:
            angles = rng.uniform(0, 2 * np.pi) + np.array([0.0, 2.1, 4.2]) + rng.uniform(-0.4, 0.4, 3)
            pts = np.stack([cx + 0.6 * size * np.cos(angles), cy + 0.6 * size * np.sin(angles)], axis=1)
            _polygon(big, pts, colour, thickness)
    for _ in range(int(n_words)):
        word = "".join(rng.choice(list(string.ascii_uppercase + string.digits), size=int(rng.integers(2, 6))))
        font = _FONTS[int(rng.integers(0, len(_FONTS)))]
        font_scale = rng.uniform(0.0015, 0.004) * scale * ss
        thickness = max(1, int(font_scale * rng.uniform(1.5, 3.0)))
        org = (int(rng.uniform(0, 0.8) * w * ss), int(rng.uniform(0.1, 1.0) * h * ss))
        cv2.putText(big, word, org, font, font_scale, _random_colour(rng, dark=True), thickness, cv2.LINE_8)
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)


def _polygon(img: np.ndarray, pts: np.ndarray, colour, thickness: int) -> None:
    poly = [np.round(pts).astype(np.int32)]
    if thickness < 0:
        cv2.fillPoly(img, poly, colour, cv2.LINE_8)
    else:
        cv2.polylines(img, poly, True, colour, thickness, cv2.LINE_8)


def plain_texture(rgb, width_px: int = 16, height_px: int = 16) -> np.ndarray:
    """A uniform colour, for textureless cloth.

    rgb : 3 ints in [0, 255]
    returns (height_px, width_px, 3) uint8 RGB
    """
    w, h = check_texture_size(width_px, height_px)
    colour = np.asarray(rgb)
    if colour.shape != (3,) or np.any(colour < 0) or np.any(colour > 255):
        raise ValueError(f"plain_texture: expected 3 values in [0, 255], got {np.asarray(rgb).tolist()}")
    img = np.empty((h, w, 3), np.uint8)
    img[:] = colour.astype(np.uint8)
    return img


def random_plain_colour(rng: np.random.Generator) -> tuple[int, int, int]:
    """A mid-saturation garment colour (no near-white or near-black, so shading shows)."""
    hue = rng.uniform(0, 180)
    hsv = np.uint8([[[hue, rng.uniform(60, 180), rng.uniform(120, 210)]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0])
