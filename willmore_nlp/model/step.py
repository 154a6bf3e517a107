"""The step problem: one NLP per time step, built once per mesh topology.

Symbolic form -> element kernels -> assembled global functions:

* The *terms* (:mod:`willmore_nlp.model.terms`) write, for one simplex, their parts of the local outer
  objective ``w_T(X_T, Y_T, Xk_T, par, c_T, Q_T)``, of the local inner energy ``e_T`` and of the outer
  constraints ``h_T``. The inner Euler-Lagrange residual of the element is ``g_T = 1/2 d e_T / d Y_T``.
* :func:`element_kernels` differentiates their sums with CasADi AD *per element* into five small
  SX functions (value, gradient, constraint, constraint Jacobian, Lagrangian Hessian), two more
  with outer constraints. Their size does not depend on the mesh.
* :class:`StepProblem` precomputes, with numpy, the gather indices of every element's inputs
  and the global sparsity patterns with an element-entry -> global-nonzero map, and builds MX
  functions ``nlp_f, nlp_g, grad_f, jac_g, hess_lag`` as: gather -> mapped kernel -> scatter-add.
  The kernels can be replaced by compiled C (:mod:`willmore_nlp.codegen`) without touching
  the assembly.

Unknowns ``z = [X_free, Y_free]`` in node-major order (node a, coordinate c at ``a*m + c``).
Parameters ``p``: :class:`willmore_nlp.model.params.StepParams` (Xk for all nodes, named scalars,
per-node data, nodal vectors). Fixed nodes (boundary conditions) take their X and Y values from
``Xk``, which never changes on fixed nodes. Besides the inner constraint ``g`` (square in Y), terms
may add a few outer equality constraints ``h(X, Y) = sum_T h_T - target = 0``; solvers see
``c = [g; h]`` with multipliers ``[lam_g; lam_h]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from willmore_nlp.model.params import BASE_SCALARS, StepParams
from willmore_nlp.model.terms.base import Element, Term

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
    for t in terms:  # terms with the same element weight are summed first, then weighted (as written by hand)
        groups.setdefault(t.weight, []).append(t.outer(e))
    w = _total([e.c(k) * _total(v) if k else _total(v) for k, v in groups.items()])
    inner = _total([t.inner(e) for t in terms])
    hs = [h for t in terms for h in t.constraints(e)]
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


def _pattern(rows: np.ndarray, cols: np.ndarray, nrow: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Compressed-column pattern of the entries (rows, cols) (same shape, -1 = dropped).

    Returns
    -------
    r, c : (nnz,) row and column of each global nonzero, in CasADi's column-major order
    emap : same shape as ``rows``: global nonzero of each entry, ``nnz`` for dropped entries
    """
    keep = (rows >= 0) & (cols >= 0)
    key = cols.astype(np.int64) * nrow + rows
    uk, inv = np.unique(key[keep], return_inverse=True)
    emap = np.full(rows.shape, uk.size, dtype=np.int64)
    emap[keep] = inv
    return uk % nrow, uk // nrow, emap


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
        self.gather = np.hstack([np.where(xfree_e, xvar, pk), np.where(yfree_e, yvar, pk), pk, qidx, cidx])
        # local z_T -> global variable (-1 when fixed)
        self.zmap = np.hstack([np.where(xfree_e, xvar, -1), np.where(yfree_e, yvar, -1)])  # K x 2nl
        self.gmap = np.where(yfree_e, (self.y_index[S][:, :, None] * m + coord).reshape(K, nl), -1)
        # gradient and constraint scatter maps (n = dropped)
        self.grad_map = np.where(self.zmap >= 0, self.zmap, self.nx)
        self.g_map = np.where(self.gmap >= 0, self.gmap, self.ng)
        # Jacobians: vec(dg/dz) column-major, entry (a, b) at b * nl + a; likewise dh/dz (nh rows)
        rows = np.repeat(self.gmap[:, None, :], 2 * nl, axis=1)  # K, 2nl(b), nl(a)
        cols = np.repeat(self.zmap[:, :, None], nl, axis=2)
        jr, jc, self.jac_map = _pattern(rows.reshape(K, -1), cols.reshape(K, -1), self.ng)
        self.jac_sparsity = ca.Sparsity.triplet(self.ng, self.nx, jr.tolist(), jc.tolist())
        hrows = np.broadcast_to(np.arange(self.nh), (K, 2 * nl, self.nh))
        hcols = np.repeat(self.zmap[:, :, None], self.nh, axis=2)
        hr, hc, self.hjac_map = _pattern(hrows.reshape(K, -1), hcols.reshape(K, -1), max(self.nh, 1))
        self.hjac_sparsity = ca.Sparsity.triplet(self.nh, self.nx, hr.tolist(), hc.tolist())
        # Hessian upper triangle: local (i <= j) -> global (min, max)
        iu, ju = np.triu_indices(2 * nl)
        a, b = self.zmap[:, iu], self.zmap[:, ju]
        hr = np.where((a >= 0) & (b >= 0), np.minimum(a, b), -1)
        hc = np.where((a >= 0) & (b >= 0), np.maximum(a, b), -1)
        hr_, hc_, self.hess_map = _pattern(hr, hc, self.nx)
        self.hess_sparsity = ca.Sparsity.triplet(self.nx, self.nx, hr_.tolist(), hc_.tolist())

    # -- global functions ------------------------------------------------------------------
    def functions(self, kernels: dict[str, ca.Function] | None = None) -> dict[str, ca.Function]:
        """Assemble the global MX functions from element kernels (symbolic or compiled).

        Returns
        -------
        dict with ``f(z, p)``, ``g(z, p)`` (inner, ng), ``grad_f(z, p) -> (f, grad)``,
        ``jac_g(z, p) -> (g, J)`` (inner), ``jac_c(z, p) -> (c, J_c)`` with c = [g; h] (the same as
        jac_g without outer constraints), ``h(z, p)`` (nh), ``hess_lag(z, p, lam_f, lam_c) -> triu(H)``
        of ``lam_f f + lam_c . c``, and the symbols ``z``, ``p`` with expressions ``f_expr``,
        ``g_expr`` (= c) for ``nlpsol``.
        """
        k = self.kernels if kernels is None else kernels
        K, nl, nh = self.K, self.spec.nl, self.nh
        z = ca.MX.sym("z", self.nx)
        p = ca.MX.sym("p", self.np_)
        lam_f = ca.MX.sym("lam_f")
        lam_c = ca.MX.sym("lam_c", self.nc)
        v = ca.vertcat(z, p, ca.DM(self.const_values.ravel()))
        E = ca.reshape(v[self.gather.ravel().tolist()], self.gather.shape[1], K)
        par = self.params.scalar_block(p)
        # lam_g per element (0 on dropped rows)
        lg_ext = ca.vertcat(lam_c[: self.ng], 0)
        LG = ca.reshape(lg_ext[self.g_map.ravel().tolist()], nl, K)

        f = ca.sum2(k["k_f"].map(K)(E, par))
        g = _scatter_add(ca.vec(k["k_g"].map(K)(E, par)), self.g_map, self.ng)
        fg, gradl = k["k_grad"].map(K)(E, par)
        grad = _scatter_add(ca.vec(gradl), self.grad_map, self.nx)
        gj, jl = k["k_jac"].map(K)(E, par)
        gjac = _scatter_add(ca.vec(gj), self.g_map, self.ng)
        J = ca.sparsity_cast(_scatter_add(ca.vec(jl), self.jac_map, self.jac_sparsity.nnz()), self.jac_sparsity)
        lh = [lam_c[self.ng :]] if nh else []
        hl = k["k_hess"].map(K)(E, par, lam_f, LG, *lh)
        H = ca.sparsity_cast(_scatter_add(ca.vec(hl), self.hess_map, self.hess_sparsity.nnz()), self.hess_sparsity)
        for name in self.params.vectors:  # nodal vectors b: g -= tt b on the free-Y rows
            b = self.params.vector(p, name)[self._free_y_rows()]
            g = g - self.params.scalar(p, "tt") * b
            gjac = gjac - self.params.scalar(p, "tt") * b
        target = ca.vertcat(*[self.params.scalar(p, t) for t in self.targets])
        if nh:
            h = ca.sum2(k["k_h"].map(K)(E, par)) - target
            hh, hjl = k["k_hjac"].map(K)(E, par)
            Jh = ca.sparsity_cast(_scatter_add(ca.vec(hjl), self.hjac_map, self.hjac_sparsity.nnz()),
                                  self.hjac_sparsity)
            c, Jc = ca.vertcat(g, h), ca.vertcat(J, Jh)
            cj = ca.vertcat(gjac, ca.sum2(hh) - target)
        else:
            h, c, Jc, cj = ca.MX(0, 1), g, J, gjac
        io = ["x", "p"]
        return {
            "z": z,
            "p": p,
            "f_expr": f,
            "g_expr": c,
            "f": ca.Function("nlp_f", [z, p], [f], io, ["f"]),
            "g": ca.Function("nlp_g", [z, p], [g], io, ["g"]),
            "h": ca.Function("nlp_h", [z, p], [h], io, ["h"]),
            "grad_f": ca.Function("nlp_grad_f", [z, p], [ca.sum2(fg), grad], io, ["f", "grad"]),
            "jac_g": ca.Function("nlp_jac_g", [z, p], [gjac, J], io, ["g", "jac"]),
            "jac_c": ca.Function("nlp_jac_c", [z, p], [cj, Jc], io, ["g", "jac"]),
            "hess_lag": ca.Function("nlp_hess_l", [z, p, lam_f, lam_c], [H], ["x", "p", "lam_f", "lam_g"], ["hess"]),
        }

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
               simplices: np.ndarray | None = None) -> np.ndarray:
        """(np,) parameter vector of a step from Xk: the base scalars and every term's values.

        ``simplices`` are all simplices of the mesh (default: the problem's own), for terms with
        per-node data built over neighbourhoods (the tangential control).
        """
        S = self.simplices if simplices is None else simplices
        values: dict[str, object] = {"tau": tau, "tt": tt, "lam": lam}
        for t in self.terms:
            values.update(t.values(Xk, tau, S, self.x_free))
        return self.params.pack(Xk, values)
