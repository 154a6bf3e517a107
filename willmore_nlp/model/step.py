"""The step problem: one NLP per time step, built once per mesh topology.

Symbolic form -> element kernels -> assembled global functions:

* The *terms* (:mod:`willmore_nlp.model.terms`) write, for one simplex, their parts of the local outer
  objective ``w_T(X_T, Y_T, Xk_T, par, c_T, Q_T)``, of the local inner energy ``e_T`` and of the outer
  constraints ``h_T``. The inner Euler-Lagrange residual of the element is ``g_T = 1/2 d e_T / d Y_T``.
* :func:`element_kernels` differentiates their sums with CasADi AD *per element* into five small
  SX functions (value, gradient, constraint, constraint Jacobian, Lagrangian Hessian), two more
  with outer constraints. Their size does not depend on the mesh.
* :class:`StepProblem` precomputes, with numpy, the gather indices of every element's inputs
  and the global sparsity patterns with an element-entry -> global-nonzero map (:class:`Pattern`).
  :class:`~willmore_nlp.model.evaluator.StepEvaluator` evaluates with these maps in numpy
  (gather -> mapped kernel -> ``bincount``); :class:`GlobalFunctions` builds, on first access,
  the same assembly as MX functions ``nlp_f, nlp_g, grad_f, jac_g, hess_lag`` for ``nlpsol``
  (IPOPT). The kernels can be replaced by compiled C (:mod:`willmore_nlp.codegen`) without
  touching the assembly.

Unknowns ``z = [X_free, Y_free]`` in node-major order (node a, coordinate c at ``a*m + c``).
Parameters ``p``: :class:`willmore_nlp.model.params.StepParams` (Xk for all nodes, named scalars,
per-node data, nodal vectors). Fixed nodes (boundary conditions) take their X and Y values from
``Xk``, which never changes on fixed nodes. Besides the inner constraint ``g`` (square in Y), terms
may add a few outer equality constraints ``h(X, Y) = sum_T h_T - target = 0``; solvers see
``c = [g; h]`` with multipliers ``[lam_g; lam_h]``.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.topology import sorted_unique
from willmore_nlp.model.params import BASE_SCALARS, StepParams
from willmore_nlp.model.terms.base import CAPABILITIES, Element, Term

KERNEL_NAMES = ("k_f", "k_g", "k_grad", "k_jac", "k_hess", "k_h", "k_hjac")
"""Element kernels in a fixed order (also the order in compiled libraries); k_h, k_hjac only with outer constraints."""


@dataclass(frozen=True)
class KernelSpec:
    """Shape of an element kernel: d, m, scalar parameters, per-element constants, per-node data, constraint rows."""

    d: int
    m: int
    scalars: tuple[str, ...]
    consts: tuple[str, ...] = ()
    nodal: tuple[tuple[str, int], ...] = ()
    nh: int = 0

    @property
    def nl(self) -> int:
        """Local nodal values of one field: (d + 1) * m."""
        return (self.d + 1) * self.m

    @property
    def n_nodal(self) -> int:
        """Per-node data width."""
        return sum(w for _, w in self.nodal)


def _total(parts: list[ca.SX | float]) -> ca.SX:
    """Sum left to right, skipping the exact zeros of terms without a contribution."""
    kept = [q for q in parts if not (isinstance(q, float) and q == 0.0)]
    total = kept[0] if kept else ca.SX(0)
    for q in kept[1:]:
        total = total + q
    return ca.SX(total)


def _check_terms(terms: Sequence[Term]) -> None:
    """UserInputError unless every term's name is an identifier (or empty), its ``requires`` are known capabilities
    and no two terms (nor a term and the step itself: tau, tt, lam) declare the same scalar parameter (one would
    silently take the other's value)."""
    owner: dict[str, str] = {k: "the step itself" for k in BASE_SCALARS}
    for t in terms:
        if t.name and not t.name.isidentifier():
            raise UserInputError(f"term {t.label!r}: its name {t.name!r} must be a Python identifier (it names the "
                                 "compiled element kernels)")
        unknown = set(t.requires) - CAPABILITIES
        if unknown:
            raise UserInputError(f"term {t.label!r} requires {', '.join(sorted(unknown))}: not a solver capability "
                                 f"(known: {', '.join(sorted(CAPABILITIES))})")
        for k in t.scalars:
            if k in owner:
                raise UserInputError(f"term {t.label!r} declares the scalar parameter {k!r}, which {owner[k]} "
                                     "declares too: give it a name of its own")
            owner[k] = f"term {t.label!r}"


def element_kernels(spec: KernelSpec, terms: Sequence[Term], name: str = "step") -> dict[str, ca.Function]:
    """Differentiate the sum of the terms' element contributions into the element kernels.

    Returns
    -------
    dict
        ``k_f(xe, par) -> w``, ``k_g(xe, par) -> g`` (nl), ``k_grad(xe, par) -> (w, dw/dz)``
        (2 nl), ``k_jac(xe, par) -> (g, vec(dg/dz))`` (nl x 2nl, column-major),
        ``k_hess(xe, par, lf, lg[, lh]) -> triu(H)`` (packed upper triangle, row-major over
        ``np.triu_indices(2 nl)``) of ``lf * w + lg . g [+ lh . h]`` in ``z_T = [X_T, Y_T]``; with
        outer constraints also ``k_h(xe, par) -> h`` (nh) and ``k_hjac(xe, par) -> (h, vec(dh/dz))``.
        ``xe = [X_T, Y_T, Xk_T, Q_T, c_T]`` with node-major nodal blocks (Q_T: ``n_nodal`` per node).
    """
    nv, m, nl = spec.d + 1, spec.m, spec.nl
    nq = spec.n_nodal * nv
    xe = ca.SX.sym("xe", 3 * nl + nq + len(spec.consts))
    par = ca.SX.sym("par", len(spec.scalars))
    Q = ca.reshape(xe[3 * nl : 3 * nl + nq], spec.n_nodal, nv)
    nodal, row = {}, 0
    for key, w in spec.nodal:
        nodal[key], row = Q[row : row + w, :], row + w
    e = Element(X=ca.reshape(xe[0:nl], m, nv), Y=ca.reshape(xe[nl : 2 * nl], m, nv),
                Xk=ca.reshape(xe[2 * nl : 3 * nl], m, nv), par={k: par[i] for i, k in enumerate(spec.scalars)},
                const={k: xe[3 * nl + nq + i] for i, k in enumerate(spec.consts)}, nodal=nodal)
    groups: dict[str, list[ca.SX | float]] = {}
    inners, hs = [], []
    for t in terms:  # terms with the same element weight are summed first, then weighted (as written by hand)
        try:
            groups.setdefault(t.weight, []).append(t.outer(e))
            inners.append(t.inner(e))
            rows = list(t.constraints(e))
        except KeyError as exc:  # (a name read from e.par, e.const or e.nodal that no term declares)
            raise UserInputError(f"term {t.label!r} reads {exc.args[0]!r}, which is not among the step's parameters "
                                 f"(scalars: {', '.join(spec.scalars)}; per-node data: "
                                 f"{', '.join(k for k, _ in spec.nodal) or 'none'}): declare it in the term's "
                                 "`scalars` or `nodal`") from exc
        for row in rows:
            if ca.depends_on(ca.SX(row), ca.vec(e.Y)):
                raise UserInputError(f"term {t.label!r}: its outer constraint depends on Y; outer constraints are "
                                     "functions of the positions X alone (the flow restores them on X)")
        hs += rows
    w = _total([e.c(k) * _total(v) if k else _total(v) for k, v in groups.items()])
    inner = _total(inners)
    z = xe[0 : 2 * nl]
    g = 0.5 * ca.gradient(inner, xe[nl : 2 * nl])
    lf = ca.SX.sym("lf")
    lg = ca.SX.sym("lg", nl)
    lag = lf * w + ca.dot(lg, g)
    h = ca.vertcat(*hs)
    lh = ca.SX.sym("lh", len(hs))
    if hs:
        lag = lag + ca.dot(lh, h)
    H = ca.hessian(lag, z)[0]
    iu = np.triu_indices(2 * nl)
    Hu = ca.vertcat(*[H[int(i), int(j)] for i, j in zip(*iu, strict=True)])
    k = {
        "k_f": ca.Function(f"{name}_k_f", [xe, par], [w]),
        "k_g": ca.Function(f"{name}_k_g", [xe, par], [g]),
        "k_grad": ca.Function(f"{name}_k_grad", [xe, par], [w, ca.gradient(w, z)]),
        "k_jac": ca.Function(f"{name}_k_jac", [xe, par], [g, ca.vec(ca.jacobian(g, z))]),
        "k_hess": ca.Function(f"{name}_k_hess", [xe, par, lf, lg, *([lh] if hs else [])], [Hu]),
    }
    if hs:
        k["k_h"] = ca.Function(f"{name}_k_h", [xe, par], [h])
        k["k_hjac"] = ca.Function(f"{name}_k_hjac", [xe, par], [h, ca.vec(ca.jacobian(h, z))])
    return k


@dataclass(frozen=True)
class Pattern:
    """Compressed-column sparsity of an assembled matrix and where every element entry lands in it.

    Attributes
    ----------
    shape : (nrow, ncol)
    row : (nnz,) row of each nonzero, column-major order (CasADi's and scipy CSC's)
    colind : (ncol + 1,) start of each column in ``row``
    emap : (K, entries per element) nonzero of each element entry (the element kernel's structural
        nonzeros, in its order), ``nnz`` for dropped entries (fixed nodes)
    """

    shape: tuple[int, int]
    row: np.ndarray
    colind: np.ndarray
    emap: np.ndarray

    @property
    def nnz(self) -> int:
        """Number of nonzeros."""
        return int(self.row.size)

    def casadi(self) -> ca.Sparsity:
        """The same pattern as a CasADi sparsity (for the MX functions)."""
        col = np.repeat(np.arange(self.shape[1]), np.diff(self.colind))
        return ca.Sparsity.triplet(self.shape[0], self.shape[1], self.row.tolist(), col.tolist())


ELEMENT_BLOCK = 4096
"""Elements per block of the pattern computation and of the numeric kernel evaluations (bounds their memory)."""


def _index_dtype(bound: int) -> type[np.signedinteger]:
    """int32 for indices up to ``bound`` below 2^31 (half the memory of int64, and scipy's own index type, so
    that matrices built on a pattern keep its arrays), else int64."""
    return np.int32 if bound < 2**31 - 1 else np.int64


def _pattern(entries: Callable[[slice], tuple[np.ndarray, np.ndarray]], width: int, K: int,
             shape: tuple[int, int]) -> Pattern:
    """Compressed-column pattern of the element entries and their map into it.

    ``entries(block)`` returns (rows, cols) of the ``width`` entries of each element of ``block`` ((n, width)
    each, -1 = dropped). Computed in blocks of elements, so that the temporaries stay at the size of one
    block beside the result (whole-mesh (K, width) int64 arrays were 2-3 times the result at 10,242
    vertices).
    """
    nrow = max(shape[0], 1)
    blocks = [slice(i, min(i + ELEMENT_BLOCK, K)) for i in range(0, K, ELEMENT_BLOCK)]

    def keys(block: slice) -> np.ndarray:
        rows, cols = entries(block)
        key = cols.astype(np.int64) * nrow + rows
        key[(rows < 0) | (cols < 0)] = -1
        return key

    uk = sorted_unique(np.concatenate([sorted_unique(keys(b)) for b in blocks] or [np.zeros(0, np.int64)]))
    uk = uk[uk >= 0]
    dtype = _index_dtype(max(uk.size, *shape))
    emap = np.empty((K, width), dtype)
    for b in blocks:
        key = keys(b)
        emap[b] = np.where(key >= 0, np.searchsorted(uk, key), uk.size)
    colind = np.searchsorted(uk // nrow, np.arange(shape[1] + 1)).astype(dtype)
    return Pattern(shape, (uk % nrow).astype(dtype), colind, emap)


def _scatter_add(values: ca.MX, emap: np.ndarray, n: int) -> ca.MX:
    """MX vector of length n with ``out[emap[i]] += values[i]``; entries mapped to n are dropped.

    Built as the gradient of a dot product with a gather, which CasADi represents by a
    single scatter-add node (no 0/1 matrix, no per-entry graph nodes). It is wrapped in its own
    Function of a free symbol so that CasADi never differentiates through ``values`` (which may
    come from compiled kernels without derivatives).
    """
    v = ca.MX.sym("v", emap.size)
    w = ca.MX.sym("w", n + 1)
    add = ca.Function("scatter_add", [v], [ca.gradient(ca.dot(w[emap.ravel().tolist()], v), w)[:n]])
    return add(values)


def _assembled(local: ca.MX, pattern: Pattern) -> ca.MX:
    """The sparse MX matrix of ``pattern`` (over every element entry, :meth:`StepProblem.mx_pattern`) whose
    nonzeros are the sums of the element entries ``local`` (the mapped kernel output, densified)."""
    return ca.sparsity_cast(_scatter_add(ca.densify(ca.vec(local)), pattern.emap, pattern.nnz), pattern.casadi())


def _unique(names: Sequence[str]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(names))


@dataclass
class StepProblem:
    """A step NLP on a fixed topology: the sum of its terms (:mod:`willmore_nlp.model.terms`).

    Parameters
    ----------
    simplices : (K, d + 1) int array
        All simplices on which element kernels are evaluated.
    n_vertices : int
    m : int
    terms : sequence of Term
        Summed in this order (W, E and the outer constraints).
    x_free : (N,) bool array
        Nodes whose position X is an unknown (default: all).
    y_free : (N,) bool array
        Nodes whose Y is an unknown and that carry a constraint row (default: all).
    element_const : dict name -> (K,) float array, optional
        Named per-element constants the terms read (``patch``, ``stiff`` of a clamped boundary).
    name : str
    """

    simplices: np.ndarray
    n_vertices: int
    m: int
    terms: Sequence[Term]
    x_free: np.ndarray | None = None
    y_free: np.ndarray | None = None
    element_const: dict[str, np.ndarray] | None = None
    name: str = "step"
    kernels: dict[str, ca.Function] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        S = np.asarray(self.simplices, dtype=np.int64)
        self.simplices = S
        N, m = self.n_vertices, self.m
        self.K, nv = S.shape
        self.d = nv - 1
        self.terms = tuple(self.terms)
        self.x_free = np.ones(N, bool) if self.x_free is None else np.asarray(self.x_free, bool)
        self.y_free = np.ones(N, bool) if self.y_free is None else np.asarray(self.y_free, bool)
        consts = dict(self.element_const or {})
        self.const_names = tuple(consts)
        self.const_values = (np.column_stack([np.asarray(consts[k], float) for k in self.const_names])
                             if consts else np.zeros((self.K, 0)))
        ts = self.terms
        _check_terms(ts)
        self.params = StepParams(N, m, _unique([*BASE_SCALARS, *(k for t in ts for k in t.scalars)]),
                                 tuple(b for t in ts for b in t.nodal), _unique([k for t in ts for k in t.vectors]))
        self.targets = tuple(k for t in ts for k in t.constraint_targets)
        self.spec = KernelSpec(self.d, m, self.params.scalars, self.const_names, self.params.nodal, len(self.targets))
        self.kernels = element_kernels(self.spec, ts, self.name)
        self._layout()

    @property
    def nonlinear_inner(self) -> bool:
        """Some term's inner energy is not quadratic in Y (the inner equation needs Newton)."""
        return any(t.nonlinear_inner for t in self.terms)

    @property
    def tangential_weight(self) -> float:
        """beta of the distance term (1 for the paper's scheme)."""
        return next((float(t.beta) for t in self.terms if hasattr(t, "beta")), 1.0)

    def requires(self) -> dict[str, Term]:
        """Solver capabilities the terms need, each with the first term that needs it."""
        out: dict[str, Term] = {}
        for t in self.terms:
            for cap in sorted(t.requires):
                out.setdefault(cap, t)
        return out

    # -- index maps (numpy, once per topology) -------------------------------------------
    def _layout(self) -> None:
        m, S, K = self.m, self.simplices, self.K
        nl = self.spec.nl
        self.x_index = np.cumsum(self.x_free) - 1  # free-X index of each node (valid where free)
        self.y_index = np.cumsum(self.y_free) - 1
        self.nX = int(self.x_free.sum())
        self.nY = int(self.y_free.sum())
        self.nx = (self.nX + self.nY) * m
        self.ng = self.nY * m
        self.nh = len(self.targets)
        self.nc = self.ng + self.nh
        self.np_ = self.params.size
        coord = np.arange(m)
        node_c = S[:, :, None] * m + coord  # K, nv, m: position of (node, c) in Xk block
        xfree_e = self.x_free[S][:, :, None].repeat(m, 2).reshape(K, nl)
        yfree_e = self.y_free[S][:, :, None].repeat(m, 2).reshape(K, nl)
        xvar = (self.x_index[S][:, :, None] * m + coord).reshape(K, nl)
        yvar = (self.nX * m + self.y_index[S][:, :, None] * m + coord).reshape(K, nl)
        pk = self.nx + node_c.reshape(K, nl)  # Xk entries in v = [z; p; consts]
        q = self.spec.n_nodal
        qidx = (self.nx + self.params.nodal_start + S[:, :, None] * q + np.arange(q)).reshape(K, (self.d + 1) * q)
        n_const = len(self.const_names)
        cidx = self.nx + self.np_ + np.arange(K * n_const).reshape(K, n_const)
        ix = _index_dtype(self.nx + self.np_ + K * n_const)
        self.gather = np.hstack([np.where(xfree_e, xvar, pk), np.where(yfree_e, yvar, pk), pk, qidx, cidx]).astype(ix)
        # local z_T -> global variable (-1 when fixed)
        self.zmap = np.hstack([np.where(xfree_e, xvar, -1), np.where(yfree_e, yvar, -1)]).astype(ix)  # K x 2nl
        self.gmap = np.where(yfree_e, (self.y_index[S][:, :, None] * m + coord).reshape(K, nl), -1).astype(ix)
        # gradient and constraint scatter maps (n = dropped)
        self.grad_map = np.where(self.zmap >= 0, self.zmap, self.nx).astype(ix)
        self.g_map = np.where(self.gmap >= 0, self.gmap, self.ng).astype(ix)
        # Jacobians: vec(dg/dz) column-major, entry (a, b) at b * nl + a; likewise dh/dz (nh rows)
        zmap, gmap, nh = self.zmap, self.gmap, self.nh

        def jac(b: slice) -> tuple[np.ndarray, np.ndarray]:
            n = len(range(K)[b])
            return (np.repeat(gmap[b, None, :], 2 * nl, axis=1).reshape(n, 2 * nl * nl),  # n, 2nl(b), nl(a)
                    np.repeat(zmap[b, :, None], nl, axis=2).reshape(n, 2 * nl * nl))

        def hjac(b: slice) -> tuple[np.ndarray, np.ndarray]:
            n = len(range(K)[b])
            return (np.broadcast_to(np.arange(nh), (n, 2 * nl, nh)).reshape(n, 2 * nl * nh),
                    np.repeat(zmap[b, :, None], nh, axis=2).reshape(n, 2 * nl * nh))

        iu, ju = np.triu_indices(2 * nl)

        def hess(b: slice) -> tuple[np.ndarray, np.ndarray]:  # upper triangle: local (i <= j) -> global (min, max)
            a, c = zmap[b][:, iu], zmap[b][:, ju]
            return np.where(c >= 0, np.minimum(a, c), -1), np.where(a >= 0, np.maximum(a, c), -1)

        def nonzero(kernel: str, entries: Callable[[slice], tuple[np.ndarray, np.ndarray]]
                    ) -> tuple[Callable[[slice], tuple[np.ndarray, np.ndarray]], int]:
            """``entries`` restricted to the structural nonzeros of the kernel's output, in its nonzero order
            (the structural zeros, e.g. the coordinate couplings of the isotropic J_Y = (M + tt L) (x) I_m,
            54 of the 162 entries of a triangle in R^3, never enter the pattern: J has a third fewer
            nonzeros), and their number."""
            nz = np.asarray(self.kernels[kernel].sparsity_out(1 if kernel in ("k_jac", "k_hjac") else 0).find(),
                            np.int64)

            def kept(b: slice) -> tuple[np.ndarray, np.ndarray]:
                rows, cols = entries(b)
                return rows[:, nz], cols[:, nz]
            return kept, nz.size

        self.jac_pattern = _pattern(*nonzero("k_jac", jac), K, (self.ng, self.nx))
        self.hjac_pattern = _pattern(*(nonzero("k_hjac", hjac) if nh else (hjac, 0)), K, (self.nh, self.nx))
        self.hess_pattern = _pattern(*nonzero("k_hess", hess), K, (self.nx, self.nx))
        self._all_entries = {"jac": (jac, 2 * nl * nl, (self.ng, self.nx)),
                             "hjac": (hjac, 2 * nl * nh, (self.nh, self.nx)),
                             "hess": (hess, iu.size, (self.nx, self.nx))}
        self._mx_patterns: dict[str, Pattern] = {}

    def mx_pattern(self, name: str) -> Pattern:
        """The pattern of ``name`` ("jac", "hjac", "hess") over every element entry, structural zeros included:
        the one the MX functions (IPOPT's KKT matrix) have always had, built on first use. (IPOPT's iterates
        depend on it through MUMPS's ordering: without the zeros, the first step of the 64-gon ellipse of
        ``tests/test_tangential.py`` took 50 iterations instead of 44.)"""
        if name not in self._mx_patterns:
            entries, width, shape = self._all_entries[name]
            self._mx_patterns[name] = _pattern(entries, width, self.K, shape)
        return self._mx_patterns[name]

    # -- global functions ------------------------------------------------------------------
    def functions(self, kernels: dict[str, ca.Function] | None = None) -> GlobalFunctions:
        """The global MX functions assembled from element kernels (symbolic or compiled), each built on
        first access (:class:`GlobalFunctions`).

        Returns
        -------
        GlobalFunctions, a mapping with ``f(z, p)``, ``g(z, p)`` (inner, ng), ``grad_f(z, p) -> (f, grad)``,
        ``jac_g(z, p) -> (g, J)`` (inner), ``jac_c(z, p) -> (c, J_c)`` with c = [g; h] (the same as
        jac_g without outer constraints), ``h(z, p)`` (nh), ``hess_lag(z, p, lam_f, lam_c) -> triu(H)``
        of ``lam_f f + lam_c . c``, and the symbols ``z``, ``p`` with expressions ``f_expr``,
        ``g_expr`` (= c) for ``nlpsol``.
        """
        return GlobalFunctions(self, self.kernels if kernels is None else kernels)

    def _free_y_rows(self) -> list[int]:
        """Positions in an (N*m) nodal vector of the free-Y rows, in constraint order."""
        nodes = np.flatnonzero(self.y_free)
        return (nodes[:, None] * self.m + np.arange(self.m)).ravel().tolist()

    # -- packing helpers -------------------------------------------------------------------
    def pack_z(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """(nx,) unknown vector from full nodal arrays X, Y ((N, m) each)."""
        return np.concatenate([X[self.x_free].ravel(), Y[self.y_free].ravel()])

    def unpack_z(self, z: np.ndarray, Xk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full nodal X, Y ((N, m) each) from the unknowns; fixed nodes take Xk."""
        m = self.m
        z = np.asarray(z, float).ravel()
        X = np.array(Xk, float, copy=True)
        Y = np.array(Xk, float, copy=True)
        X[self.x_free] = z[: self.nX * m].reshape(-1, m)
        Y[self.y_free] = z[self.nX * m :].reshape(-1, m)
        return X, Y

    def unpack_x(self, x: np.ndarray, Xk: np.ndarray) -> np.ndarray:
        """Full nodal X ((N, m)) from the free-X unknowns ``x`` ((nX m,)); fixed nodes take Xk."""
        X = np.array(Xk, float, copy=True)
        X[self.x_free] = np.asarray(x, float).reshape(-1, self.m)
        return X

    def pack_p(self, Xk: np.ndarray, tau: float, tt: float, lam: float,
               simplices: np.ndarray | None = None, off: Collection[str] = ()) -> np.ndarray:
        """(np,) parameter vector of a step from Xk: the base scalars and every term's values.

        ``simplices`` are all simplices of the mesh (default: the problem's own), for terms with
        per-node data built over neighbourhoods (the tangential control). ``off``: scalar parameters of
        terms left out (e.g. "control_weight"): every scalar of a term whose scalars are all named is 0 and its
        per-node data are zeros instead of computed (for the evaluations that such a term cannot change or
        must not enter: the inner equation, the outer constraints, the energy without it).
        """
        S = self.simplices if simplices is None else simplices
        values: dict[str, object] = {"tau": tau, "tt": tt, "lam": lam}
        N = np.shape(Xk)[0]
        for t in self.terms:
            if t.scalars and set(t.scalars) <= set(off):
                values.update({k: 0.0 for k in t.scalars})
                values.update({k: np.zeros((N, w)) for k, w in t.nodal})
            else:
                given = t.values(Xk, tau, S, self.x_free)
                undeclared = set(given) - {*t.scalars, *(k for k, _ in t.nodal), *t.vectors}
                if undeclared:
                    raise UserInputError(f"term {t.label!r} gives values for {', '.join(sorted(undeclared))}, which "
                                         "it does not declare (its scalars, nodal and vectors)")
                values.update(given)
        return self.params.pack(Xk, values)


class GlobalFunctions(Mapping):
    """The assembled global functions of a :class:`StepProblem` (keys: :meth:`StepProblem.functions`),
    each built on its first access, with the expressions they share.

    Every function is gather -> mapped element kernel -> scatter-add over the whole mesh; its MX graph
    holds index vectors of the size of the element-entry maps, and its evaluation buffers the element
    outputs (the Hessian's: 171 values per triangle). A solver that never asks for a function (the
    reduced solvers never use ``f_expr``, ``g_expr`` or ``jac_c`` without outer constraints; IPOPT never
    uses ``g`` or ``h``) pays neither.

    Parameters
    ----------
    problem : StepProblem
    kernels : the element kernels (symbolic or compiled, :data:`KERNEL_NAMES`)
    """

    KEYS = ("z", "p", "f_expr", "g_expr", "f", "g", "h", "grad_f", "jac_g", "jac_c", "hess_lag")

    def __init__(self, problem: StepProblem, kernels: dict[str, ca.Function]) -> None:
        self.problem = problem
        self.kernels = kernels
        self._built: dict[str, Any] = {}

    def __getitem__(self, key: str) -> Any:
        if key not in self.KEYS:
            raise KeyError(key)
        if key not in self._built:
            self._built[key] = getattr(self, f"_build_{key}")()
        return self._built[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.KEYS)

    def __len__(self) -> int:
        return len(self.KEYS)

    def built(self) -> tuple[str, ...]:
        """The keys built so far (functions and the shared expressions, in order of construction)."""
        return tuple(self._built)

    def _part(self, key: str, make: Callable[[], Any]) -> Any:
        """A shared expression, made once (kept with the built functions under a private key)."""
        if key not in self._built:
            self._built[key] = make()
        return self._built[key]

    # -- shared symbols and expressions ----------------------------------------------------
    def _build_z(self) -> ca.MX:
        return ca.MX.sym("z", self.problem.nx)

    def _build_p(self) -> ca.MX:
        return ca.MX.sym("p", self.problem.np_)

    def _elements(self) -> tuple[ca.MX, ca.MX]:
        """E: the (nin, K) element inputs gathered from [z; p; consts], and the scalar parameter block."""
        def make() -> tuple[ca.MX, ca.MX]:
            P = self.problem
            v = ca.vertcat(self["z"], self["p"], ca.DM(P.const_values.ravel()))
            E = ca.reshape(v[P.gather.ravel().tolist()], P.gather.shape[1], P.K)
            return E, P.params.scalar_block(self["p"])
        return self._part("_elements", make)

    def _map(self, name: str) -> ca.Function:
        return self.kernels[name].map(self.problem.K)

    def _vectors(self, g: ca.MX) -> ca.MX:
        """g minus tt b on the free-Y rows for every nodal vector b of the terms."""
        P, p = self.problem, self["p"]
        for name in P.params.vectors:
            g = g - P.params.scalar(p, "tt") * P.params.vector(p, name)[P._free_y_rows()]
        return g

    def _target(self) -> ca.MX:
        P, p = self.problem, self["p"]
        return ca.vertcat(*[P.params.scalar(p, t) for t in P.targets])

    def _f(self) -> ca.MX:
        return self._part("_f", lambda: ca.sum2(self._map("k_f")(*self._elements())))

    def _g(self) -> ca.MX:
        P = self.problem
        return self._part("_g", lambda: self._vectors(
            _scatter_add(ca.vec(self._map("k_g")(*self._elements())), P.g_map, P.ng)))

    def _h(self) -> ca.MX:
        if not self.problem.nh:
            return ca.MX(0, 1)
        return self._part("_h", lambda: ca.sum2(self._map("k_h")(*self._elements())) - self._target())

    def _jac(self) -> tuple[ca.MX, ca.MX]:
        """(g, J) of the inner constraint from the Jacobian kernel."""
        def make() -> tuple[ca.MX, ca.MX]:
            P = self.problem
            gj, jl = self._map("k_jac")(*self._elements())
            J = _assembled(jl, P.mx_pattern("jac"))
            return self._vectors(_scatter_add(ca.vec(gj), P.g_map, P.ng)), J
        return self._part("_jac", make)

    # -- functions ---------------------------------------------------------------------------
    def _build_f_expr(self) -> ca.MX:
        return self._f()

    def _build_g_expr(self) -> ca.MX:
        return ca.vertcat(self._g(), self._h()) if self.problem.nh else self._g()

    def _build_f(self) -> ca.Function:
        return ca.Function("nlp_f", [self["z"], self["p"]], [self._f()], _IO, ["f"])

    def _build_g(self) -> ca.Function:
        return ca.Function("nlp_g", [self["z"], self["p"]], [self._g()], _IO, ["g"])

    def _build_h(self) -> ca.Function:
        return ca.Function("nlp_h", [self["z"], self["p"]], [self._h()], _IO, ["h"])

    def _build_grad_f(self) -> ca.Function:
        P = self.problem
        fg, gradl = self._map("k_grad")(*self._elements())
        grad = _scatter_add(ca.vec(gradl), P.grad_map, P.nx)
        return ca.Function("nlp_grad_f", [self["z"], self["p"]], [ca.sum2(fg), grad], _IO, ["f", "grad"])

    def _build_jac_g(self) -> ca.Function:
        return ca.Function("nlp_jac_g", [self["z"], self["p"]], list(self._jac()), _IO, ["g", "jac"])

    def _build_jac_c(self) -> ca.Function:
        P = self.problem
        gjac, J = self._jac()
        if P.nh:
            hh, hjl = self._map("k_hjac")(*self._elements())
            Jh = _assembled(hjl, P.mx_pattern("hjac"))
            gjac, J = ca.vertcat(gjac, ca.sum2(hh) - self._target()), ca.vertcat(J, Jh)
        return ca.Function("nlp_jac_c", [self["z"], self["p"]], [gjac, J], _IO, ["g", "jac"])

    def _build_hess_lag(self) -> ca.Function:
        P = self.problem
        z, p = self["z"], self["p"]
        lam_f = ca.MX.sym("lam_f")
        lam_c = ca.MX.sym("lam_c", P.nc)
        E, par = self._elements()
        LG = ca.reshape(ca.vertcat(lam_c[: P.ng], 0)[P.g_map.ravel().tolist()], P.spec.nl, P.K)  # 0 on dropped rows
        lh = [lam_c[P.ng :]] if P.nh else []
        hl = self._map("k_hess")(E, par, lam_f, LG, *lh)
        H = _assembled(hl, P.mx_pattern("hess"))
        return ca.Function("nlp_hess_l", [z, p, lam_f, lam_c], [H], ["x", "p", "lam_f", "lam_g"], ["hess"])


_IO = ["x", "p"]
