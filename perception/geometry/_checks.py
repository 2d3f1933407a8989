"""Input checks for arrays at public boundaries.

Each ``check_*`` helper converts its argument to the documented array form and raises
``ValueError`` with a one-line message naming the argument and what was received (shape,
dtype or value), never ``assert``: input checks must survive ``python -O``. The first
argument is the name used in the message, the second the value.
"""

from __future__ import annotations

import math

import numpy as np


def _finite_floats(name: str, arr: np.ndarray, copy: bool = True) -> np.ndarray:
    """``arr`` as float64 if its dtype is numeric and its values finite, else ValueError naming it."""
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"Expected {name} with a numeric dtype, got {arr.dtype}")
    arr = arr.astype(np.float64, copy=copy)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"Expected {name} with finite values, got NaN or infinity")
    return arr


def check_positive(name: str, value, allow_zero: bool = False) -> float:
    """``value`` as a finite float > 0 (or >= 0 with ``allow_zero``), else ValueError naming it."""
    value = float(value)
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"Expected {name} {bound}, got {value}")
    return value


def check_points(name: str, points, n: int | None = None, dim: int = 3, allow_empty: bool = False) -> np.ndarray:
    """Return ``points`` as a finite (n, dim) float64 array.

    Parameters
    ----------
    name : argument name used in the error message
    points : array-like, expected shape (n, dim)
    n : required number of rows, or None for any (at least one, unless ``allow_empty``)
    dim : required number of columns
    allow_empty : whether zero rows are accepted

    Returns
    -------
    (n, dim) float64
    """
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] != dim or (n is not None and arr.shape[0] != n):
        want = f"({'N' if n is None else n}, {dim})"
        raise ValueError(f"Expected {name} with shape {want}, got {arr.shape}")
    if arr.shape[0] == 0 and not allow_empty:
        raise ValueError(f"Expected {name} with at least one row, got {arr.shape}")
    return _finite_floats(name, arr, copy=False)


def check_ids(name: str, ids, n_vertices: int, ndim: int = 1, allow_empty: bool = False) -> np.ndarray:
    """Return vertex ids as an int64 array of shape (K,) (``ndim=1``) or (K, 3) (``ndim=2``, faces).

    Parameters
    ----------
    name : argument name used in the error message
    ids : array-like of integers in [0, n_vertices)
    n_vertices : number of mesh vertices
    ndim : 1 for a list of ids, 2 for triangles (K, 3)
    allow_empty : whether K = 0 is accepted

    Returns
    -------
    (K,) or (K, 3) int64
    """
    arr = np.asarray(ids)
    if arr.ndim != ndim or (ndim == 2 and arr.shape[1] != 3):
        want = "(K,)" if ndim == 1 else "(K, 3)"
        raise ValueError(f"Expected {name} with shape {want}, got {arr.shape}")
    if arr.size == 0:
        if not allow_empty:
            raise ValueError(f"Expected {name} to be non-empty, got shape {arr.shape}")
        return arr.astype(np.int64)
    if arr.dtype.kind not in "iu":
        raise ValueError(f"Expected {name} with an integer dtype, got {arr.dtype}")
    arr = arr.astype(np.int64, copy=False)
    if arr.min() < 0 or arr.max() >= n_vertices:
        raise ValueError(
            f"Expected {name} with vertex ids in [0, {n_vertices}), got ids in [{arr.min()}, {arr.max()}]"
        )
    return arr


def check_vector(name: str, vector, unit: bool = False, size: int = 3) -> np.ndarray:
    """Return ``vector`` as a finite (size,) float64 array, normalised if ``unit``.

    Raises ValueError for another shape, non-finite values or, with ``unit``, a
    zero vector.
    """
    arr = np.asarray(vector)
    if arr.shape != (size,):
        raise ValueError(f"Expected {name} with shape ({size},), got {arr.shape}")
    arr = _finite_floats(name, arr)
    if unit:
        norm = np.linalg.norm(arr)
        if norm < 1e-12:
            raise ValueError(f"Expected {name} to be a non-zero direction, got {arr.tolist()}")
        arr = arr / norm
    return arr


def check_transform(name: str, T, tol: float = 1e-6) -> np.ndarray:
    """Return a rigid transform as a (4, 4) float64 array.

    The upper-left (3, 3) block must be a rotation (orthonormal, determinant +1)
    within ``tol`` and the last row ``[0, 0, 0, 1]``.
    """
    arr = np.asarray(T)
    if arr.shape != (4, 4):
        raise ValueError(f"Expected {name} with shape (4, 4), got {arr.shape}")
    arr = _finite_floats(name, arr)
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise ValueError(f"Expected {name} with last row [0, 0, 0, 1], got {arr[3].tolist()}")
    R = arr[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=tol):
        raise ValueError(f"Expected {name} with an orthonormal rotation block, got R^T R = {np.round(R.T @ R, 6).tolist()}")
    det = np.linalg.det(R)
    if det < 0:
        raise ValueError(f"Expected {name} with a rotation of determinant +1, got {det:.6g}")
    return arr
