"""Sparse Cholesky factorisation of symmetric positive definite matrices, with a scipy fallback.

The step solver ``newton-krylov`` factorises two kinds of SPD matrices many times on one topology:
the N x N matrix M[X] + tt L[X] (the isotropic J_Y = (M + tt L) (x) I_m) and the 3N x 3N
Gauss-Newton preconditioner (two-ring coupling).

Backends
--------
``cholmod``
    SuiteSparse's CHOLMOD through the registry wheel ``sksparse-minimal`` (a fork of ``cholespy``
    that bundles CHOLMOD built with METIS and LAPACK/BLAS, so that it factorises supernodally and
    tries METIS beside AMD; no system libraries). Each call orders and factorises (the binding has
    no numeric-only refactorisation). Measured on the preconditioner of the 10,242-vertex sphere
    (30,726 x 30,726, 1.75e6 nonzeros; one thread, quiet machine): 1.12 s against 2.01 s for
    ``cholespy`` (CHOLMOD simplicial with AMD only) and 0.99 s for MKL PARDISO (``pypardiso``,
    whose ``mkl`` wheels weigh 270 MB to download and 0.9 GB installed); at 2,562 vertices
    0.48 s / 0.65 s / 0.15 s. Solves with the supernodal factor run in the bundled reference BLAS
    and were slower than cholespy's (B above: 0.021 s / 0.015 s; M + tt L with three right-hand
    sides at 10,242 vertices: 2.3 ms / 0.6 ms), so the factor is converted to its simplicial form
    after each factorisation (``change_factor``, the cost of one or two solves): solves then took
    5.5 ms instead of 8.7 ms (B, 2,562 vertices) and 0.11 ms instead of 1.1 ms (M + tt L, 2,562).
    ``cholespy`` itself cannot be loaded in the same process (both register the same nanobind type).
``scipy``
    SuperLU (``scipy.sparse.linalg.splu``) with COLAMD ordering: used when ``sksparse-minimal`` is
    not installed, or when asked for.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.errors import UserInputError

try:
    from sksparse_minimal._cholespy_core import CholeskySolver as _Cholmod
except ImportError:  # pragma: no cover - the fallback itself is tested by forcing backend="scipy"
    _Cholmod = None

BACKENDS = ("auto", "cholmod", "scipy")


def resolve_backend(name: str) -> str:
    """The backend used for ``name`` (``"auto"``: cholmod when installed, else scipy)."""
    if name not in BACKENDS:
        raise UserInputError(f"option cholesky must be one of {', '.join(BACKENDS)}, got {name!r}")
    if name == "auto":
        return "cholmod" if _Cholmod is not None else "scipy"
    if name == "cholmod" and _Cholmod is None:
        raise UserInputError("option cholesky='cholmod' needs the package sksparse-minimal "
                             "(pip install sksparse-minimal)")
    return name


class SymmetricFactor:
    """Factorisation of a symmetric positive definite sparse matrix.

    Parameters
    ----------
    backend : {"auto", "cholmod", "scipy"}

    Attributes
    ----------
    n_numeric : number of factorisations done
    """

    def __init__(self, backend: str = "auto") -> None:
        self.backend = resolve_backend(backend)
        self._solver: Any = None
        self._n = 0
        self.n_numeric = 0

    def factor(self, A: sp.spmatrix) -> SymmetricFactor:
        """Factorise the SPD (n, n) matrix ``A`` (both triangles given); returns self."""
        A = sp.csc_matrix(A)
        self._n = A.shape[0]
        self._solver = None  # the previous factor goes first: never two alive (0.65 GB each for B at 40,962 vertices)
        if self.backend == "scipy":
            self._solver = spla.splu(A, permc_spec="COLAMD")
        else:
            A.sort_indices()
            self._solver = _Cholmod(self._n, A.indptr.astype(np.int32), A.indices.astype(np.int32),
                                    np.ascontiguousarray(A.data, dtype=float))
            # supernodal factorisation, simplicial LL' solves (module docstring): the conversion costs
            # about two solves and makes each 1.2x (B) to 3-10x (M + tt L, three right-hand sides) faster
            self._solver.change_factor(True, False)
        self.n_numeric += 1
        return self

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A^-1 b for b of shape (n,) or (n, k)."""
        b = np.ascontiguousarray(b, dtype=float)
        if self.backend == "scipy":
            return self._solver.solve(b)
        x = np.empty_like(b)
        self._solver.solve(b, x, 0)  # mode 0: CHOLMOD_A
        return x


class KronFactor:
    """J = A (x) I_m in node-major order (dof a*m + c) through a factorisation of the (n, n) matrix A.

    ``solve`` takes (n*m,) vectors; ``trans`` is accepted for the interface of SuperLU objects and
    ignored (J is symmetric).
    """

    def __init__(self, factor: SymmetricFactor, m: int) -> None:
        self.factor = factor
        self.m = m

    def solve(self, b: np.ndarray, trans: str = "N") -> np.ndarray:
        """J^-1 b for b of shape (n*m,): one factorisation, m right-hand sides."""
        return self.factor.solve(np.asarray(b, float).reshape(-1, self.m)).ravel()


class FullFactor:
    """A symmetric J factorised as a whole (the anisotropic J_Y); ``trans`` is ignored."""

    def __init__(self, factor: SymmetricFactor) -> None:
        self.factor = factor

    def solve(self, b: np.ndarray, trans: str = "N") -> np.ndarray:
        """J^-1 b for b of shape (n,)."""
        return self.factor.solve(b)
