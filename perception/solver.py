"""The semi-implicit minimisation of the paper (section III-E, eq. 32-37).

Each iteration solves ``(K + alpha I) V_t = alpha V_{t-1} - sum_k lambda_k grad_k(V_{t-1})``:
smoothness implicit, data terms explicit. ``K + alpha I`` is constant for a mesh, so it is
factored once and every iteration (and frame) is a back-substitution for the three
coordinate columns at once.

The step ``D = V_t - V_{t-1} = -(K + alpha I)^{-1} grad Psi(V_{t-1})`` is a preconditioned
descent direction. The paper takes it whole; with many correspondences on one triangle
the explicit data forces can overshoot, so each step is checked against the energy and
halved until it decreases (Armijo backtracking). The factorisation is untouched by this.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

log = logging.getLogger(__name__)


@dataclass
class SolveResult:
    """vertices (N, 3) float64; energies per term (weighted total under "total");
    iterations used; converged: the last step moved no vertex more than the tolerance."""

    vertices: np.ndarray
    energies: dict
    iterations: int
    converged: bool
    history: list = field(default_factory=list)


class SemiImplicitSolver:
    """Minimises ``Psi_S(V) + sum_k lambda_k Psi_k(V)`` from a starting mesh.

    K : (N, N) sparse smoothness matrix; alpha : adaptation rate (> 0), larger is more
    cautious. Data terms are ``(weight, term)`` pairs whose ``evaluate(V)`` returns
    ``(energy, gradient (N, 3))``.
    """

    def __init__(self, K: sp.spmatrix, alpha: float):
        if not alpha > 0:
            raise ValueError(f"alpha must be positive, got {alpha}")
        n = K.shape[0]
        self.K = sp.csc_matrix(K)
        self.alpha = float(alpha)
        self._lu = splu((self.K + self.alpha * sp.identity(n, format="csc")).tocsc())

    def _total(self, V, terms):
        KV = self.K @ V
        parts = {"smoothness": 0.5 * float(np.sum(V * KV))}
        grad = KV.copy()
        total = parts["smoothness"]
        for weight, term in terms:
            e, g = term.evaluate(V)
            parts[term.name] = e
            total += weight * e
            grad += weight * g
        parts["total"] = total
        return total, grad, parts

    def minimise(self, V0: np.ndarray, terms, max_iterations: int = 30, tolerance_m: float = 1e-4,
                 max_halvings: int = 8) -> SolveResult:
        V = np.array(V0, dtype=np.float64)
        total, grad, parts = self._total(V, terms)
        history = [total]
        it = 0
        converged = False
        for it in range(1, max_iterations + 1):
            data_grad = grad - self.K @ V
            D = self._lu.solve(self.alpha * V - data_grad) - V
            slope = float(np.sum(grad * D))
            if slope >= 0:  # no descent left (gradient numerically zero)
                converged = True
                it -= 1
                break
            step = 1.0
            for _ in range(max_halvings + 1):
                V_try = V + step * D
                t_try, g_try, p_try = self._total(V_try, terms)
                if t_try <= total + 1e-4 * step * slope:
                    break
                step *= 0.5
            else:
                converged = True  # no decrease along D: at a (local) minimum of the data
                it -= 1
                break
            moved = step * float(np.max(np.abs(D)))
            V, total, grad, parts = V_try, t_try, g_try, p_try
            history.append(total)
            if moved < tolerance_m:
                converged = True
                break
        return SolveResult(vertices=V, energies=parts, iterations=it, converged=converged, history=history)
