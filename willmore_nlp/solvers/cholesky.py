"""Sparse Cholesky factorisation of symmetric positive definite matrices, with a scipy fallback.

The step solver ``newton-krylov`` factorises two kinds of SPD matrices many times on one topology:
the N x N matrix M[X] + tt L[X] (the isotropic J_Y = (M + tt L) (x) I_m) and the 3N x 3N
Gauss-Newton preconditioner (two-ring coupling).

Backends
--------
``cholmod``
    SuiteSparse's CHOLMOD through the registry wheel ``sksparse-minimal`` (a fork of ``cholespy`` that bundles
    CHOLMOD built with METIS and LAPACK/BLAS, so that it factorises supernodally and tries METIS beside AMD;
    no system libraries). Its Python class orders and factorises in every call; this module drives CHOLMOD's C
    API, which the extension exports, through ctypes instead, so that a sparsity pattern is analysed once and
    refactorised numerically (:class:`SymmetricFactor`). The wheel's bundled BLAS is the reference (netlib)
    one; before the extension is loaded, :func:`_use_casadi_openblas` puts the OpenBLAS that CasADi ships
    (IPOPT's own) into the global symbol scope, so that CHOLMOD's dense kernels run in OpenBLAS (:data:`BLAS`;
    ``WILLMORE_NLP_CHOLMOD_BLAS=reference`` keeps the reference BLAS). Measured on the preconditioner B of the
    10,242-vertex sphere (30,726 x 30,726, 1.75e6 nonzeros; one thread): factorisation 0.73 s with OpenBLAS
    against 1.73 s with the reference BLAS (earlier, with the reference BLAS: 2.01 s for ``cholespy``, CHOLMOD
    simplicial with AMD only, and 0.99 s for MKL PARDISO, ``pypardiso``, whose ``mkl`` wheels weigh 270 MB to
    download and 0.9 GB installed); solves with B 16.5 ms with the supernodal factor against 23.5 ms after
    conversion to the simplicial form (24.5 ms with the reference BLAS, whose supernodal solves took 32 ms).
    Solves with the N x N matrix M + tt L (three right-hand sides) stay faster in the simplicial form (1.5 ms
    against 2.1 ms at 10,242 vertices). ``SymmetricFactor(simplicial=...)`` chooses the form; by default
    simplicial only with the reference BLAS (the conversion costs about two solves). ``cholespy`` itself
    cannot be loaded in the same process (both register the same nanobind type).
``scipy``
    SuperLU (``scipy.sparse.linalg.splu``) with COLAMD ordering: used when ``sksparse-minimal`` is
    not installed, or when asked for.
"""

from __future__ import annotations

import ctypes
import os
import sys
import weakref
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import threadpoolctl

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
    1.70 / 0.84 / 1.08 s with one), faster with two at 40,962 (17.7 / 5.2 / 4.3 s against 23.9 / 5.6 / 5.6 s);
    numeric refactorisations of B alone (:class:`SymmetricFactor`, idle machine): two threads 1.16 / 1.27 / 1.56x
    faster at 2,562 / 10,242 / 40,962 vertices.
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


@contextmanager
def other_blas_one_thread() -> Iterator[None]:
    """Run the block with numpy's and scipy's BLAS libraries on one thread; CHOLMOD's (:data:`BLAS`) keeps its count.

    numpy and scipy ship OpenBLAS builds of their own beside the one CHOLMOD runs on (CasADi's). After a threaded
    call, and numpy's dot of two vectors of more than 10,000 entries is one, OpenBLAS's idle worker threads spin for
    a while before they sleep; on a machine with no more cores than threads they hold the core that CHOLMOD's second
    thread needs. Measured on this 2-core machine: a numeric refactorisation of M + tt L at 10,242 vertices
    0.013-0.017 s on its own, 0.09-0.12 s right after a 400 x 400 numpy product; in newton-krylov's steps 2-3 at
    10,242 vertices the 6-7 such refactorisations took 0.32-0.47 s per step, 0.10 s with numpy's and scipy's BLAS on
    one thread (and B's 0.56-0.60 s, 0.40-0.48 s). The vector operations of CG gain nothing from threads.
    threadpoolctl finds those libraries by their file names (CasADi's ``libcasadi-tp-openblas`` is not among them,
    tested).
    """
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
        yield


class _Sparse(ctypes.Structure):
    """CHOLMOD's ``cholmod_sparse`` (a compressed-column matrix; the layout of CHOLMOD 2-5, SuiteSparse 4-7)."""

    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("nz", ctypes.c_void_p), ("x", ctypes.c_void_p),
                ("z", ctypes.c_void_p), ("stype", ctypes.c_int), ("itype", ctypes.c_int), ("xtype", ctypes.c_int),
                ("dtype", ctypes.c_int), ("sorted", ctypes.c_int), ("packed", ctypes.c_int)]


class _Dense(ctypes.Structure):
    """CHOLMOD's ``cholmod_dense`` (column-major, leading dimension d)."""

    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("d", ctypes.c_size_t), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p), ("xtype", ctypes.c_int),
                ("dtype", ctypes.c_int)]


class _FactorHead(ctypes.Structure):
    """The first fields of ``cholmod_factor``: minor < n after a factorisation means not positive definite."""

    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t)]


_REAL, _SOLVE_A = 1, 0  # CHOLMOD_REAL (xtype), CHOLMOD_A (solve A x = b)
_COMMON_BYTES = 1 << 16  # cholmod_common is about 2-4 kB in CHOLMOD 3-5; cholmod_start fills it


def _load_cholmod() -> ctypes.CDLL | None:
    """CHOLMOD's C API from the extension of ``sksparse-minimal``, which exports it (SuiteSparse 5.4 in 0.3).

    The package's Python class orders and factorises in one call; the C API separates the symbolic analysis
    (fill-reducing ordering, elimination tree, supernodes: ``cholmod_analyze``) from the numeric factorisation
    (``cholmod_factorize``), so that :class:`SymmetricFactor` analyses each sparsity pattern once. None when
    the package is missing or its CHOLMOD is not a version whose structures this module declares.
    """
    try:
        from sksparse_minimal import _cholespy_core
    except ImportError:  # pragma: no cover - the fallback itself is tested by forcing backend="scipy"
        return None
    lib = ctypes.CDLL(_cholespy_core.__file__)
    version = (ctypes.c_int * 3)()
    if not hasattr(lib, "cholmod_analyze") or not 4 <= lib.SuiteSparse_version(version) // 1000 <= 7:
        return None  # pragma: no cover - another build of the package
    vp, sp_p, cp = ctypes.c_void_p, ctypes.POINTER(_Sparse), ctypes.c_void_p
    for name, res, args in (("cholmod_start", ctypes.c_int, [cp]), ("cholmod_finish", ctypes.c_int, [cp]),
                            ("cholmod_analyze", vp, [sp_p, cp]), ("cholmod_factorize", ctypes.c_int, [sp_p, vp, cp]),
                            ("cholmod_copy_factor", vp, [vp, cp]),
                            ("cholmod_change_factor", ctypes.c_int, [ctypes.c_int] * 5 + [vp, cp]),
                            ("cholmod_solve", ctypes.POINTER(_Dense), [ctypes.c_int, vp, ctypes.POINTER(_Dense), cp]),
                            ("cholmod_free_factor", ctypes.c_int, [ctypes.POINTER(vp), cp]),
                            ("cholmod_free_dense", ctypes.c_int, [ctypes.POINTER(ctypes.POINTER(_Dense)), cp])):
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    _silence(lib)
    return lib


def _silence(lib: ctypes.CDLL) -> None:
    """Turn off CHOLMOD's own printing: SuiteSparse 5's global ``SuiteSparse_config`` holds the printf it prints
    warnings with (its fifth function pointer), set to NULL here when it is the C library's printf (the layout
    checked). A failed factorisation is reported by its status, which :meth:`SymmetricFactor.factor` raises as
    LinAlgError and the solvers' messages carry; CHOLMOD had printed each one to stderr as well ("CHOLMOD warning:
    matrix not positive definite. file: /project/ext/...": a new user's check, an anisotropic clamped patch)."""
    try:
        config = (ctypes.c_void_p * 7).in_dll(lib, "SuiteSparse_config")
        printf = ctypes.cast(ctypes.CDLL(None).printf, ctypes.c_void_p).value
    except (ValueError, AttributeError, OSError):  # pragma: no cover - another SuiteSparse layout: it keeps printing
        return
    if config[4] == printf:
        config[4] = None


_Cholmod = _load_cholmod()

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
    """Factorisation of a symmetric positive definite sparse matrix, refactorised as its values change.

    With CHOLMOD the symbolic analysis (ordering, elimination tree, supernodes) is done once per sparsity
    pattern and kept; a later :meth:`factor` of a matrix with the same pattern is a numeric factorisation only.
    Measured on newton-krylov's preconditioner B of the benchmark's spheres (one thread, idle machine): the
    package's call (analysis and factorisation) 0.70 s at 10,242 vertices (30,726 rows), of which the analysis
    0.22 s, against 0.45-0.50 s for a refactorisation; 6.75 s at 40,962 vertices, analysis 0.84 s, against
    3.7-4.6 s (CHOLMOD's default postordering, which the package turns off, also makes the factor faster).

    Parameters
    ----------
    backend : {"auto", "cholmod", "scipy"}
    simplicial : bool, optional
        CHOLMOD only: convert each supernodal factor to its simplicial form for the solves (module
        docstring); default: only when CHOLMOD runs on the reference BLAS.

    Attributes
    ----------
    n_numeric : number of factorisations done
    n_symbolic : number of symbolic analyses done (CHOLMOD; one per sparsity pattern met in a row)
    """

    def __init__(self, backend: str = "auto", simplicial: bool | None = None) -> None:
        self.backend = resolve_backend(backend)
        self.simplicial = (BLAS == "reference") if simplicial is None else simplicial
        self._solver: Any = None
        self._n = 0
        self.n_numeric = 0
        self.n_symbolic = 0
        if self.backend == "cholmod":
            self._common = ctypes.create_string_buffer(_COMMON_BYTES)
            _Cholmod.cholmod_start(self._common)
            # [symbolic, numeric] factors; freed with the workspace when this object goes
            self._factors = [ctypes.c_void_p(), ctypes.c_void_p()]
            self._pattern: tuple[np.ndarray, np.ndarray] | None = None  # analysed (indptr, indices)
            self._embedded: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # a contained pattern's positions
            weakref.finalize(self, _release, self._factors, self._common)

    def factor(self, A: sp.spmatrix) -> SymmetricFactor:
        """Factorise the SPD (n, n) matrix ``A`` (both triangles given); returns self.

        Raises
        ------
        numpy.linalg.LinAlgError
            CHOLMOD: ``A`` is not positive definite.
        """
        A = sp.csc_matrix(A)
        self._n = A.shape[0]
        if self.backend == "scipy":
            self._solver = None  # the previous factor goes first: never two alive (0.65 GB each for B at 40,962 v)
            self._solver = spla.splu(A, permc_spec="COLAMD")
            self.n_numeric += 1
            return self
        A.sum_duplicates()  # sorted row indices, no duplicates: CHOLMOD's packed form
        indptr, indices = (a.astype(np.int32, copy=False) for a in (A.indptr, A.indices))
        data = np.ascontiguousarray(A.data, dtype=float)
        symbolic, numeric = self._factors
        _free_factor(numeric, self._common)  # never two numeric factors alive
        known = self._pattern is not None and all(map(np.array_equal, self._pattern, (indptr, indices)))
        if not known:
            indptr, indices, data, known = self._on_pattern(indptr, indices, data)
        M = _Sparse(self._n, self._n, data.size, indptr.ctypes.data, indices.ctypes.data, None, data.ctypes.data,
                    None, 1, 0, _REAL, 0, 1, 1)  # stype 1: the upper triangle is read
        if not known:
            _free_factor(symbolic, self._common)
            symbolic.value = _Cholmod.cholmod_analyze(ctypes.byref(M), self._common)
            self._pattern, self._embedded = (indptr, indices), None
            self.n_symbolic += 1
        numeric.value = _Cholmod.cholmod_copy_factor(symbolic, self._common)
        if not symbolic or not numeric or not _Cholmod.cholmod_factorize(ctypes.byref(M), numeric, self._common):
            raise MemoryError(f"CHOLMOD could not factorise a {self._n} x {self._n} matrix with {data.size} nonzeros")
        minor = ctypes.cast(numeric, ctypes.POINTER(_FactorHead)).contents.minor
        if minor < self._n:
            raise np.linalg.LinAlgError(f"matrix not positive definite (CHOLMOD: leading minor {minor} of {self._n})")
        if self.simplicial:  # supernodal factorisation, simplicial LL' solves (module docstring)
            _Cholmod.cholmod_change_factor(_REAL, 1, 0, 1, 1, numeric, self._common)
        self.n_numeric += 1
        return self

    def _on_pattern(self, indptr: np.ndarray, indices: np.ndarray,
                    data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """(indptr, indices, data, analysed): the matrix on the analysed pattern with explicit zeros when its pattern
        is contained in it (analysed True), else on the union of both patterns (a new analysis).

        scipy's sparse products and sums drop entries that come out exactly zero, so the pattern of a matrix
        assembled from the same operators can lose entries from one point to the next (newton-krylov's B on the
        642-vertex sphere, its third step); the union keeps the analysis of the operators' structural pattern.
        """
        n = self._n
        if self._pattern is None or self._pattern[0].size != n + 1:
            return indptr.copy(), indices.copy(), data, False
        last = self._embedded
        if last is None or not all(map(np.array_equal, last[:2], (indptr, indices))):
            keys, analysed = _keys(indptr, indices), _keys(*self._pattern)
            pos = np.minimum(np.searchsorted(analysed, keys), analysed.size - 1)
            if not np.array_equal(analysed[pos], keys):  # new entries: the union, analysed anew
                union = np.sort(np.concatenate([analysed, keys]), kind="stable")  # two sorted runs: a merge
                union = union[np.r_[True, union[1:] != union[:-1]]]
                cols, rows = np.divmod(union, n)
                full = np.zeros(union.size)
                full[np.searchsorted(union, keys)] = data
                return np.searchsorted(cols, np.arange(n + 1)).astype(np.int32), rows.astype(np.int32), full, False
            last = self._embedded = (indptr.copy(), indices.copy(), pos)  # the positions of the pattern met last
        full = np.zeros(self._pattern[1].size)
        full[last[2]] = data
        return *self._pattern, full, True

    def solve(self, b: np.ndarray) -> np.ndarray:
        """A^-1 b for b of shape (n,) or (n, k)."""
        b = np.ascontiguousarray(b, dtype=float)
        if self.backend == "scipy":
            return self._solver.solve(b)
        k = 1 if b.ndim == 1 else b.shape[1]
        B = np.asfortranarray(b.reshape(self._n, k))
        rhs = _Dense(self._n, k, B.size, self._n, B.ctypes.data, None, _REAL, 0)
        with one_blas_thread():
            X = _Cholmod.cholmod_solve(_SOLVE_A, self._factors[1], ctypes.byref(rhs), self._common)
        if not X:
            raise MemoryError(f"CHOLMOD could not solve with a {self._n} x {self._n} factor")
        try:
            x = np.ctypeslib.as_array(ctypes.cast(X.contents.x, ctypes.POINTER(ctypes.c_double)), (k, self._n)).T
            return x.reshape(b.shape).copy()  # a copy in C order: CHOLMOD's array is freed below
        finally:
            _Cholmod.cholmod_free_dense(ctypes.byref(X), self._common)


def _keys(indptr: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(nnz,) int64 keys col * n + row of a compressed-column pattern with sorted rows: sorted, unique."""
    n = indptr.size - 1
    return np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr)) * n + indices


def _free_factor(factor: ctypes.c_void_p, common: Any) -> None:
    """Free a CHOLMOD factor held in ``factor`` (which is then NULL); nothing if it is NULL."""
    if factor:
        _Cholmod.cholmod_free_factor(ctypes.byref(factor), common)


def _release(factors: list[ctypes.c_void_p], common: Any) -> None:
    """Free a :class:`SymmetricFactor`'s CHOLMOD factors and workspace (its finaliser)."""
    for f in factors:
        _free_factor(f, common)
    _Cholmod.cholmod_finish(common)


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
