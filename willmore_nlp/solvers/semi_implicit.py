"""Linear semi-implicit baseline for Willmore flow of closed curves (not an NLP: one sparse solve per step).

The scheme is the mixed (position, curvature vector) parametric discretisation of elastic flow of
curves in R^m in the spirit of Dziuk, Kuwert & Schaetzle (*Evolution of elastic curves in R^n:
existence and computation*, SIAM J. Math. Anal. 33, 2002), with all geometric quantities on X^k:

    M (X^{k+1} - X^k) / tau = L kappa^{k+1} - 3/2 M_l |kappa^k|^2 kappa^{k+1} - lam L X^{k+1}
    M kappa^{k+1} + L X^{k+1} = 0

M, L are the P1 mass and stiffness matrices of X^k, M_l the lumped mass. For a smooth curve this is
X_t = -d_s^2 kappa - 3/2 |kappa|^2 kappa + lam kappa, whose normal part is the Willmore (elastic)
flow -(kappa_ss + kappa^3 / 2) n + lam kappa n; the tangential part only reparametrises. The
|kappa|^2 factor is lagged, so the system is linear and decouples into the m coordinates with one
sparse LU per step. This is the baseline the paper compares against (its Figs. 2-3 and 9 quote
semi-implicit schemes); surfaces (Rusu's or Dziuk's 2008 scheme) are not implemented.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.fem.assembly import lumped_mass, mass_stiffness
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.solvers.base import SolveResult, register_solver


class SemiImplicitSolver:
    """One linear solve per step for closed curves (see the module docstring).

    Parameters
    ----------
    evaluator : StepEvaluator
        Supplies the mesh connectivity and the parameter layout (Xk, tau, tt, lam); the step
        problem's W is only evaluated for reporting.
    options : dict
        None accepted (the scheme has no tolerances).
    """

    name = "semi-implicit"
    variational = False
    """Not a minimisation of W: the flow does not apply the nested scheme's energy inequality."""

    def __init__(self, evaluator: StepEvaluator, options: dict[str, Any]) -> None:
        unknown = set(options) - {"tol", "max_iter", "warm_start", "print_level"}
        if unknown:
            raise ValueError(f"solver semi-implicit: unknown option(s) {', '.join(sorted(unknown))}; it has none")
        P = evaluator.problem
        if P.simplices.shape[1] != 2 or P.nX != P.n_vertices:
            raise ValueError("solver semi-implicit: the baseline is implemented for closed curves only "
                             "(no surfaces, no clamped boundaries)")
        self.ev = evaluator
        self.P = P

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """X^{k+1} from X^k = the Xk block of ``p``; ``z0`` is not used."""
        t0 = time.perf_counter()
        P, m = self.P, self.P.m
        N = P.n_vertices
        Xk = p[: N * m].reshape(-1, m)
        tau, lam = float(p[N * m]), float(p[N * m + 2])
        S = P.simplices
        M, L = mass_stiffness(Xk, S, N)
        Ml = lumped_mass(Xk, S, N)
        kappa_k = -L @ Xk / Ml[:, None]
        D = sp.diags(1.5 * Ml * np.sum(kappa_k**2, axis=1))
        K = sp.bmat([[M + tau * lam * L, -tau * (L - D)], [L, M]], format="csc")
        rhs = np.vstack([M @ Xk, np.zeros_like(Xk)])
        sol = spla.splu(K).solve(rhs)
        X = sol[:N]
        Y = self.ev.solve_y(X, p)
        z = P.pack_z(X, Y)
        ok = bool(np.all(np.isfinite(X)))
        stats = {"n_linear_solves": m, "n_factorizations": 1, "t_wall_total": time.perf_counter() - t0,
                 "kkt_residual": 0.0}
        return SolveResult(z=z, f=self.ev.f(z, p) if ok else float("nan"), lam_g=np.zeros(P.ng), converged=ok,
                           status="linear solve" if ok else "non-finite solution", iterations=1, stats=stats)


@register_solver("semi-implicit")
def make_semi_implicit(evaluator: StepEvaluator, options: dict[str, Any]) -> SemiImplicitSolver:
    """Factory for :class:`SemiImplicitSolver`."""
    return SemiImplicitSolver(evaluator, options)
