"""Reduced-space step solvers: Y eliminated, W^(X) = W(Xk, X, Y[X]) minimised over X (paper Sec. 4.1).

For given X the inner equation g(X, Y) = 0 is solved for Y (linear for the isotropic scheme,
damped Newton for anisotropic energies, :meth:`StepEvaluator.solve_y`). The gradient of W^ comes
from the adjoint: with J = dg/dz = [J_X | J_Y] and the objective gradient (f_X, f_Y),

    J_Y^T lam = -f_Y,        grad W^ = f_X + J_X^T lam,

which is the paper's dual problem (M + tt L) P = tau/tt^2 M (Y - X) up to sign and scale
(g = 1/2 dE/dY). Hessian-vector products of W^ (``newton``) are exact second-order adjoints with
the Lagrangian Hessian H of f + lam . g:

    v_Y = -J_Y^{-1} J_X v_X,  w = H (v_X, v_Y),  J_Y^T mu = -w_Y,  (Hess W^) v_X = w_X + J_X^T mu.

One sparse LU of J_Y at each evaluation point serves the adjoint and every Hessian-vector product
there (the inner Newton solve for Y factorises on its own).

Methods: ``gd`` (gradient descent with Armijo backtracking, the paper's method), ``lbfgs``
(scipy L-BFGS-B), ``newton`` (scipy trust-region Newton-CG with exact Hessian-vector products).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import scipy.optimize as so
import scipy.sparse.linalg as spla

from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.settings import SolverSettings, integer, option, real
from willmore_nlp.solvers.base import SolveResult, register_solver


@dataclass(frozen=True)
class ReducedSettings(SolverSettings):
    """Options of the reduced solvers ``gd``, ``lbfgs`` and ``newton``.

    Attributes
    ----------
    tol : float
        Tolerance on |grad W^|_inf relative to max(1, |grad W^(X0)|_inf).
    max_iter : int
        Iterations.
    armijo : float
        Sufficient-decrease constant of the line search (``gd``, ``newton-krylov``).
    """

    tol: float = option(1e-6, real(0, lo_open=True))
    max_iter: int = option(1000, integer(0))
    armijo: float = option(1e-4, real(0, 1, lo_open=True))


@dataclass
class _Point:
    """Everything evaluated at one X: Y[X], W^, its gradient, J_X, J_Y, the factorised J_Y and the adjoint."""

    x: np.ndarray
    z: np.ndarray
    f: float
    grad: np.ndarray
    lam: np.ndarray
    Jx: Any
    lu: Any
    H: Any = None
    Jy: Any = None


class ReducedSolver:
    """W^(X) minimised over the free X with Y eliminated.

    Parameters
    ----------
    evaluator : StepEvaluator
    settings : ReducedSettings
    method : {"gd", "lbfgs", "newton"}
    """

    def __init__(self, evaluator: StepEvaluator, settings: ReducedSettings, method: str) -> None:
        self.name = method
        self.ev = evaluator
        self.P = evaluator.problem
        self.tol = settings.tol
        self.max_iter = settings.max_iter
        self.armijo = settings.armijo
        self.nxm = self.P.nX * self.P.m
        self._counts: dict[str, int] = {}

    # -- evaluation -------------------------------------------------------------------
    def _count(self, key: str, n: int = 1) -> None:
        self._counts[key] = self._counts.get(key, 0) + n

    def _at(self, x: np.ndarray, p: np.ndarray, Y0: np.ndarray) -> _Point:
        P, m = self.P, self.P.m
        Xk = p[: P.n_vertices * m].reshape(-1, m)
        X, _ = P.unpack_z(np.concatenate([x, np.zeros(int(P.y_free.sum()) * m)]), Xk)
        Y = self.ev.solve_y(X, p, Y0)
        self._count("n_inner_solve")
        z = P.pack_z(X, Y)
        f, gf = self.ev.f_grad(z, p)
        J = self.ev.jac_g(z, p)
        self._count("n_eval_grad_f")
        self._count("n_eval_jac_g")
        lu = spla.splu(J[:, self.nxm :].tocsc())
        self._count("n_factorizations")
        return self._point(x, z, f, gf, J, lu)

    def _point(self, x: np.ndarray, z: np.ndarray, f: float, gf: np.ndarray, J: Any, lu: Any) -> _Point:
        """The reduced gradient at a feasible z from the adjoint ``J_Y^T lam = -f_Y`` (module docstring).

        ``lu`` is any factorisation of J_Y with ``solve(b, trans="T")``.
        """
        lam = lu.solve(-gf[self.nxm :], trans="T")
        self._count("n_linear_solves")
        Jx = J[:, : self.nxm]
        grad = gf[: self.nxm] + Jx.T @ lam
        return _Point(x.copy(), z, f, grad, lam, Jx, lu, Jy=J[:, self.nxm :])

    def _hessp(self, pt: _Point, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        vy = -pt.lu.solve(pt.Jx @ v)
        if pt.H is None:
            pt.H = self.ev.hess_lag(pt.z, p, 1.0, pt.lam)
            self._count("n_eval_hess")
        w = pt.H @ np.concatenate([v, vy])
        mu = pt.lu.solve(-w[self.nxm :], trans="T")
        self._count("n_linear_solves", 2)
        return w[: self.nxm] + pt.Jx.T @ mu

    # -- methods ----------------------------------------------------------------------
    def _gd(self, pt: _Point, p: np.ndarray, gtol: float) -> tuple[_Point, int, str]:
        step = 1.0
        for it in range(self.max_iter):
            if np.abs(pt.grad).max() <= gtol:
                return pt, it, "converged"
            d = -pt.grad
            gd = float(pt.grad @ d)
            step *= 2.0
            Y0 = self.P.unpack_z(pt.z, p[: self.P.n_vertices * self.P.m].reshape(-1, self.P.m))[1]
            while True:
                try:
                    new = self._at(pt.x + step * d, p, Y0)
                    ok = np.isfinite(new.f) and new.f <= pt.f + self.armijo * step * gd
                except RuntimeError:
                    ok = False
                if ok:
                    break
                step *= 0.5
                if step < 1e-20:
                    return pt, it, "line search failed"
            pt = new
        return pt, self.max_iter, "maximum iterations"

    def _scipy(self, pt0: _Point, p: np.ndarray, gtol: float) -> tuple[_Point, int, str]:
        cache: dict[str, _Point] = {"pt": pt0}
        Xk = p[: self.P.n_vertices * self.P.m].reshape(-1, self.P.m)

        def point(x: np.ndarray) -> _Point:
            if not np.array_equal(x, cache["pt"].x):
                Y0 = self.P.unpack_z(cache["pt"].z, Xk)[1]
                cache["pt"] = self._at(x, p, Y0)
            return cache["pt"]

        def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
            q = point(x)
            return q.f, q.grad

        if self.name == "lbfgs":
            r = so.minimize(fun, pt0.x, jac=True, method="L-BFGS-B",
                            options={"maxiter": self.max_iter, "gtol": gtol, "ftol": 1e-15, "maxcor": 20})
        else:
            r = so.minimize(fun, pt0.x, jac=True, method="trust-ncg",
                            hessp=lambda x, v: self._hessp(point(x), p, v),
                            options={"maxiter": self.max_iter, "gtol": gtol})
        pt = point(r.x)
        gmax = float(np.abs(pt.grad).max())
        status = "converged" if gmax <= gtol else f"{r.message} (|grad W^| = {gmax:.2e} > {gtol:.2e})"
        return pt, int(r.nit), status

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """Minimise W^ from the X part of ``z0`` (its Y part warm-starts the inner solves)."""
        t0 = time.perf_counter()
        self._counts = {}
        Xk = p[: self.P.n_vertices * self.P.m].reshape(-1, self.P.m)
        pt = self._at(np.asarray(z0[: self.nxm], float), p, self.P.unpack_z(z0, Xk)[1])
        gtol = self.tol * max(1.0, float(np.abs(pt.grad).max()))
        if self.name == "gd":
            pt, it, status = self._gd(pt, p, gtol)
        else:
            pt, it, status = self._scipy(pt, p, gtol)
        stats: dict[str, Any] = dict(self._counts)
        stats["t_wall_total"] = time.perf_counter() - t0
        stats["kkt_residual"] = float(np.abs(pt.grad).max())
        stats["gtol"] = gtol
        stats["inf_pr"] = float(np.abs(self.ev.g(pt.z, p)).max())
        return SolveResult(z=pt.z, f=pt.f, lam_g=pt.lam, converged=status == "converged", status=status,
                           iterations=it, stats=stats)



for _name in ("gd", "lbfgs", "newton"):
    register_solver(_name, type(f"{_name.title()}Settings", (ReducedSettings,), {"solver": _name}))(
        partial(ReducedSolver, method=_name))
