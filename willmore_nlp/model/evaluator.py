"""Numeric evaluation of an assembled step problem: values, sparse derivatives, Y[X]."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.model.step import ELEMENT_BLOCK, GlobalFunctions, Pattern, StepProblem


def to_scipy(M: ca.DM) -> sp.csc_matrix:
    """CasADi sparse DM -> scipy CSC without densifying."""
    spy = M.sparsity()
    colind = np.asarray(spy.colind(), dtype=np.int64)
    row = np.asarray(spy.row(), dtype=np.int64)
    data = np.asarray(M.nonzeros(), dtype=float)
    return sp.csc_matrix((data, row, colind), shape=M.shape)


_MATRIX_OUTPUT = {"k_jac": (1, "jac_pattern"), "k_hjac": (1, "hjac_pattern"), "k_hess": (0, "hess_pattern")}
"""Kernel -> (output, pattern attribute of the StepProblem) of the one output that is a sparse matrix's entries."""


class StepEvaluator:
    """Numpy-facing evaluation of the global functions of a :class:`StepProblem`.

    Values and derivatives are assembled in numpy from the element kernels: the element inputs are
    gathered with the problem's index maps, the kernel mapped over blocks of elements runs once per
    block (compiled C or CasADi's virtual machine), and its element outputs are summed into the global vector or the
    nonzeros of the global sparse matrix by ``np.bincount`` over the element-entry map (the same sums,
    in the same order, as the scatter-add of the MX functions). The MX functions of ``functions``
    (for ``nlpsol``) are built only when a solver asks for them: the reduced solvers never do.

    Parameters
    ----------
    problem : StepProblem
    functions : GlobalFunctions
        The output of :meth:`StepProblem.functions` (symbolic or compiled kernels); its kernels are the
        ones evaluated here.
    maps : dict, optional
        The kernels mapped over element blocks, by kernel name and block size: a cache that the evaluators of one
        flow share across its rebuilds (the same kernels on a new connectivity), where CasADi's map costs about 4 ms
        per kernel and block size (0.03 s of every rebuild after Delaunay flips at 2,562 vertices). An entry serves
        only the kernel object it was made from.
    """

    def __init__(self, problem: StepProblem, functions: GlobalFunctions,
                 maps: dict[tuple[str, bool], tuple[ca.Function, int, ca.Function]] | None = None) -> None:
        self.problem = problem
        self.fn = functions
        self.kernels = functions.kernels
        self._maps = {} if maps is None else maps
        self._buffers: dict[str, tuple[Any, ...]] = {}
        self._xe = np.zeros(problem.gather.size)  # the element inputs, shared by every kernel's buffer
        self.cholesky: str | None = None  # backend of the inner solves' Cholesky (:meth:`linear_solve`); None: LU
        self._emaps: dict[str, np.ndarray] = {}
        self._sym: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # full pattern, source in the upper

    def _mapped(self, name: str, f: ca.Function, n: int) -> ca.Function:
        """``f`` mapped over ``n`` elements, from the shared cache when it holds that map of this very kernel (two
        entries per kernel: the full block and the last remainder, so that remeshings do not grow it)."""
        key = (name, n == ELEMENT_BLOCK)
        hit = self._maps.get(key)
        if hit is None or hit[0] is not f or hit[1] != n:
            hit = self._maps[key] = (f, n, f.map(n))
        return hit[2]

    def _kernel(self, name: str, z: np.ndarray, p: np.ndarray, *rest: Any) -> list[np.ndarray]:
        """Nonzeros of every output of kernel ``name`` mapped over the elements (element-major order) at ``z``.

        The element inputs are gathered from ``z`` and ``p`` (:meth:`_elements`) into the buffer all kernels
        share; ``p`` is the parameter vector, whose scalar block all elements share (copied to each); ``rest``
        are the Hessian kernel's multiplier inputs: ``lf`` (shared), ``lg`` ((K, nl), per element) and ``lh``
        (shared). Uses CasADi's function buffers (inputs and outputs bound once to numpy arrays): no
        conversion of inputs to DM nor of outputs to Python lists. Structural zeros of an output (AD knows
        some entries vanish) are not stored: :meth:`_dense`, :meth:`_sum` place the nonzeros. The matrix
        output of a kernel (:data:`_MATRIX_OUTPUT`) is returned assembled, as the nonzeros of its pattern: it
        is summed block by block, so that its element values (K x 144 at 40,962 vertices for the Hessian,
        94 MB) are never held.
        """
        P = self.problem
        if name not in self._buffers:
            f = self.kernels[name]
            mat, pattern = _MATRIX_OUTPUT.get(name, (-1, ""))
            ins = [self._xe] + [np.zeros(P.K * f.sparsity_in(i).nnz()) for i in range(1, f.n_in())]
            outs = [np.zeros((min(ELEMENT_BLOCK, P.K) if i == mat else P.K) * f.sparsity_out(i).nnz())
                    for i in range(f.n_out())]
            runs = []
            for start in range(0, P.K, ELEMENT_BLOCK):  # the map in element blocks: a map over all K elements
                n = min(ELEMENT_BLOCK, P.K - start)  # kept sparsities of K x (entries) int64 in CasADi (0.3 GB
                buf, run = self._mapped(name, f, n).buffer()  # at 40,962 vertices); the values are the same
                for i, a in enumerate(ins):
                    w = f.sparsity_in(i).nnz()
                    buf.set_arg(i, memoryview(a)[start * w : (start + n) * w])
                for i, a in enumerate(outs):
                    w = f.sparsity_out(i).nnz()
                    at = 0 if i == mat else start  # the matrix output: the block's values, assembled at once
                    buf.set_res(i, memoryview(a)[at * w : (at + n) * w])
                runs.append((start, n, buf, run))  # (the buffer must outlive its run)
            self._buffers[name] = (runs, ins, outs, mat, pattern)
        runs, ins, outs, mat, pattern = self._buffers[name]
        self._elements(z, p)
        for i, (a, v) in enumerate(zip(ins[1:], (P.params.scalar_block(p), *rest), strict=True), start=1):
            v = np.asarray(v, float)
            if i == 3:  # lg, per element
                a[:] = v.ravel()
            else:  # an input all elements share
                a.reshape(P.K, -1)[:] = v.ravel()
        if mat >= 0:
            emap = getattr(P, pattern).emap
            data = np.zeros(getattr(P, pattern).nnz + 1)  # the last entry takes the dropped element entries
        for start, n, _, run in runs:
            if run():
                raise RuntimeError(f"evaluation of the element kernel {name} failed")
            if mat >= 0:  # in element order, as one bincount over all elements would add (bitwise the same sums)
                block = emap[start : start + n].ravel()
                np.add.at(data, block, outs[mat][: block.size])
        return [data[:-1] if i == mat else a for i, a in enumerate(outs)]

    def _positions(self, name: str, i: int) -> np.ndarray | None:
        """Dense element-major position of each nonzero of output ``i`` of kernel ``name`` (None: dense output).
        Computed when asked (only the vector outputs need it: the matrices go through their patterns, and the
        positions of the Hessian's and Jacobian's nonzeros were 160 MB at 40,962 vertices)."""
        spy = self.kernels[name].sparsity_out(i)
        if spy.is_dense():
            return None
        return (np.arange(self.problem.K)[:, None] * spy.numel() + np.asarray(spy.find(), np.int64)).ravel()

    def _dense(self, name: str, i: int, values: np.ndarray) -> np.ndarray:
        """(K, width) output ``i`` of kernel ``name`` from its nonzeros ``values``."""
        pos = self._positions(name, i)
        if pos is None:
            return values.reshape(self.problem.K, -1)
        out = np.zeros(self.kernels[name].sparsity_out(i).numel() * self.problem.K)
        out[pos] = values
        return out.reshape(self.problem.K, -1)

    def _sum(self, name: str, i: int, values: np.ndarray, emap: np.ndarray, n: int) -> np.ndarray:
        """(n,) sums of the element entries of a vector (nonzeros ``values`` of output ``i`` of kernel ``name``,
        whose entries go to ``emap`` ((K, width); n = dropped)): the scatter-add of the assembly."""
        key = f"{name}:{i}"
        if key not in self._emaps:
            pos = self._positions(name, i)
            self._emaps[key] = emap.ravel() if pos is None else emap.ravel()[pos]
        return np.bincount(self._emaps[key], weights=values, minlength=n + 1)[:n]

    @staticmethod
    def _matrix(data: np.ndarray, pattern: Pattern) -> sp.csc_matrix:
        """Sparse matrix of ``pattern`` with the nonzeros ``data`` (an assembled kernel output)."""
        return sp.csc_matrix((data, pattern.row, pattern.colind), shape=pattern.shape)

    def _elements(self, z: np.ndarray, p: np.ndarray) -> None:
        """Gather the (K, nin) element inputs [X_T, Y_T, Xk_T, Q_T, c_T] from [z; p; consts] into the input
        buffer all kernels share (one (K, nin) array instead of one per kernel and a temporary)."""
        P = self.problem
        v = np.concatenate([np.asarray(z, float).ravel(), np.asarray(p, float).ravel(), P.const_values.ravel()])
        np.take(v, P.gather, out=self._xe.reshape(P.gather.shape))

    def _vectors(self, g: np.ndarray, p: np.ndarray) -> np.ndarray:
        """g - tt b on the free-Y rows for every nodal vector b of the terms."""
        P = self.problem
        for name in P.params.vectors:
            g = g - P.params.scalar(p, "tt") * np.asarray(P.params.vector(p, name))[P._free_y_rows()]
        return g

    def _targets(self, p: np.ndarray) -> np.ndarray:
        P = self.problem
        return np.array([P.params.scalar(p, t) for t in P.targets])

    def f(self, z: np.ndarray, p: np.ndarray) -> float:
        """Objective W."""
        return float(self._kernel("k_f", z, p)[0].sum())

    def g(self, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(ng,) constraint residual g = 1/2 dE/dY."""
        P = self.problem
        return self._vectors(self._sum("k_g", 0, self._kernel("k_g", z, p)[0], P.g_map, P.ng), p)

    def h(self, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(nh,) outer constraint residual (empty without outer constraints)."""
        if not self.problem.nh:
            return np.zeros(0)
        hv = self._dense("k_h", 0, self._kernel("k_h", z, p)[0])
        return hv.sum(axis=0) - self._targets(p)

    def c_jac(self, z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, sp.csc_matrix]:
        """(nc,) all constraints c = [g; h] and their (nc, nx) Jacobian (IPOPT's and SQP's view)."""
        gv, J = self.g_jac(z, p)
        P = self.problem
        if not P.nh:
            return gv, J
        hv, hl = self._kernel("k_hjac", z, p)
        Jh = self._matrix(hl, P.hjac_pattern)
        hv = self._dense("k_hjac", 0, hv).sum(axis=0) - self._targets(p)
        return np.concatenate([gv, hv]), sp.vstack([J, Jh], format="csc")

    def f_grad(self, z: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray]:
        """W and its (nx,) gradient from one evaluation."""
        P = self.problem
        w, gl = self._kernel("k_grad", z, p)
        return float(w.sum()), self._sum("k_grad", 1, gl, P.grad_map, P.nx)

    def grad_f(self, z: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(nx,) gradient of W."""
        return self.f_grad(z, p)[1]

    def g_jac(self, z: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, sp.csc_matrix]:
        """(ng,) constraint residual and (ng, nx) Jacobian from one evaluation."""
        P = self.problem
        gl, jl = self._kernel("k_jac", z, p)
        return self._vectors(self._sum("k_jac", 0, gl, P.g_map, P.ng), p), self._matrix(jl, P.jac_pattern)

    def jac_g(self, z: np.ndarray, p: np.ndarray) -> sp.csc_matrix:
        """(ng, nx) constraint Jacobian."""
        return self.g_jac(z, p)[1]

    def _hess_data(self, z: np.ndarray, p: np.ndarray, lam_f: float, lam_g: np.ndarray) -> np.ndarray:
        """Nonzeros of the upper triangle of the Lagrangian Hessian (:meth:`hess_lag_upper`)."""
        P = self.problem
        lam = np.asarray(lam_g, float).ravel()
        LG = np.append(lam[: P.ng], 0.0)[P.g_map]  # 0 on dropped rows
        rest = [float(lam_f), LG] + ([lam[P.ng :]] if P.nh else [])
        return self._kernel("k_hess", z, p, *rest)[0]

    def hess_lag_upper(self, z: np.ndarray, p: np.ndarray, lam_f: float, lam_g: np.ndarray) -> sp.csc_matrix:
        """(nx, nx) upper triangle of the Hessian of lam_f W + lam_c . c; ``lam_c`` is (nc,) = [lam_g; lam_h]."""
        pat = self.problem.hess_pattern
        return sp.csc_matrix((self._hess_data(z, p, lam_f, lam_g), pat.row, pat.colind), shape=pat.shape)

    def hess_lag(self, z: np.ndarray, p: np.ndarray, lam_f: float, lam_g: np.ndarray) -> sp.csc_matrix:
        """(nx, nx) full symmetric Hessian of lam_f W + lam_c . c (see :meth:`hess_lag_upper`).

        Its pattern (the upper one mirrored) and the source of each of its nonzeros in the upper triangle
        are computed once, so that each call is one gather of the upper nonzeros.
        """
        if self._sym is None:
            pat = self.problem.hess_pattern
            U = sp.csc_matrix((np.arange(1, pat.nnz + 1, dtype=float), pat.row, pat.colind), shape=pat.shape)
            F = (U + sp.triu(U, 1).T).tocsc()
            F.sort_indices()
            self._sym = (F.indices, F.indptr, (F.data - 1).astype(np.int32 if pat.nnz < 2**31 else np.int64))
        indices, indptr, src = self._sym
        n = self.problem.nx
        return sp.csc_matrix((self._hess_data(z, p, lam_f, lam_g)[src], indices, indptr), shape=(n, n))

    def hess_lag_operator(self, z: np.ndarray, p: np.ndarray, lam_f: float,
                          lam_g: np.ndarray) -> spla.LinearOperator:
        """The (nx, nx) Hessian of :meth:`hess_lag` as an operator on its upper triangle U:
        ``H v = U v + U^T v - diag(U) v``: the same products (the same flops) with about half the nonzeros
        in memory and without the mirrored pattern that :meth:`hess_lag` keeps."""
        U = self.hess_lag_upper(z, p, lam_f, lam_g)
        Ut, d = U.T, U.diagonal()

        def matvec(v: np.ndarray) -> np.ndarray:
            v = np.ravel(v)
            return U @ v + Ut @ v - d * v

        return spla.LinearOperator(U.shape, matvec=matvec, rmatvec=matvec, dtype=float)

    def linear_solve(self, Jy: sp.csc_matrix, r: np.ndarray) -> np.ndarray:
        """J_Y^-1 r for the inner Jacobian J_Y ((ng, ng)): the default solver of :meth:`inner_solve`.

        With :attr:`cholesky` set (``newton-krylov`` sets it to its backend, a ``relax_newton`` flow to "auto") and a
        linear inner equation, J_Y = (M[X] + tt L[X]) (x) I_m in node-major order, so one sparse Cholesky
        (:mod:`willmore_nlp.solvers.cholesky`) of the N x N block serves the m coordinates: at 10,242
        vertices Y[X] took 0.11-0.14 s instead of 1.24 s, and the flow's construction peaked at 0.39 GB
        instead of 0.49 GB. Otherwise scipy's sparse LU of the whole J_Y, as before: IPOPT's iterates depend
        on the rounding of Y (the first step of the 64-gon ellipse of ``tests/test_tangential.py``, with a
        free tangential motion, took 75 iterations instead of 44 and ended in a clustered local minimum
        with the Cholesky Y and without the structural zeros in IPOPT's patterns).
        """
        if self.cholesky is None or self.problem.nonlinear_inner:
            return spla.spsolve(Jy, r)
        from willmore_nlp.solvers.cholesky import KronFactor, SymmetricFactor  # (the solvers import this module)

        m = self.problem.m
        return KronFactor(SymmetricFactor(self.cholesky).factor(Jy[0::m, 0::m]), m).solve(r)

    def solve_y(self, X: np.ndarray, p: np.ndarray, Y0: np.ndarray | None = None, tol: float = 1e-12,
                max_iter: int = 100, linear_solve: Callable[[sp.csc_matrix, np.ndarray], np.ndarray] | None = None
                ) -> np.ndarray:
        """Y[X]: solve the inner equation g(X, Y) = 0 for the free Y (:meth:`inner_solve`)."""
        return self.inner_solve(X, p, Y0, tol, max_iter, linear_solve, min_steps=0)[0]

    def inner_solve(self, X: np.ndarray, p: np.ndarray, Y0: np.ndarray | None = None, tol: float = 1e-12,
                    max_iter: int = 100, linear_solve: Callable[[sp.csc_matrix, np.ndarray], np.ndarray] | None = None,
                    min_steps: int | None = None) -> tuple[np.ndarray, np.ndarray, sp.csc_matrix]:
        """Solve the inner equation g(X, Y) = 0 (only g: the outer constraints h play no part) by damped Newton.

        One Newton step (plus a refinement if rounding asks) for a linear inner equation. For
        nonlinear inner energies g = 1/2 dE/dY is the gradient of a strictly convex energy, but a
        nearly non-smooth gamma (the regularised l1 norm ``gamma2``) makes plain Newton overshoot:
        steps are halved until the residual decreases (backtracking on |g|). Converged when
        ``|g|_inf <= tol |J_Y|_max |Y|_max`` (relative, so that a surface of any size is solved alike: with the
        former floor ``max(1, ...)`` a curve 4e-5 wide passed the test at Y0 = X, and its steps started
        from a gradient of exactly 0).

        Parameters
        ----------
        X : (N, m) full nodal positions
        p : parameter vector (its Xk block supplies the fixed nodes)
        Y0 : (N, m) initial guess, default X
        linear_solve : callable (J_Y, r) -> J_Y^-1 r, optional
            Solver of the Newton systems (default :meth:`linear_solve`); the ``newton-krylov`` step
            solver passes its own (which keeps the factorisation for its adjoints).
        min_steps : int, optional
            Newton steps taken (whole) even when Y0 already meets the tolerance. Default: one for a linear inner
            equation, where that step is exact, none for a nonlinear one (the reduced step solvers' evaluations of
            W^ use the default; :meth:`solve_y` takes none). The reduced solvers' trial points differ from the
            last point by steps so small near convergence that Y0 passed the test unchanged, and W^ at such a
            stale Y was off by up to 1e-7 of itself (a 10,242-vertex sphere:
            W^(X + 1e-10 d) - W^(X - 1e-10 d) = 7.6e-8 for a random d whose derivative predicts 2.5e-13).

        Returns
        -------
        Y : (N, m)
        z : (nx,) the unknowns (X, Y)
        J : (ng, nx) the inner Jacobian at z
        """
        P = self.problem
        if min_steps is None:
            min_steps = 0 if P.nonlinear_inner else 1
        m = P.m
        Xk = P.params.xk(p)
        Y = np.array(X if Y0 is None else Y0, float, copy=True)
        Y[~P.y_free] = Xk[~P.y_free]
        nXm = P.nX * m
        z = P.pack_z(X, Y)
        r, J = self.g_jac(z, p)
        for it in range(max_iter):
            Jy = J[:, nXm:]
            scale = max(float(np.abs(Jy).max()) * float(np.abs(Y).max()), np.finfo(float).tiny)
            if it >= min_steps and np.linalg.norm(r, np.inf) <= tol * scale:
                return Y, z, J
            dy = (linear_solve or self.linear_solve)(Jy.tocsc(), -r).reshape(-1, m)
            rn = np.linalg.norm(r)
            alpha = 1.0
            for _ in range(40):
                Yt = Y.copy()
                Yt[P.y_free] += alpha * dy
                zt = P.pack_z(X, Yt)
                rt, Jt = self.g_jac(zt, p)
                if np.linalg.norm(rt) < rn or alpha < 1e-9 or it < min_steps:  # (a forced step is taken whole)
                    break
                alpha *= 0.5
            Y, z, r, J = Yt, zt, rt, Jt
        raise RuntimeError(
            f"inner equation not solved to {tol:g} in {max_iter} Newton iterations "
            f"(residual {np.linalg.norm(r, np.inf):.3e})"
        )
