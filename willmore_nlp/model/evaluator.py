"""Numeric evaluation of an assembled step problem: values, sparse derivatives, Y[X]."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.model.step import StepProblem


def to_scipy(M: ca.DM) -> sp.csc_matrix:
    """CasADi sparse DM -> scipy CSC without densifying."""
    spy = M.sparsity()
    colind = np.asarray(spy.colind(), dtype=np.int64)
    row = np.asarray(spy.row(), dtype=np.int64)
    data = np.asarray(M.nonzeros(), dtype=float)
    return sp.csc_matrix((data, row, colind), shape=M.shape)


class StepEvaluator:
    """Numpy-facing evaluation of the global functions of a :class:`StepProblem`.

    Parameters
    ----------
    problem : StepProblem
    functions : dict
        The output of :meth:`StepProblem.functions` (symbolic or compiled kernels).
    """

    def __init__(self, problem: StepProblem, functions: dict[str, ca.Function]) -> None:
        self.problem = problem
        self.fn = functions
        self._buffers: dict[str, tuple[Any, ...]] = {}

    def _eval(self, name: str, *args: Any) -> list[np.ndarray]:
        """Nonzeros of every output of ``fn[name]`` at dense ``args`` (copies, one array per output).

        Uses CasADi's function buffers (inputs and outputs bound once to numpy arrays), which skips
        the conversion of inputs to DM and of outputs to Python lists: 5-10x less overhead than a
        plain call on the sparse Jacobian and Hessian (measured at 2,562 vertices).
        """
        f = self.fn[name]
        if name not in self._buffers:
            if not hasattr(f, "buffer"):  # CasADi without function buffers
                return [np.asarray(ca.DM(o).nonzeros(), float) for o in f.call(list(args))]
            buf, run = f.buffer()
            ins = [np.zeros(f.sparsity_in(i).nnz()) for i in range(f.n_in())]
            outs = [np.zeros(f.sparsity_out(i).nnz()) for i in range(f.n_out())]
            for i, a in enumerate(ins):
                buf.set_arg(i, memoryview(a))
            for i, a in enumerate(outs):
                buf.set_res(i, memoryview(a))
            self._buffers[name] = (buf, run, ins, outs)
        _, run, ins, outs = self._buffers[name]
        for a, v in zip(ins, args, strict=True):
            a[:] = np.asarray(v, float).ravel()
        if run():
            raise RuntimeError(f"evaluation of {name} failed")
        return [o.copy() for o in outs]

    def _sparse(self, name: str, i: int, data: np.ndarray) -> sp.csc_matrix:
        """Output ``i`` of ``fn[name]`` as scipy CSC from its nonzeros (pattern cached per function)."""
        key = f"{name}:{i}"
        if key not in self._buffers:
            spy = self.fn[name].sparsity_out(i)
            self._buffers[key] = (np.asarray(spy.row(), np.int64), np.asarray(spy.colind(), np.int64), spy.shape)
        row, colind, shape = self._buffers[key]
        return sp.csc_matrix((data, row, colind), shape=shape)

    def f(self, z: np.ndarray, p: np.ndarray) -> float:
        """Objective W."""
        return float(self._eval("f", z, p)[0][0])

    def g(self, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(ng,) constraint residual g = 1/2 dE/dY."""
        return self._eval("g", z, p)[0]

    def h(self, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(nh,) outer constraint residual (empty without outer constraints)."""
        if not self.problem.nh:
            return np.zeros(0)
        return self._eval("h", z, p)[0]

    def c_jac(self, z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, sp.csc_matrix]:
        """(nc,) all constraints c = [g; h] and their (nc, nx) Jacobian (IPOPT's and SQP's view)."""
        name = "jac_c" if self.problem.nh else "jac_g"
        cv, J = self._eval(name, z, p)
        return cv, self._sparse(name, 1, J)

    def f_grad(self, z: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray]:
        """W and its (nx,) gradient from one evaluation."""
        fv, gv = self._eval("grad_f", z, p)
        return float(fv[0]), gv

    def grad_f(self, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(nx,) gradient of W."""
        return self.f_grad(z, p)[1]

    def g_jac(self, z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, sp.csc_matrix]:
        """(ng,) constraint residual and (ng, nx) Jacobian from one evaluation."""
        gv, J = self._eval("jac_g", z, p)
        return gv, self._sparse("jac_g", 1, J)

    def jac_g(self, z: np.ndarray, p: np.ndarray) -> sp.csc_matrix:
        """(ng, nx) constraint Jacobian."""
        return self.g_jac(z, p)[1]

    def hess_lag_upper(self, z: np.ndarray, p: np.ndarray, lam_f: float, lam_g: np.ndarray) -> sp.csc_matrix:
        """(nx, nx) upper triangle of the Hessian of lam_f W + lam_c . c; ``lam_c`` is (nc,) = [lam_g; lam_h]."""
        return self._sparse("hess_lag", 0, self._eval("hess_lag", z, p, lam_f, lam_g)[0])

    def hess_lag(self, z: np.ndarray, p: np.ndarray, lam_f: float, lam_g: np.ndarray) -> sp.csc_matrix:
        """(nx, nx) full symmetric Hessian of lam_f W + lam_c . c (see :meth:`hess_lag_upper`)."""
        U = self.hess_lag_upper(z, p, lam_f, lam_g)
        return (U + sp.triu(U, 1).T).tocsc()

    def solve_y(self, X: np.ndarray, p: np.ndarray, Y0: np.ndarray | None = None, tol: float = 1e-12,
                max_iter: int = 100, linear_solve: Callable[[sp.csc_matrix, np.ndarray], np.ndarray] | None = None
                ) -> np.ndarray:
        """Y[X]: solve the inner equation g(X, Y) = 0 for the free Y (:meth:`inner_solve`)."""
        return self.inner_solve(X, p, Y0, tol, max_iter, linear_solve)[0]

    def inner_solve(self, X: np.ndarray, p: np.ndarray, Y0: np.ndarray | None = None, tol: float = 1e-12,
                    max_iter: int = 100, linear_solve: Callable[[sp.csc_matrix, np.ndarray], np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, sp.csc_matrix]:
        """Solve the inner equation g(X, Y) = 0 (only g: the outer constraints h play no part) by damped Newton.

        One Newton step (plus a refinement if rounding asks) for a linear inner equation. For
        nonlinear inner energies g = 1/2 dE/dY is the gradient of a strictly convex energy, but a
        nearly non-smooth gamma (the regularised l1 norm ``gamma2``) makes plain Newton overshoot:
        steps are halved until the residual decreases (backtracking on |g|). Converged when
        ``|g|_inf <= tol * max(1, |J_Y|_max |Y|_max)``.

        Parameters
        ----------
        X : (N, m) full nodal positions
        p : parameter vector (its Xk block supplies the fixed nodes)
        Y0 : (N, m) initial guess, default X
        linear_solve : callable (J_Y, r) -> J_Y^-1 r, optional
            Solver of the Newton systems (default scipy's sparse LU); the ``newton-krylov`` step
            solver passes its sparse Cholesky.

        Returns
        -------
        Y : (N, m)
        z : (nx,) the unknowns (X, Y)
        J : (ng, nx) the inner Jacobian at z
        """
        P = self.problem
        m = P.m
        Xk = P.params.xk(p)
        Y = np.array(X if Y0 is None else Y0, float, copy=True)
        Y[~P.y_free] = Xk[~P.y_free]
        nXm = P.nX * m
        z = P.pack_z(X, Y)
        r, J = self.g_jac(z, p)
        for _ in range(max_iter):
            Jy = J[:, nXm:]
            scale = max(1.0, float(np.abs(Jy).max()) * float(np.abs(Y).max()))
            if np.linalg.norm(r, np.inf) <= tol * scale:
                return Y, z, J
            dy = (spla.spsolve(Jy.tocsc(), -r) if linear_solve is None else linear_solve(Jy.tocsc(), -r)).reshape(-1, m)
            rn = np.linalg.norm(r)
            alpha = 1.0
            for _ in range(40):
                Yt = Y.copy()
                Yt[P.y_free] += alpha * dy
                zt = P.pack_z(X, Yt)
                rt, Jt = self.g_jac(zt, p)
                if np.linalg.norm(rt) < rn or alpha < 1e-9:
                    break
                alpha *= 0.5
            Y, z, r, J = Yt, zt, rt, Jt
        raise RuntimeError(
            f"inner equation not solved to {tol:g} in {max_iter} Newton iterations "
            f"(residual {np.linalg.norm(r, np.inf):.3e})"
        )
