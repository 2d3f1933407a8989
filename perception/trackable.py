"""Where an image has texture that a point tracker can follow, rather than sensor noise.

Shi-Tomasi corner detection (``cv2.goodFeaturesToTrack``) keeps the strongest corners
relative to the strongest one in the image. On a cloth without print the strongest
"corners" are the camera's noise laid over smooth shading: Lucas-Kanade then follows the
shading, which stays where the light and the folds put it while the material slides under
it, and the correspondence term drags the mesh along with it.

A point can be followed when its window's structure tensor has, in its weakest direction,
clearly more gradient energy than the image's noise alone would put there. For white noise
of standard deviation sigma, the 3x3 Sobel gradient (divided by 8) has variance
``3 / 16 sigma^2`` in each direction, so a ``w x w`` window sums to about
``3 / 16 w^2 sigma^2``. The ratio of a window's smallest eigenvalue to that figure is the
texture's signal-to-noise ratio: about 1 (at most 1.6 in a 640 x 480 frame) where there is
nothing but noise, hence ``MIN_TEXTURE_SNR``. At the corners Shi-Tomasi picks (10th to 90th
percentile) it is 0.9 to 1.5 on the simulation's plain cloth, 6 to 80 on a grey foam seen by a
Kinect, 11 to 33 on a real shirt and 60 to 600 on a simulated print.

The noise is measured on the object's own pixels (Immerkaer's Laplacian-difference estimate,
with the median of absolute responses so that sparse edges do not raise it), as one figure
for the object: noise grows with brightness, and the background (a bright wall, a clipped
one) says little about the cloth's. A dense fine weave (cells of 2-3 px) raises the estimate,
which makes the test stricter there, never looser.
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.raster import bounding_box

#: a window counts as trackable above this many times the gradient energy of noise alone
MIN_TEXTURE_SNR = 2.0
#: noise below this (8-bit levels) is taken as this: 8-bit quantisation alone gives 0.29
MIN_NOISE_SIGMA = 0.5
#: the Laplacian-difference kernel: it cancels any locally linear (and most smooth) structure
_LAPLACE_DIFF = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
#: for Gaussian noise of sigma, the kernel's response has standard deviation 6 sigma; the
#: median of |x| for a normal variable is 0.6745 of its standard deviation
_MEDIAN_TO_SIGMA = 1.0 / (6.0 * 0.6745)


def noise_sigma(grey: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Standard deviation (8-bit levels) of the white noise in ``grey`` (H, W) uint8, over the
    pixels of ``mask`` (H, W) bool whose 3x3 neighbourhood lies in it (all if None).
    raises ValueError for another dtype, or when no such pixel exists"""
    if np.asarray(grey).dtype != np.uint8:
        raise ValueError(f"noise_sigma: expected a uint8 grey image, got {np.asarray(grey).dtype}")
    response = np.abs(cv2.filter2D(np.asarray(grey, np.float32), -1, _LAPLACE_DIFF))
    inner = np.zeros(response.shape, bool)
    inner[1:-1, 1:-1] = True
    if mask is not None:
        inner &= cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if not inner.any():
        raise ValueError(f"noise_sigma: no pixel with a 3x3 neighbourhood inside the image or mask (shape {np.shape(grey)})")
    return _grouped_median(np.rint(response[inner]).astype(np.int64)) * _MEDIAN_TO_SIGMA


def _grouped_median(values: np.ndarray) -> float:
    """The median of non-negative integers, interpolated within its unit bin: the plain
    median of integer responses moves in whole steps, a quarter of a grey level of noise."""
    counts = np.bincount(values)
    upto = np.cumsum(counts)  # values in each bin and under it
    half = len(values) / 2.0
    k = int(np.searchsorted(upto, half))
    return max(0.0, k - 0.5 + (half - (upto[k] - counts[k])) / counts[k])


def texture_snr(grey: np.ndarray, window: int, sigma: float) -> np.ndarray:
    """(H, W) float32: the smallest eigenvalue of each ``window`` x ``window`` structure
    tensor of ``grey`` over what white noise of ``sigma`` would give."""
    g = np.asarray(grey, np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    size = (int(window), int(window))
    xx = cv2.boxFilter(gx * gx, -1, size, normalize=False)
    xy = cv2.boxFilter(gx * gy, -1, size, normalize=False)
    yy = cv2.boxFilter(gy * gy, -1, size, normalize=False)
    smallest = (xx + yy) / 2 - np.sqrt(((xx - yy) / 2) ** 2 + xy * xy)
    return smallest / np.float32(3.0 / 16.0 * window * window * sigma * sigma)


def trackable(grey: np.ndarray, mask: np.ndarray, window: int, min_snr: float = MIN_TEXTURE_SNR) -> np.ndarray:
    """(H, W) bool: the pixels of ``mask`` whose ``window``-sized neighbourhood in ``grey``
    (uint8) has texture ``min_snr`` times above the noise measured on ``mask``."""
    out = np.zeros(mask.shape, bool)
    box = bounding_box(mask, pad=window)
    if box is None:
        return out
    y0, y1, x0, x1 = box
    crop, inside = grey[y0:y1, x0:x1], mask[y0:y1, x0:x1]
    try:
        sigma = max(noise_sigma(crop, inside), MIN_NOISE_SIGMA)
    except ValueError:  # a mask too thin to measure the noise on: nothing there to track either
        return out
    out[y0:y1, x0:x1] = inside & (texture_snr(crop, window, sigma) >= min_snr)
    return out
