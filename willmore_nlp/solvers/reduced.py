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

Outer constraints h(X, Y) = 0 (a few rows: volume, area) become constraints h^(X) = h(X, Y[X]) of the
reduced problem, with the reduced Jacobian C = dh^/dX = Jh_X + nu^T J_X, J_Y^T nu = -Jh_Y^T (one adjoint
per row). ``gd`` then follows the projected gradient G + C^T mu, mu = -(C C^T)^-1 C G (the least-squares
multipliers), and restores h^ = 0 at every trial point by Gauss-Newton steps -C^T (C C^T)^-1 h^: every
iterate is feasible, W^ decreases. The step problem's multipliers are [lam + nu mu; mu].

Methods: ``gd`` (gradient descent with Armijo backtracking, the paper's method; with outer constraints
projected), ``lbfgs`` (scipy L-BFGS-B), ``newton`` (scipy trust-region Newton-CG with exact
Hessian-vector products); the last two refuse outer constraints.
"""

from __future__ import annotations

import itertools
import time
import warnings
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import scipy.linalg as la
import scipy.optimize as so
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.fem.assembly import lumped_mass
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.model.step import StepProblem
from willmore_nlp.model.terms import CAPABILITIES
from willmore_nlp.settings import SolverSettings, integer, option, real
from willmore_nlp.solvers.base import SolveResult, register_solver
from willmore_nlp.solvers.cholesky import SymmetricFactor


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
    pgrad: Any = None  # gradient projected on the tangent space of the outer constraints (= grad without)
    h: Any = None  # (nh,) outer constraint residual
    C: Any = None  # (nh, nX m) reduced outer constraint Jacobian
    nu: Any = None  # (ng, nh) the outer constraints' adjoints: J_Y^T nu = -Jh_Y^T
    BC: Any = None  # B^-1 C^T and C B^-1 C^T of a preconditioner B (newton-krylov)
    CBC: Any = None
    gf: Any = None  # (nx,) objective gradient at z
    gv: Any = None  # (ng,) inner constraint residual at z (newton-krylov's full-space iteration)


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
        self._S: sp.csc_matrix | None = None  # free X dofs -> Y dofs (:meth:`_gauss_newton`)

    # -- evaluation -------------------------------------------------------------------
    def _count(self, key: str, n: int = 1) -> None:
        self._counts[key] = self._counts.get(key, 0) + n

    def _at(self, x: np.ndarray, p: np.ndarray, Y0: np.ndarray) -> _Point:
        P = self.P
        _, z, J = self.ev.inner_solve(P.unpack_x(x, P.params.xk(p)), p, Y0)
        self._count("n_inner_solve")
        f, gf = self.ev.f_grad(z, p)
        self._count("n_eval_grad_f")
        self._count("n_eval_jac_g")
        lu = spla.splu(J[:, self.nxm :].tocsc())
        self._count("n_factorizations")
        return self._point(x, z, f, gf, J, lu, p)

    def _point(self, x: np.ndarray, z: np.ndarray, f: float, gf: np.ndarray, J: Any, lu: Any,
               p: np.ndarray) -> _Point:
        """The reduced gradient at a feasible z from the adjoint ``J_Y^T lam = -f_Y`` (module docstring);
        with outer constraints also their reduced Jacobian and the projected gradient.

        ``lu`` is any factorisation of J_Y with ``solve(b, trans="T")``.
        """
        lam = lu.solve(-gf[self.nxm :], trans="T")
        self._count("n_linear_solves")
        Jx = J[:, : self.nxm]
        grad = gf[: self.nxm] + Jx.T @ lam
        pt = _Point(x.copy(), z, f, grad, lam, Jx, lu, Jy=J[:, self.nxm :], pgrad=grad, gf=gf)
        if self.P.nh:
            c, Jc = self.ev.c_jac(z, p)
            Jh = Jc.tocsr()[self.P.ng :]
            nu = np.column_stack([lu.solve(-row, trans="T") for row in Jh[:, self.nxm :].toarray()])
            self._count("n_linear_solves", self.P.nh)
            pt.h, pt.C = c[self.P.ng :], Jh[:, : self.nxm].toarray() + (Jx.T @ nu).T
            mu = -np.linalg.solve(pt.C @ pt.C.T, pt.C @ grad)
            pt.pgrad = grad + pt.C.T @ mu
            pt.lam, pt.nu = np.concatenate([lam + nu @ mu, mu]), nu
        return pt

    def _with_multipliers(self, pt: _Point, mu: np.ndarray) -> None:
        """Give the point's step-problem multipliers the outer constraints' multipliers ``mu`` ((nh,)) in place of
        the least-squares ones :meth:`_point` fitted: [lam + nu mu; mu]."""
        nh = self.P.nh
        pt.lam = np.concatenate([pt.lam[:-nh] + pt.nu @ (mu - pt.lam[-nh:]), mu])

    def _feasible(self, x: np.ndarray, p: np.ndarray, Y0: np.ndarray) -> _Point:
        """The point at x pulled onto h^ = 0 by Gauss-Newton steps along C^T (module docstring)."""
        pt = self._at(x, p, Y0)
        if not self.P.nh:
            return pt
        P = self.P
        htol = 1e-13 * np.abs([P.params.scalar(p, t) for t in P.targets])  # (relative, each: the flow's test)
        for _ in range(30):
            if np.all(np.abs(pt.h) <= htol):
                return pt
            pt = self._at(pt.x - pt.C.T @ np.linalg.solve(pt.C @ pt.C.T, pt.h), p, Y0)
            self._count("n_restoration")
        raise RuntimeError(f"outer constraints not restored (|h| = {np.abs(pt.h).max():.3e})")

    def _distance_hessian(self, z: np.ndarray, p: np.ndarray) -> sp.csc_matrix:
        """D: the Hessian in X of the distance (and control) part of W, i.e. of W with tau = 0 (constant in X)."""
        U = sp.csc_matrix(self.ev.hess_lag_upper(z, self.P.params.replace(p, tau=0.0), 1.0,
                                                 np.zeros(self.P.nc))[: self.nxm, : self.nxm])
        self._count("n_eval_hess")
        return (U + sp.triu(U, 1).T).tocsc()

    def _gauss_newton(self, pt: _Point, p: np.ndarray, weight: float = 1.0) -> sp.csr_matrix:
        """(nX m, nX m) ``weight`` times the Gauss-Newton part of the Hessian of 2 e(X) at ``pt``: 2 K^T Ml^-1 K,
        K = (J_X + J_Y S) / tt, Ml the lumped mass of the free Y nodes and S the injection of the free X dofs into
        the Y dofs (the residual (Y[X] - X) / tt of W is -Ml^-1 K to first order; ``newton-krylov``'s preconditioner
        is D + tau times this, :func:`normal_spectrum`'s its normal part)."""
        P, m = self.P, self.P.m
        if self._S is None:
            nodes = np.flatnonzero(P.x_free)
            rows = (P.y_index[nodes][:, None] * m + np.arange(m)).ravel()
            self._S = sp.csc_matrix((np.ones(rows.size), (rows, np.arange(rows.size))), shape=(P.ng, self.nxm))
        tt = P.params.scalar(p, "tt")
        X, _ = P.unpack_z(pt.z, P.params.xk(p))
        ml = lumped_mass(X, P.simplices, P.n_vertices)[P.y_free]
        K = (pt.Jx + pt.Jy @ self._S).tocsr()  # tt K
        # K^T (row-scaled K): one sparse product instead of three (0.2 s instead of 0.53-0.75 s at 10,242 v)
        return (K.T @ K.multiply(np.repeat(2.0 * weight / (tt * tt * ml), m)[:, None]).tocsr()).tocsr()

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
            if np.abs(pt.pgrad).max() <= gtol:
                return pt, it, "converged"
            d = -pt.pgrad
            gd = float(pt.grad @ d)
            step *= 2.0
            Y0 = self.P.unpack_z(pt.z, self.P.params.xk(p))[1]
            while True:
                try:
                    new = self._feasible(pt.x + step * d, p, Y0)
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
        Xk = self.P.params.xk(p)

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
        Xk = self.P.params.xk(p)
        pt = self._feasible(np.asarray(z0[: self.nxm], float), p, self.P.unpack_z(z0, Xk)[1])
        gtol = self.tol * max(1.0, float(np.abs(pt.pgrad).max()))
        if self.name == "gd":
            pt, it, status = self._gd(pt, p, gtol)
        else:
            pt, it, status = self._scipy(pt, p, gtol)
        stats: dict[str, Any] = dict(self._counts)
        stats["t_wall_total"] = time.perf_counter() - t0
        stats["kkt_residual"] = float(np.abs(pt.pgrad).max())
        stats["gtol"] = gtol
        stats["inf_pr"] = float(np.abs(np.concatenate([self.ev.g(pt.z, p), self.ev.h(pt.z, p)])).max())
        return SolveResult(z=pt.z, f=pt.f, lam_g=pt.lam, converged=status == "converged", status=status,
                           iterations=it, stats=stats)


for _name in ("gd", "lbfgs", "newton"):
    register_solver(_name, type(f"{_name.title()}Settings", (ReducedSettings,), {"solver": _name}),
                    CAPABILITIES if _name == "gd" else CAPABILITIES - {"constraints"})(
        partial(ReducedSolver, method=_name))


CONVEXITY_RESTARTS = 20
"""Restarts of the Lanczos iteration of :func:`convexity_limit` (40 Lanczos vectors each, relative residual 0.1: a
Ritz value is a Rayleigh quotient, so an inaccurate one overestimates tau_c, never underestimates it; the jump needs
tau_c to a factor 2). Measured on the first steps of docs/guide/mesh_quality.md's inputs: where the most negative
mode is strong (noisy inputs: the cylinder, cone, smoothed box, noisy spheres, tori, capsules and double torus) it
converges in 0.1 s (700 vertices) to 8 s (15,170) and 34 s (39,891) with sparse LU factors of J_Y and D (1.2 s
and 9.5 s with newton-krylov's Cholesky factors); on smooth inputs it either does not converge
(ellipsoid 1:1:2 of 2,562 v, 48x24 grid torus, Lawson's genus 2: 1.9-8.4 s), which is read as no strongly negative
mode, or finds a weak one (trimesh tori, the double torus: tau / 2.9 - tau / 11.9). With the residual 1e-2 and 20
vectors a noisy double torus (4,205 v, noise 0.1 h) did not converge in 221 products (8.7 s) and its first step
then took 17 attempts; with these settings it converges in 61 (1.2 s) to lambda = -8,531, 1.8 % above the value the
residual 1e-2 reaches with 100 restarts (-8,684)."""

CONVEXITY_FIRST_RESTARTS = 2
"""Restarts of the first, cheap look of ``convex_start`` (the flow, after a first step's first failed attempt): 61-81
Hessian-vector products. It converges where the most negative mode is strong (the noisy inputs of
docs/guide/mesh_quality.md but the noisy capsule of the study, h / 753, a genus-2 level set, h / 577, and the torus
pair of 10,192 v, h / 30,270; the 39,891-vertex noisy sphere needs the second cycle) and then gives the value of
:data:`CONVEXITY_RESTARTS` exactly (the same deterministic iteration, stopped at the same cycle); on smooth inputs it
costs 0.3-0.8 s (800-2,600 vertices) instead of 1.1-4.4 s."""


CONVEXITY_DENSE_MAX = 4000
"""Curves whose step has at most this many free unknowns in X get :func:`convexity_limit` from the dense reduced
Hessian (one product per unknown and one generalised eigenproblem): a curve's spectrum is wide and its lowest modes
come in pairs on symmetric shapes, where the Lanczos iteration did not converge even in 100 restarts and the first
step then failed. Measured (one thread): a smooth 5-fold wobbly ellipse with a tip of radius 0.05 (tau_c = tau /
11,121 at 400 vertices, tau / 3,169 at 1,500, the same tau_c ~ 9.3e-6 at every resolution: the tip's time scale)
0.12 s at 800 unknowns, 0.68 s at 1,600, 4.1 s at 3,000 (Lanczos: no convergence in 81-661 products); its first
step had failed all 18 attempts (IPOPT and newton-krylov down to tau / 256) on 400, 800 and 1,500 vertices."""


def convexity_dense(problem: StepProblem, dense: bool = False) -> bool:
    """Whether :func:`convexity_limit` (with ``dense``) of ``problem``'s step uses the dense eigenproblem, whose
    tau_c is exact: a curve, or ``dense``, with at most :data:`CONVEXITY_DENSE_MAX` free unknowns in X."""
    return (dense or problem.simplices.shape[1] == 2) and problem.nX * problem.m <= CONVEXITY_DENSE_MAX


def convexity_limit(evaluator: StepEvaluator, z0: np.ndarray, p: np.ndarray, restarts: int = CONVEXITY_RESTARTS,
                    solver: ReducedSolver | None = None, dense: bool = False) -> float:
    """The step size below which the step problem is convex at its start: tau_c with the reduced Hessian
    D + tau R of W^ at X^k positive definite for every tau < tau_c.

    W^(X) = (distance) + tau W(X, Y[X]) with Y[X] independent of tau, so the reduced Hessian at X^k is D + tau R
    with D (the distance part's Hessian, SPD) and R independent of tau. With lambda the smallest eigenvalue of
    (D + tau R) v = lambda D v at the tau of ``p`` (Lanczos, at most ``restarts`` restarts), tau_c = tau / (1 -
    lambda) when lambda < 1. A strongly negative mode is what it is for: inf when lambda >= 1 (R has no negative
    mode). With outer constraints it is the limit of the step problem without them (their multipliers 0, IPOPT's
    start): a lower bound of the constrained one at X^k, whose reduced Hessian is this one on the constraints'
    tangent space (its smallest eigenvalue is not below this one's). trimesh's box subdivided 3 times (386 v) with V
    and A fixed has tau_c = tau / 4,287; IPOPT failed its first step at every tau from tau to tau / 256 (its iterates
    collapse triangles: smallest angle 45 -> 0.4 deg in 11 iterations) and takes it at tau / 8,192 in 5 iterations.
    nan when the Lanczos iteration does not converge in its restarts (the clustered low end of a smooth
    surface's spectrum, read as no strongly negative mode; on smooth meshes it may converge to a weak mode instead:
    tau / 4.7 and tau / 6.8 on the tests' 162-vertex ellipsoid and 16x8 torus with tangential weight 1). The
    iteration is deterministic: where it converges within fewer restarts, more give the same value. Curves of at most
    :data:`CONVEXITY_DENSE_MAX` unknowns: the dense eigenproblem instead (always found; ``restarts`` unused).

    Parameters
    ----------
    evaluator : StepEvaluator
    z0 : (nx,) the start (X^k, Y[X^k]) of the step
    p : (np,) its parameters (X^k and tau among them)
    restarts : int
        Lanczos restarts (ARPACK's ``maxiter``), :data:`CONVEXITY_RESTARTS` or :data:`CONVEXITY_FIRST_RESTARTS`
    dense : bool
        The dense eigenproblem for surfaces too, up to :data:`CONVEXITY_DENSE_MAX` unknowns (exact: the Lanczos
        value is a Ritz value, never below the smallest eigenvalue, so its tau_c is never below the true one, and
        from its deterministic start it can miss the lowest mode of a symmetric surface: the torus problem at tau =
        5.9 with tangential weight 1, 864 unknowns, Lanczos tau / 152, dense tau / 421 as a finite-difference reduced
        Hessian gives; 0.45 s against 0.04 s; a fixed-step flow's error names it: ``WillmoreFlow._fixed_step_hint``)
    solver : ReducedSolver, optional
        A reduced solver of ``evaluator`` whose factorisations of J_Y serve Y[X], the adjoint and the products (the
        flow's newton-krylov: a Cholesky factor of J_Y's N x N block; default: a ``newton`` solver, a sparse LU of
        the 3N x 3N J_Y). Measured at 39,891 vertices (two cycles, 81 products): 9.5 s with newton-krylov's factors,
        16.3 s with the default (34-36 s when D was factorised by a sparse LU as well). D is factorised by Cholesky
        with the evaluator's backend (newton-krylov's ``cholesky`` option; "auto" otherwise).

    Returns
    -------
    float
        tau_c > 0, inf or nan.
    """
    P = evaluator.problem
    red = ReducedSolver(evaluator, ReducedSettings(), "newton") if solver is None else solver
    x0 = np.asarray(z0[: red.nxm], float)
    pt = red._at(x0, p, P.unpack_z(z0, P.params.xk(p))[1])
    if P.nh:  # the adjoint alone, the outer constraints' multipliers 0
        red._with_multipliers(pt, np.zeros(P.nh))
    D = red._distance_hessian(pt.z, p)
    pt.H = evaluator.hess_lag_operator(pt.z, p, 1.0, pt.lam)
    n = x0.size
    if convexity_dense(P, dense):
        Hd = np.column_stack([red._hessp(pt, p, e) for e in np.eye(n)])
        smallest = float(la.eigh(0.5 * (Hd + Hd.T), D.toarray(), eigvals_only=True, subset_by_index=[0, 0])[0])
    else:
        hess = spla.LinearOperator((n, n), matvec=lambda v: red._hessp(pt, p, np.ravel(v)), dtype=float)
        chol = SymmetricFactor(evaluator.cholesky or "auto").factor(D)  # (the user's backend where newton-krylov's)
        dinv = spla.LinearOperator((n, n), matvec=lambda v: chol.solve(np.ravel(v)), dtype=float)
        # a deterministic start (ARPACK's own random one depends on the calls before): the gradient, which is largest
        # where the energy concentrates. A seeded random part (0.1 or 1 times its largest entry) was measured
        # (2026-12-02) and not kept: it finds the symmetric torus's lowest mode (tau / 420, dense 420.5; the gradient
        # start: 152) but leaves the first look unconverged on a noisy trimesh torus (tau / 2,066 found by the gradient
        # start) and the full look on a smooth 1:1:2 ellipsoid of 642 v (tau / 18.3, dense 18.3) and a trimesh torus
        # (4.2, dense 6.3); the dense look took 1-5.6 s at 288-642 v there (the Lanczos looks 0.1-0.7 s)
        v0 = pt.grad + 1e-3 * max(float(np.abs(pt.grad).max()), 1e-300)
        try:
            lam = spla.eigsh(hess, k=1, M=D, Minv=dinv, which="SA", tol=0.1, ncv=min(40, n - 1),
                             maxiter=restarts, v0=v0, return_eigenvectors=False)
        except spla.ArpackNoConvergence:
            return float("nan")
        smallest = float(lam[0])
    tau = P.params.scalar(p, "tau")
    return tau / (1.0 - smallest) if smallest < 1.0 else float("inf")


SPECTRUM_DENSE_MAX = 400
"""Largest count of free nodes whose :func:`normal_spectrum` is dense (above: ``lobpcg`` and preconditioned CG).
Measured (one thread, states near rest, the lowest eigenvalue): trimesh tori of 390 / 527 / 617 / 1,101 vertices
0.108 / 0.19 / 0.26 / 0.96 s dense, 0.083 / 0.097 / 0.14 / 0.19 s iterative (the same eigenvalues to 1e-6); a 642-vertex
vesicle with V and A fixed 0.29 / 0.25 s; six on the 162-vertex sphere 0.03 / 0.06 s, on a 2,562-vertex
vesicle 6.9 / 2.6 s. The dense one cannot fail to converge (a state far from rest can make lobpcg fail); until
2026-11-30 (night) it ran up to 1,500 free nodes, where a relaxed torus of 1,434 vertices spent 3.6 s of its last
step in it."""
SPECTRUM_BLOCK = 6
"""Vectors :func:`normal_spectrum`'s ``lobpcg`` iterates beyond the ``count`` asked for (a round sphere's lowest
eigenvalue has multiplicity 5)."""
SPECTRUM_RETRY_BLOCK = 2 * SPECTRUM_BLOCK + 1
"""The vectors beyond ``count`` of :func:`normal_spectrum`'s second try, when ``lobpcg`` did not converge at any shift
with :data:`SPECTRUM_BLOCK`. Measured (2026-12-02): a new user's genus-3 surface at rest (3,942 vertices, marching
cubes) failed its relaxation's test with 1 + 6 vectors, the lowest residual stalled at 1.86 times the tolerance at every
shift (14 s), where 1 + 7, 1 + 9 and 1 + 12 converged in 4-7 s to the dense eigenvalue 8.7075 (a block whose edge
splits a cluster of eigenvalues converges slowly)."""
SPECTRUM_RTOL = 1e-4
"""``lobpcg``'s tolerance on the residual r = Pi^T (R - mu M_n) phi of its M_n-unit eigenvectors, in the norm of M_n^-1
(a bound on the eigenvalue's error) relative to a round sphere's lowest eigenvalue 24 / L^4; the eigenvalues' error
is of the residual's square over the spectral gap. Tighter ones are below what the products resolve on fine meshes:
the residuals stalled at 5e-8 of that unit at 2,562 vertices and at 7e-7 at 10,242, then the iteration broke down."""
SPECTRUM_SHIFTS = (30.0, 300.0, 3000.0)
"""Shifts (times 1 / L^4) of :func:`normal_spectrum`'s preconditioner tried in turn (:func:`_spectrum_iterative`)."""
SPECTRUM_MAX_ITER = 200
"""Iterations of ``lobpcg`` (per shift) and of the Newton step's CG in :func:`normal_spectrum` (converged: 40-130;
a raw noisy 10,242-vertex ellipsoid, far from rest, failed after 3 x 500 in 210 s)."""
SPECTRUM_CHUNK = 20
"""``lobpcg`` iterations between two tests of the wanted eigenpairs' residuals in :func:`normal_spectrum`."""


def normal_spectrum(evaluator: StepEvaluator, z0: np.ndarray, p: np.ndarray, normals: np.ndarray,
                    fields: np.ndarray | None = None, count: int = 2, solver: ReducedSolver | None = None,
                    method: str = "auto") -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The lowest eigenvalues and modes of the energy's Hessian on normal motions of the free nodes at a state, and
    how far the energy is above the minimum of its quadratic model there.

    At the state X = X^k of ``z0`` the reduced Hessian of the step's objective is D + tau R (:func:`convexity_limit`),
    R the Hessian of 2 e(X), e the scheme's energy, with the outer constraints' multipliers of the least-squares fit of
    its gradient's normal part (at an equilibrium, the constraints' pressure and tension). Restricted to normal
    motions v = phi n (the tangential ones only move nodes within the surface: the discrete energy has negative modes
    there, the mesh's own instability, which is not the surface's), on the tangent space of the outer constraints and
    M-orthogonal to the normal parts of ``fields`` (a closed surface's rigid motions, the symmetries of its energy),
    the eigenvalues mu of R phi = mu D phi are those of the L^2 Hessian of e (D = 2 M, M the mass matrix of the
    distance term): negative at a saddle, whose mode lowers the energy at second order. On the unit sphere mu tends
    to (l - 1) l (l + 1) (l + 2), l >= 2, the Willmore operator's (tested: 24 at l = 2, at order 2 in h).

    ``method="dense"``: one Hessian-vector product per free node and one generalised eigenproblem of that size (0.4
    s at 534 vertices, 13 s at 2,562, 119 s at 5,000). ``"iterative"``: matrix-free, scipy's ``lobpcg`` on the
    constraints' tangent space (its ``Y``) preconditioned by the Cholesky factor of the normal part of the Gauss-Newton
    matrix plus M (:meth:`ReducedSolver._gauss_newton`: R's leading part), and the Newton step by CG with the same
    preconditioner (the same numbers as dense to the tolerances; tested). ``"auto"``: dense up to
    :data:`SPECTRUM_DENSE_MAX` free nodes, iterative for ``count = 0`` (the gap and the Newton step alone: CG, whose
    step is taken where it converges to a descent direction of positive curvature, else nan). A ``count`` of over a
    fifth of the motions is dense either way (lobpcg's block would be). The eigenvalues are the scheme's at its
    tau_tilde: the round sphere's 24.53 / 24.13 / 24.03 at 642 / 2,562 / 10,242 vertices are at tau_tilde = h^2 / 100
    (the defaults); at h^2 / 10 23.15 / 23.79 / 23.95, at h^2 / 1000 24.67 / 24.17 (a new user's check).

    Parameters
    ----------
    evaluator : StepEvaluator
    z0 : (nx,) the state (X, Y[X])
    p : (np,) parameters of a step from X (X^k = X)
    normals : (nX, m) unit normals of the free nodes (the X variables' order)
    fields : (nX, k) normal components of motions to leave out (their span, directions whose singular value is
        below 1e-2 of the largest dropped: on a sphere the rotations' normal parts vanish), or None
    count : how many of the lowest eigenvalues
    solver : ReducedSolver, optional
        A reduced solver of ``evaluator`` whose factorisations of J_Y serve the products (default: ``newton``'s
        sparse LU)
    method : "auto", "dense" or "iterative"

    Returns
    -------
    mu : (count,) ascending eigenvalues
    modes : (nX, count) the normal displacements phi of their modes, each scaled to max |phi| = 1
    gap : e(X) minus the minimum of e's quadratic model on these motions (the Newton decrement; energy units): how
        far a state at rest on normal motions is from their minimum; nan when the lowest eigenvalue is not positive
    newton : (nX,) the normal displacement of the Newton step to that minimum (nan where there is none)
    """
    P = evaluator.problem
    red = ReducedSolver(evaluator, ReducedSettings(), "newton") if solver is None else solver
    x0 = np.asarray(z0[: red.nxm], float)
    pt = red._at(x0, p, P.unpack_z(z0, P.params.xk(p))[1])
    nX, m = normals.shape
    Nm = sp.csr_matrix((np.ravel(normals), (np.arange(nX * m), np.repeat(np.arange(nX), m))), shape=(nX * m, nX))
    D = red._distance_hessian(pt.z, p)
    rows = [np.asarray(pt.C) @ Nm] if P.nh else []  # (the constraints' rows on normal motions)
    gn = Nm.T @ pt.grad  # (the objective's gradient on normal motions)
    if P.nh:  # the multipliers that fit the gradient's normal part (its tangential part, O(1) on a discrete sphere,
        # is the mesh's: fitted too it gave a round sphere's volume a pressure 0.55 and its modes +0.55)
        # (columns of norm 1 and directions below 3e-2 of the largest dropped: on a sphere the volume's and the area's
        # gradients are parallel, singular values 1.5e-2 / 7.7e-3 of the largest at 162 / 642 v, and the exact fit gave
        # them multipliers of +-1e4 and the sphere an eigenvalue of -56,605; a vesicle of v = 0.99: 5e-2, 0.85: 0.16)
        w = 1.0 / D.diagonal()[::m] ** 0.5
        cols = np.linalg.norm(rows[0] * w, axis=1)
        red._with_multipliers(pt, -np.linalg.lstsq((rows[0] * w).T / cols, gn * w, rcond=3e-2)[0] / cols)
    pt.H = evaluator.hess_lag_operator(pt.z, p, 1.0, pt.lam)
    Mn = (Nm.T @ (D @ Nm)).tocsc()
    tau = P.params.scalar(p, "tau")
    if fields is not None and fields.size:  # (their span: directions below 1e-2 of the largest are no field's)
        U, s, _ = np.linalg.svd(fields, full_matrices=False)
        rows.append(U[:, s > 1e-2 * s[0]].T @ Mn)
    # (each row scaled to norm 1: the rank decision must not depend on the units of its constraint)
    A = np.vstack(rows) if rows else np.zeros((0, nX))
    A = A / np.linalg.norm(A, axis=1, keepdims=True)

    def hess(phi: np.ndarray) -> np.ndarray:  # R phi
        return (Nm.T @ red._hessp(pt, p, Nm @ phi) - Mn @ phi) / tau

    if method not in ("auto", "dense", "iterative"):
        raise ValueError(f"normal_spectrum: method {method!r}")
    dense = method == "dense" or (method == "auto" and count > 0 and nX <= SPECTRUM_DENSE_MAX)
    # (lobpcg solves a block of over a fifth of the motions densely, which refuses constraints: a new user's
    # count = 28 on 162 vertices raised scipy's NotImplementedError)
    if dense or (count and 5 * (count + SPECTRUM_BLOCK) > nX - len(A)):
        Rn = np.column_stack([hess(e) for e in np.eye(nX)])
        Rn = 0.5 * (Rn + Rn.T)
        Z = la.null_space(A, rcond=1e-8) if len(A) else np.eye(nX)
        RZ = Z.T @ Rn @ Z
        mu, V = la.eigh(RZ, Z.T @ Mn.toarray() @ Z, subset_by_index=[0, min(max(count, 1), Z.shape[1]) - 1])
        # the Newton decrement of e on these motions: e(X) - min of its quadratic model, g^T R^-1 g / (4 tau^2) with g
        # the projected gradient of the objective (2 tau grad e at X^k; Z is orthogonal to the constraints' rows, so
        # their multipliers' part of the gradient drops out); nan where the model has no minimum
        g = Z.T @ gn
        step = Z @ -la.solve(RZ, g, assume_a="sym") if mu[0] > 0 else np.full(nX, np.nan)
        mu, modes = mu[:count], Z @ V[:, :count]  # (count = 0: the lowest only told whether there is a minimum)
    else:
        mu, modes, step = _spectrum_iterative(red, pt, p, Nm, Mn, A, hess, gn, count)
    gap = -float(gn @ step) / (4 * tau * tau) if np.all(np.isfinite(step)) else float("nan")
    return mu, modes / np.abs(modes).max(axis=0) if count else modes, gap, step / tau


def _spectrum_iterative(red: ReducedSolver, pt: _Point, p: np.ndarray, Nm: sp.csr_matrix, Mn: sp.csc_matrix,
                        A: np.ndarray, hess: Any, gn: np.ndarray,
                        count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`normal_spectrum` without dense matrices: (mu, modes, Newton step of R (times tau)).

    On the motions with A phi = 0, i.e. M_n-orthogonal to Y = M_n^-1 A^T (an M_n-orthonormal basis of their span,
    directions below 1e-8 of the largest dropped as the dense path's null space does), ``lobpcg`` iterates on Pi^T R Pi
    (Pi = I - Y Y^T M_n; with R itself scipy's constraints ``Y``, which must span an invariant subspace, left the
    residuals at 0.7 on an ellipsoid) preconditioned by the Cholesky factor of T = N^T G N + s M_n (G the Gauss-Newton
    matrix, :meth:`ReducedSolver._gauss_newton`). The shift s must lie above the negative eigenvalues of a saddle
    (with s = 50 / L^4 the iteration broke down on an ellipsoid 1:1:1.5 with V and A fixed, eigenvalue -16 / L^4):
    :data:`SPECTRUM_SHIFTS` are tried in turn until the ``count`` lowest residuals meet the tolerance. The Newton
    step solves Pi^T R Pi x = -Pi^T g by CG preconditioned with Pi T^-1 Pi^T.

    Raises
    ------
    ArithmeticError
        when the eigenvalue iteration (at every shift) or, at a minimum, the Newton step's CG does not converge (``count
        = 0``: the step is nan instead)
    """
    nX = Mn.shape[0]
    Y = SymmetricFactor("auto").factor(Mn).solve(np.ascontiguousarray(A.T)) if len(A) else np.zeros((nX, 0))
    if Y.shape[1]:
        w, V = np.linalg.eigh(Y.T @ (Mn @ Y))
        keep = w > 1e-16 * w.max()
        Y = Y @ (V[:, keep] / np.sqrt(w[keep]))

    def project(v: np.ndarray) -> np.ndarray:  # Pi v
        return v - Y @ (Y.T @ (Mn @ v))

    def project_t(v: np.ndarray) -> np.ndarray:  # Pi^T v
        return v - Mn @ (Y @ (Y.T @ v))

    def hess_t(v: np.ndarray) -> np.ndarray:  # Pi^T R Pi v
        return project_t(hess(project(v)))

    def operator(f: Any) -> spla.LinearOperator:
        return spla.LinearOperator((nX, nX), matvec=lambda v: f(np.ravel(v)), dtype=float,
                                   matmat=lambda V: np.column_stack([f(v) for v in np.asarray(V).reshape(nX, -1).T]))

    G = (Nm.T @ red._gauss_newton(pt, p) @ Nm).tocsc()
    ones = np.ones(nX)
    unit = 1.0 / (float(ones @ (Mn @ ones)) / (8 * np.pi)) ** 2  # 1 / L^4 (D = 2 M: 1.D.1 = 2 area)
    T = SymmetricFactor("auto")

    def newton_cg() -> tuple[np.ndarray, int]:  # Pi^T R Pi x = -Pi^T g, preconditioned by Pi T^-1 Pi^T
        # (to 1e-8 of the right-hand side, or to the residual of a uniform step error of 1e-12 L (L = unit^-1/4): at
        # rest the right-hand side is round-off, 1e-19 of the energy on a polished ellipsoid, and CG cannot reduce it)
        atol = 1e-12 * 24 * unit * unit**-0.25 * float(np.linalg.norm(Mn @ ones))
        return spla.cg(operator(hess_t), project_t(-gn), rtol=1e-8, atol=atol, maxiter=SPECTRUM_MAX_ITER,
                       M=operator(lambda v: project(T.solve(project_t(v)))))

    if not count:  # the Newton step alone: CG, and a minimum where it converges to a descent of positive curvature
        T.factor((G + SPECTRUM_SHIFTS[0] * unit * Mn).tocsc())
        x, info = newton_cg()
        ok = not info and float(gn @ x) < 0 and float(x @ hess_t(x)) > 0
        return np.zeros(0), np.zeros((nX, 0)), project(x) if ok else np.full(nX, np.nan)
    tol = SPECTRUM_RTOL * 24 * unit * float(np.sqrt(Mn.diagonal().mean()))  # (lobpcg's 2-norm of r)

    def residuals(mu: np.ndarray, V: np.ndarray) -> np.ndarray:  # lobpcg's 2-norms of the wanted pairs' residuals
        return np.array([np.linalg.norm(hess_t(v) - m * (Mn @ v)) for m, v in zip(mu, V.T, strict=True)])

    for extra, shift in itertools.product((SPECTRUM_BLOCK, SPECTRUM_RETRY_BLOCK), SPECTRUM_SHIFTS):
        k = min(count + extra, nX - Y.shape[1])
        T.factor((G + shift * unit * Mn).tocsc())
        V, done, res = project(np.random.default_rng(0).standard_normal((nX, k))), 0, np.full(count, np.inf)
        while done < SPECTRUM_MAX_ITER and not np.all(res <= tol):
            # in chunks from the last Ritz vectors: lobpcg stops when the whole block has converged, and the vectors
            # beyond ``count`` (higher eigenvalues, whose residuals stall higher) took 200 iterations at 40,962
            # vertices where the wanted ones had converged in 70
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # (breakdown or not converged: judged by the residuals)
                mu, V = spla.lobpcg(operator(hess_t), V, B=Mn, M=operator(T.solve), Y=Y if Y.shape[1] else None,
                                    tol=tol, maxiter=SPECTRUM_CHUNK, largest=False)
            done += SPECTRUM_CHUNK
            order = np.argsort(mu)
            mu, V = mu[order], V[:, order]
            if not np.all(np.isfinite(V)):
                break
            res = residuals(mu[:count], V[:, :count])
        if np.all(res <= tol):
            break
    else:
        raise ArithmeticError(f"normal_spectrum: lobpcg did not converge in {SPECTRUM_MAX_ITER} iterations at each "
                              f"preconditioner shift, with {count} + {SPECTRUM_BLOCK} and {count} + "
                              f"{SPECTRUM_RETRY_BLOCK} vectors (the lowest eigenpairs' last residuals "
                              f"{np.min(res / tol):.3g} to {np.max(res / tol):.3g} times the tolerance; is the state "
                              "at rest?)")
    mu, V = mu[:count], V[:, :count]
    if not mu[0] > 0:
        return mu, V, np.full(nX, np.nan)
    x, info = newton_cg()
    if info:
        raise ArithmeticError(f"normal_spectrum: the Newton step's CG did not converge in {info} iterations")
    return mu, V, project(x)
