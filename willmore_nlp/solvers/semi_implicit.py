"""Linear semi-implicit baseline for Willmore flow of closed curves and surfaces (one sparse solve per step).

A mixed (position X, mean-curvature vector H) parametric scheme with all geometric quantities on
X^k, in the spirit of Dziuk, Kuwert & Schaetzle (*Evolution of elastic curves in R^n: existence and
computation*, SIAM J. Math. Anal. 33, 2002) for curves and of Rusu's mixed scheme (*An algorithm for
the elastic flow of surfaces*, Interfaces Free Bound. 7, 2005) for surfaces:

    M (X^{k+1} - X^k) / tau = L H^{k+1} + M_l diag(c^k) H^{k+1} - lam L X^{k+1}
    M H^{k+1} + L X^{k+1} = 0,          c = -3/2 |H|^2 + 4 K

M, L are the P1 mass and stiffness matrices of X^k, M_l the lumped mass, K the Gauss curvature
(angle defect, 0 for curves). For a smooth surface, X_t = -Delta H + c H has the normal part of
Willmore flow, -(Delta h + h (h^2 - 4K)/2) n with h = k1 + k2 (the tangential part only
reparametrises), plus lam H for the area term; round spheres are stationary for lam = 0. The
coefficient c is lagged, so the system is linear and decouples into the m coordinates: one sparse
LU per step. Differences from the cited schemes: tangential terms are dropped and the nonlinearity
is lagged explicitly; it is a baseline, stable only for small tau (measured in the studies).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.errors import UserInputError
from willmore_nlp.fem.assembly import lumped_mass, mass_stiffness
from willmore_nlp.geometry import gauss_curvature
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.settings import SOLVER_IGNORED, SolverSettings
from willmore_nlp.solvers.base import SolveResult, register_solver


@dataclass(frozen=True)
class SemiImplicitSettings(SolverSettings):
    """``semi-implicit`` has no options (it has no tolerances: ``tol`` and ``max_iter`` are ignored)."""

    solver = "semi-implicit"
    ignores = (*SOLVER_IGNORED, "tol", "max_iter")


@register_solver("semi-implicit", SemiImplicitSettings, capabilities=frozenset(), noun="the baseline")
class SemiImplicitSolver:
    """One linear solve per step for closed curves and surfaces (see the module docstring).

    Parameters
    ----------
    evaluator : StepEvaluator
        Supplies the mesh connectivity and the parameter layout (Xk, tau, tt, lam); the step
        problem's W is only evaluated for reporting.
    settings : SemiImplicitSettings
    """

    name = "semi-implicit"

    def __init__(self, evaluator: StepEvaluator, settings: SemiImplicitSettings) -> None:
        self.check_problem(evaluator.problem)
        self.ev = evaluator
        self.P = evaluator.problem

    @staticmethod
    def check_problem(P: Any) -> None:
        """UserInputError unless the step problem ``P`` is a closed curve's or a closed surface's in R^3 (checked before
        the terms, :func:`~willmore_nlp.solvers.base.check_solver`: a clamped arc was first told to drop the tangential
        weight that its problem had set, then that the baseline has no clamped boundaries)."""
        if P.nX != P.n_vertices or (P.simplices.shape[1] == 3 and P.m != 3):
            raise UserInputError("solver semi-implicit: the baseline is implemented for closed curves and closed "
                                 "surfaces in R^3 (no clamped boundaries)")

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """X^{k+1} from X^k = the Xk block of ``p``; ``z0`` is not used."""
        t0 = time.perf_counter()
        P, m = self.P, self.P.m
        N = P.n_vertices
        Xk = P.params.xk(p)
        tau, lam = P.params.scalar(p, "tau"), P.params.scalar(p, "lam")
        S = P.simplices
        M, L = mass_stiffness(Xk, S, N)
        Ml = lumped_mass(Xk, S, N)
        Hk = -L @ Xk / Ml[:, None]
        K = gauss_curvature(Xk, S) if S.shape[1] == 3 else np.zeros(N)
        D = sp.diags(Ml * (1.5 * np.sum(Hk**2, axis=1) - 4.0 * K))
        A = sp.bmat([[M + tau * lam * L, -tau * (L - D)], [L, M]], format="csc")
        rhs = np.vstack([M @ Xk, np.zeros_like(Xk)])
        sol = spla.splu(A).solve(rhs)
        X = sol[:N]
        Y = self.ev.solve_y(X, p)
        z = P.pack_z(X, Y)
        ok = bool(np.all(np.isfinite(X)))
        stats = {"n_linear_solves": m, "n_factorizations": 1, "t_wall_total": time.perf_counter() - t0,
                 "kkt_residual": 0.0}
        return SolveResult(z=z, f=self.ev.f(z, p) if ok else float("nan"), lam_g=np.zeros(P.nc), converged=ok,
                           status="linear solve" if ok else "non-finite solution", iterations=1, stats=stats)

