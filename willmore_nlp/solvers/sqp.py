"""Newton's method for the Lagrangian (paper Sec. 4.2) as a line-search SQP with exact Hessians.

Each iteration solves the KKT system of the step problem

    [ H + delta I   J^T ] [ dz  ]     [ grad f ]
    [ J             0   ] [ lam ] = - [ c      ]

with c = [g; h] the inner and the outer constraints, J their Jacobian, H the exact Hessian of the
Lagrangian f + lam . c (assembled from the element kernels), and
takes a backtracking step on the l1 merit function f + nu |c|_1. With outer constraints, when the
full step fails, a second-order correction (the same KKT matrix with right-hand side [0; c(z + dz)])
is tried first: it avoids the Maratos effect, which cut the steps of constrained flows (volume and
area fixed, 162-vertex ellipsoid) to 1/32 for 30 iterations per step (3 with it). Without outer
constraints it is not tried: on the stiff circle step of tests/test_solvers.py it led the iterates
into a region of tiny steps (200 iterations instead of ~60). Where the step has too little
curvature (dz^T H dz < kappa |dz|^2, an inertia-free test in the spirit of Chiang & Zavala 2016)
the Hessian is regularised by delta I, increased tenfold until the test holds.

This replaces CasADi's ``sqpmethod``, which on these problems (indefinite Lagrangian Hessian,
positive definite only on the constraint null space) diverges without convexification, stalls with
``convexify_strategy="regularize"`` (steps of 3e-5) and crashes with the ``eigen-*`` strategies in
CasADi 3.8.2 (measured; issue-5 note).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.settings import SolverSettings, integer, option, real
from willmore_nlp.solvers.base import SolveResult, register_solver


@dataclass(frozen=True)
class SqpSettings(SolverSettings):
    """Options of ``sqp``.

    Attributes
    ----------
    tol : float
        Tolerance on the dual and primal infeasibility, relative to max(1, |grad f(z0)|_inf).
    max_iter : int
        SQP iterations.
    """

    solver = "sqp"
    tol: float = option(1e-9, real(0, lo_open=True))
    max_iter: int = option(200, integer(0))


@register_solver("sqp", SqpSettings)
class SqpSolver:
    """Line-search SQP with exact Hessians (see the module docstring).

    Parameters
    ----------
    evaluator : StepEvaluator
    settings : SqpSettings
    """

    name = "sqp"

    def __init__(self, evaluator: StepEvaluator, settings: SqpSettings) -> None:
        self.ev = evaluator
        self.tol = settings.tol
        self.max_iter = settings.max_iter

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """Solve from ``z0`` (multipliers start at ``lam_g0`` or 0)."""
        t0 = time.perf_counter()
        ev = self.ev
        z = np.array(z0, float)
        lam = np.zeros(ev.problem.nc) if lam_g0 is None else np.array(lam_g0, float)
        counts = {"n_eval_f": 0, "n_eval_grad_f": 0, "n_eval_jac_g": 0, "n_eval_hess": 0, "n_factorizations": 0}
        nu = 1.0
        soc = ev.problem.nh > 0
        delta = 0.0
        status = "maximum iterations"
        scale = None
        inf_du = inf_pr = float("inf")
        for it in range(self.max_iter + 1):
            f, gf = ev.f_grad(z, p)
            g, J = ev.c_jac(z, p)
            counts["n_eval_grad_f"] += 1
            counts["n_eval_jac_g"] += 1
            if scale is None:
                scale = max(1.0, float(np.abs(gf).max()))
            inf_du = float(np.abs(gf + J.T @ lam).max())
            inf_pr = float(np.abs(g).max())
            if inf_du <= self.tol * scale and inf_pr <= self.tol * scale:
                status = "converged"
                break
            if it == self.max_iter:
                break
            H = ev.hess_lag(z, p, 1.0, lam)
            counts["n_eval_hess"] += 1
            n = z.size
            delta = delta / 4 if delta > 0 else 0.0
            for _ in range(30):
                K = sp.bmat([[H + delta * sp.identity(n), J.T], [J, None]], format="csc")
                lu = spla.splu(K)
                sol = lu.solve(-np.concatenate([gf, g]))
                counts["n_factorizations"] += 1
                dz, lam_new = sol[:n], sol[n:]
                if float(dz @ (H @ dz)) + delta * float(dz @ dz) >= 1e-8 * scale * float(dz @ dz):
                    break
                delta = max(1e-6 * scale, 10 * delta)
            nu = max(nu, 1.1 * float(np.abs(lam_new).max()))
            phi0 = f + nu * np.abs(g).sum()
            dphi = float(gf @ dz) - nu * np.abs(g).sum()
            alpha = 1.0
            for _ in range(40):
                zt = z + alpha * dz
                ft = ev.f(zt, p)
                counts["n_eval_f"] += 1
                gt = np.concatenate([ev.g(zt, p), ev.h(zt, p)])
                if np.isfinite(ft) and ft + nu * np.abs(gt).sum() <= phi0 + 1e-4 * alpha * dphi:
                    break
                if soc and alpha == 1.0 and np.all(np.isfinite(gt)):  # second-order correction (Maratos effect)
                    zs = zt - lu.solve(np.concatenate([np.zeros(n), gt]))[:n]
                    fs = ev.f(zs, p)
                    counts["n_eval_f"] += 1
                    if np.isfinite(fs) and fs + nu * np.abs(np.concatenate([ev.g(zs, p), ev.h(zs, p)])).sum() <= (
                            phi0 + 1e-4 * dphi):
                        dz = zs - z
                        break
                alpha *= 0.5
            z = z + alpha * dz
            lam = lam + alpha * (lam_new - lam)
        stats = dict(counts)
        stats.update(t_wall_total=time.perf_counter() - t0, inf_du=inf_du, inf_pr=inf_pr,
                     kkt_residual=max(inf_du, inf_pr), gtol=self.tol * (scale or 1.0),
                     n_linear_solves=counts["n_factorizations"], delta=delta)
        return SolveResult(z=z, f=f, lam_g=lam, converged=status == "converged", status=status,
                           iterations=it, stats=stats)

