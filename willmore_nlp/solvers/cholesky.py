"""Sparse symmetric factorisation with the symbolic analysis kept per sparsity pattern.

The step solver ``newton-krylov`` factorises two kinds of symmetric positive definite matrices
many times on one topology: the N x N matrix M[X] + tt L[X] (the isotropic J_Y = (M + tt L) (x) I_m)
and the 3N x 3N Gauss-Newton preconditioner. Their sparsity pattern is fixed per mesh topology,
their values change with X.

Backends
--------
``qdldl``
    The QDLDL LDL^T factorisation (registry wheel ``qdldl``, no system libraries). Its AMD ordering
    and symbolic analysis are done once per pattern; a new matrix with the same pattern is
    refactorised numerically only (``Solver.update``).
``scipy``
    SuperLU (``scipy.sparse.linalg.splu``) with COLAMD ordering, used when ``qdldl`` is not
    installed or when asked for. SuperLU has no separate symbolic phase.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.errors import UserInputError

try:  # pragma: no cover - exercised by the import itself
    import qdldl as _qdldl
except ImportError:  # pragma: no cover - the fallback is tested by forcing backend="scipy"
    _qdldl = None

BACKENDS = ("auto", "qdldl", "scipy")


def resolve_backend(name: str) -> str:
    """The backend used for ``name`` (``"auto"``: qdldl when installed, else scipy)."""
    if name not in BACKENDS:
        raise UserInputError(f"option cholesky must be one of {', '.join(BACKENDS)}, got {name!r}")
    if name == "auto":
        return "qdldl" if _qdldl is not None else "scipy"
    if name == "qdldl" and _qdldl is None:
        raise UserInputError("option cholesky='qdldl' needs the package qdldl (pip install qdldl)")
    return name


class SymmetricFactor:
    """Factorisations of symmetric matrices that share one sparsity pattern (re-analysed if it changes).

    Parameters
    ----------
    backend : {"auto", "qdldl", "scipy"}

    Attributes
    ----------
    n_symbolic : number of symbolic analyses (orderings) done
    n_numeric : number of numeric factorisations done
    """

    def __init__(self, backend: str = "auto") -> None:
        self.backend = resolve_backend(backend)
        self._solver: Any = None
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None
        self.n_symbolic = 0
        self.n_numeric = 0

    def factor(self, A: sp.spmatrix) -> SymmetricFactor:
        """Factorise the symmetric (n, n) matrix ``A`` (both triangles given); returns self."""
        if self.backend == "scipy":
            self._solver = spla.splu(sp.csc_matrix(A), permc_spec="COLAMD")
            self.n_symbolic += 1
            self.n_numeric += 1
            return self
        U = sp.triu(A, format="csc")
        U.sort_indices()
        same = (self._pattern is not None and self._pattern[0].shape == U.indptr.shape
                and self._pattern[1].shape == U.indices.shape and np.array_equal(self._pattern[0], U.indptr)
                and np.array_equal(self._pattern[1], U.indices))
        if same:
            self._solver.update(U, upper=True)
        else:
            self._solver = _qdldl.Solver(U, upper=True)
            self._pattern = (U.indptr.copy(), U.indices.copy())
            self.n_symbolic += 1
        self.n_numeric += 1
        return self

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A^-1 b for b of shape (n,) or (n, k)."""
        b = np.asarray(b, float)
        if self.backend == "scipy":
            return self._solver.solve(b)
        if b.ndim == 1:
            return np.asarray(self._solver.solve(b))
        return np.column_stack([self._solver.solve(np.ascontiguousarray(b[:, j])) for j in range(b.shape[1])])


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
