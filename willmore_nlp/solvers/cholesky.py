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
    no numeric-only refactorisation). The wheel's bundled BLAS is the reference (netlib) one; before
    the extension is loaded, :func:`_use_casadi_openblas` puts the OpenBLAS that CasADi ships (IPOPT's
    own) into the global symbol scope, so that CHOLMOD's dense kernels run in OpenBLAS
    (:data:`BLAS`; ``WILLMORE_NLP_CHOLMOD_BLAS=reference`` keeps the reference BLAS). Measured on the
    preconditioner B of the 10,242-vertex sphere (30,726 x 30,726, 1.75e6 nonzeros; one thread):
    factorisation 0.73 s with OpenBLAS against 1.73 s with the reference BLAS (earlier, with the
    reference BLAS: 2.01 s for ``cholespy``, CHOLMOD simplicial with AMD only, and 0.99 s for MKL
    PARDISO, ``pypardiso``, whose ``mkl`` wheels weigh 270 MB to download and 0.9 GB installed);
    solves with B 16.5 ms with the supernodal factor against 23.5 ms after conversion to the
    simplicial form (24.5 ms with the reference BLAS, whose supernodal solves took 32 ms). Solves with
    the N x N matrix M + tt L (three right-hand sides) stay faster in the simplicial form (1.5 ms
    against 2.1 ms at 10,242 vertices). ``SymmetricFactor(simplicial=...)`` chooses the form;
    by default simplicial only with the reference BLAS (the conversion costs about two solves).
    ``cholespy`` itself cannot be loaded in the same process (both register the same nanobind type).
``scipy``
    SuperLU (``scipy.sparse.linalg.splu``) with COLAMD ordering: used when ``sksparse-minimal`` is
    not installed, or when asked for.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp.errors import UserInputError

BLAS_ENV = "WILLMORE_NLP_CHOLMOD_BLAS"
"""Environment variable: ``reference`` keeps the wheel's own reference BLAS for CHOLMOD (default: ``openblas``)."""


def _use_casadi_openblas() -> ctypes.CDLL | None:
    """Put the OpenBLAS shipped with CasADi into the process's global symbol scope, before CHOLMOD is loaded.

    The extension of ``sksparse-minimal`` resolves its BLAS/LAPACK symbols (dgemm_, dsyrk_, dtrsm_, dpotrf_,
    dgemv_, dtrsv_ and their complex versions) when it is imported; the dynamic linker looks in the global
    scope before the extension's own dependencies (the bundled reference BLAS), so a library loaded with
    ``RTLD_GLOBAL`` first serves them. CasADi's ``libcasadi-tp-openblas`` exports these standard names
    and is the library IPOPT and MUMPS already use (it is their own dependency, so their results do not
    change). Measured on the preconditioner of the 10,242-vertex sphere (one thread): supernodal
    factorisation 0.73 s instead of 1.73 s, solve 16.5 ms instead of 24.5 ms (simplicial form).

    Returns the loaded library (CHOLMOD's BLAS is then OpenBLAS), or None: the reference BLAS (asked for by
    :data:`BLAS_ENV`, library not found, or ``sksparse_minimal`` imported before this module).
    """
    if os.environ.get(BLAS_ENV, "openblas").strip().lower() == "reference":
        return None
    if "sksparse_minimal._cholespy_core" in sys.modules:  # pragma: no cover - bound to its own BLAS already
        return None
    try:
        import casadi

        libs = sorted(Path(casadi.__file__).parent.glob("libcasadi-tp-openblas.so*"))
        return ctypes.CDLL(str(libs[0]), mode=os.RTLD_GLOBAL | os.RTLD_NOW) if libs else None
    except (ImportError, OSError):  # pragma: no cover - depends on the installation
        return None


_OPENBLAS = _use_casadi_openblas()
BLAS = "reference" if _OPENBLAS is None else "openblas"
"""BLAS of CHOLMOD's supernodal factorisation and solves (:func:`_use_casadi_openblas`)."""


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with CHOLMOD's OpenBLAS on one thread, the process's count restored after it.

    The supernodal solves are sequences of small triangular and matrix products, for which OpenBLAS's
    threads cost more than they gain. Measured with two threads (the default on this 2-core machine,
    ``OPENBLAS_NUM_THREADS`` unset) against one, 10,242-vertex sphere, newton-krylov steps 1-3: CG 5.30 / 1.62 /
    1.39 s against 1.92 / 0.61 / 0.45 s for the same 69 / 22 / 17 iterations, twice the CPU time. The
    factorisations keep the process's count: equal at 10,242 vertices (1.65 / 0.95 / 0.88 s with two threads,
    1.70 / 0.84 / 1.08 s with one), faster with two at 40,962 (17.7 / 5.2 / 4.3 s against 23.9 / 5.6 / 5.6 s).
    A solve is then the same arithmetic whatever ``OPENBLAS_NUM_THREADS`` says. One call pair costs under a
    microsecond.
    """
    n = _OPENBLAS.openblas_get_num_threads() if _OPENBLAS is not None else 1
    if n == 1:
        yield
        return
    _OPENBLAS.openblas_set_num_threads(1)
    try:
        yield
    finally:
        _OPENBLAS.openblas_set_num_threads(n)

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
    simplicial : bool, optional
        CHOLMOD only: convert each supernodal factor to its simplicial form for the solves (module
        docstring); default: only when CHOLMOD runs on the reference BLAS.

    Attributes
    ----------
    n_numeric : number of factorisations done
    """

    def __init__(self, backend: str = "auto", simplicial: bool | None = None) -> None:
        self.backend = resolve_backend(backend)
        self.simplicial = (BLAS == "reference") if simplicial is None else simplicial
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
            indptr, indices = (a.astype(np.int32, copy=False) for a in (A.indptr, A.indices))
            self._solver = _Cholmod(self._n, indptr, indices, np.ascontiguousarray(A.data, dtype=float))
            if self.simplicial:  # supernodal factorisation, simplicial LL' solves (module docstring)
                self._solver.change_factor(True, False)
        self.n_numeric += 1
        return self

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A^-1 b for b of shape (n,) or (n, k)."""
        b = np.ascontiguousarray(b, dtype=float)
        if self.backend == "scipy":
            return self._solver.solve(b)
        x = np.empty_like(b)
        with one_blas_thread():
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
