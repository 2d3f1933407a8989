"""Where the hidden part of a cloth goes: moved, and turned, with the cloth seen around it.

A vertex the camera cannot see has no data; the motion prior carries it by keeping the edges
around it as they were predicted (``perception.energy.MotionPriorTerm``). Edges kept as they
were do not turn: while the part in view turns (a cloth lifted off a table stands up, a hanging
one turns on its gripper), the hidden part is only shifted along and is left lying as it was,
bent away from the part seen at their seam.

``carried_prior`` moves the prior of each hidden vertex by the rigid motion (turn and shift)
that the vertices seen near it in the material made from the prediction to the estimate: a
fit weighted by their material distance, so the nearest say most and a part far from all of
them moves as the nearest part seen does. The solver then keeps the hidden part's edges as
they are in that moved prior.

Arrays: (N, 3) float metres, one row per mesh vertex; masks (N,) bool.
"""

from __future__ import annotations

import numpy as np

#: how far (metres, in the material) the motion of a vertex seen reaches: the weight of its
#: motion in a hidden vertex's fit falls as a Gaussian of their distance with this width
REACH_M = 0.1
#: at most this many of the vertices seen are the evidence (the fits' cost grows with them)
MAX_EVIDENCE = 96
#: at most this many fits are made, at hidden vertices spread over the hidden part; every
#: hidden vertex moves as the one nearest it
MAX_FITS = 64
#: fewer vertices seen than this give no motion to carry the hidden ones with
MIN_SEEN = 6
#: a neighbourhood of vertices seen that is this close to a line (its second spread at most
#: this fraction of its first) cannot say how it turned about that line: its shift alone is used
FLAT_RATIO = 0.05


def carried_prior(material: np.ndarray, prior: np.ndarray, estimate: np.ndarray, seen: np.ndarray,
                  hidden: np.ndarray, reach_m: float = REACH_M) -> np.ndarray:
    """(N, 3) the prior moved with the cloth seen.

    material : (N, 3) the vertices' material positions (the canonical mesh), which say who is
        near whom
    prior : (N, 3) the prediction the motion prior keeps hidden vertices near
    estimate : (N, 3) the estimate solved from it, whose ``seen`` vertices the data placed
    seen : (N,) bool, the vertices whose motion (prior to estimate) is evidence
    hidden : (N,) bool, the vertices to carry
    Returns the ``estimate`` where the vertex is not ``hidden``, and where it is, its prior
    moved by the rigid motion fitted to the seen vertices' motion, weighted by material
    distance (Gaussian of width ``reach_m``); ``estimate`` itself with fewer than ``MIN_SEEN``
    vertices seen.
    """
    moved = np.array(estimate, dtype=np.float64, copy=True)
    seen = np.asarray(seen, bool) & ~np.asarray(hidden, bool)
    hidden = np.asarray(hidden, bool)
    if seen.sum() < MIN_SEEN or not hidden.any():
        return moved
    ids = _evenly(np.flatnonzero(seen), MAX_EVIDENCE)
    hidden_ids = np.flatnonzero(hidden)
    sites = _evenly(hidden_ids, MAX_FITS)
    R, ca, cb = _rigid_fits(material[sites], material[ids], prior[ids], estimate[ids], reach_m)
    # each hidden vertex moves as the fit at the site nearest it in the material
    site = np.argmin(_squared_distances(material[hidden_ids], material[sites]), axis=1)
    moved[hidden_ids] = np.einsum("hij,hj->hi", R[site], prior[hidden_ids] - ca[site]) + cb[site]
    return moved


def _evenly(ids: np.ndarray, most: int) -> np.ndarray:
    """At most ``most`` of ``ids`` (K,) int, evenly spread along them: on the lattice meshes
    the tracker lays, numbered row by row, they spread over the cloth."""
    return ids if len(ids) <= most else ids[np.linspace(0, len(ids) - 1, most).round().astype(int)]


def _squared_distances(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(P, Q) squared distances between the points ``p`` (P, 3) and ``q`` (Q, 3)."""
    return np.maximum(np.sum(p ** 2, axis=1)[:, None] + np.sum(q ** 2, axis=1)[None, :] - 2.0 * p @ q.T, 0.0)


def _rigid_fits(sites: np.ndarray, material: np.ndarray, a: np.ndarray, b: np.ndarray, reach_m: float):
    """(R (S, 3, 3), ca (S, 3), cb (S, 3)): at each of the material points ``sites`` (S, 3), the
    rotation and centroids of the rigid motion x -> R (x - ca) + cb that best takes the points
    ``a`` (P, 3) to ``b`` (P, 3), each weighted by a Gaussian of the distance from its material
    position ``material`` (P, 3) to the site."""
    d2 = _squared_distances(sites, material)
    # A site far from all the points takes the motion of a wider neighbourhood: the nearest
    # ones alone are a strip along the seam, which cannot say how the cloth turned about it.
    # Weights relative to the nearest point, so none underflows.
    nearest = d2.min(axis=1, keepdims=True)
    W = np.exp(-(d2 - nearest) / (2.0 * np.maximum(reach_m ** 2, nearest)))
    W /= W.sum(axis=1, keepdims=True)
    ca, cb = W @ a, W @ b
    H = (W @ (a[:, :, None] * b[:, None, :]).reshape(len(a), 9)).reshape(-1, 3, 3) - ca[:, :, None] * cb[:, None, :]
    U, S, Vt = np.linalg.svd(H)
    V, Ut = np.transpose(Vt, (0, 2, 1)), np.transpose(U, (0, 2, 1))
    D = np.zeros((len(H), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.sign(np.linalg.det(V @ Ut))  # a rotation, not a reflection
    R = V @ D @ Ut
    R[S[:, 1] <= FLAT_RATIO * np.maximum(S[:, 0], 1e-30)] = np.eye(3)
    return R, ca, cb
