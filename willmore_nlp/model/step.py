"""The step problem: one NLP per time step, built once per mesh topology.

Symbolic form -> element kernels -> assembled global functions:

* An *energy* (see :mod:`willmore_nlp.model.energies`) writes, for one simplex, the local outer
  objective ``w_T(X_T, Y_T, Xk_T, par, c_T)`` and the local inner energy ``e_T``. The inner
  Euler-Lagrange residual of the element is ``g_T = 1/2 d e_T / d Y_T``.
* :func:`element_kernels` differentiates these with CasADi AD *per element* into five small
  SX functions (value, gradient, constraint, constraint Jacobian, Lagrangian Hessian). Their size
  does not depend on the mesh.
* :class:`StepProblem` precomputes, with numpy, the gather indices of every element's inputs
  and the global sparsity patterns with an element-entry -> global-nonzero map, and builds MX
  functions ``nlp_f, nlp_g, grad_f, jac_g, hess_lag`` as: gather -> mapped kernel -> scatter-add.
  The kernels can be replaced by compiled C (:mod:`willmore_nlp.codegen`) without touching
  the assembly.

Unknowns ``z = [X_free, Y_free]`` in node-major order (node a, coordinate c at ``a*m + c``).
Parameters ``p = [Xk (N*m, all nodes), tau, tt, lam, nodal (N*n_nodal), extra...]``: ``nodal``
holds per-node parameters that every element gathers with its nodes (the tangential-control data,
:mod:`willmore_nlp.tangential`), ``extra`` the co-normal term. Fixed nodes (boundary
conditions) take their X and Y values from ``Xk``, which never changes on fixed nodes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

# names of the five element kernels, in a fixed order (also the order in compiled libraries)
KERNEL_NAMES = ("k_f", "k_g", "k_grad", "k_jac", "k_hess")

EnergyFn = Callable[[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX, ca.SX], tuple[ca.SX, ca.SX]]
"""(X, Y, Xk, par, c, Q) -> (w_T, e_T); X, Y, Xk are (m, d+1) SX; par = (tau, tt, lam, ...); c per-element
data; Q the (n_nodal, d+1) per-node parameters of the element's nodes (0 rows when there are none)."""


@dataclass(frozen=True)
class KernelSpec:
    """Shape of an element kernel: d, m, number of scalar parameters, per-element constants and per-node parameters."""

    d: int
    m: int
    n_par: int = 3
    n_const: int = 0
    n_nodal: int = 0

    @property
    def nl(self) -> int:
        """Local nodal values of one field: (d + 1) * m."""
        return (self.d + 1) * self.m


def element_kernels(spec: KernelSpec, energy: EnergyFn, name: str = "step") -> dict[str, ca.Function]:
    """Differentiate an element energy into the five element kernels.

    Returns
    -------
    dict
        ``k_f(xe, par) -> w``, ``k_g(xe, par) -> g`` (nl), ``k_grad(xe, par) -> (w, dw/dz)``
        (2 nl), ``k_jac(xe, par) -> (g, vec(dg/dz))`` (nl x 2nl, column-major),
        ``k_hess(xe, par, lf, lg) -> triu(H)`` (packed upper triangle, row-major over
        ``np.triu_indices(2 nl)``) of ``lf * w + lg . g`` in ``z_T = [X_T, Y_T]``.
        ``xe = [X_T, Y_T, Xk_T, Q_T, c_T]`` with node-major nodal blocks (Q_T: ``n_nodal`` per node).
    """
    nv, m, nl = spec.d + 1, spec.m, spec.nl
    xe = ca.SX.sym("xe", 3 * nl + spec.n_nodal * nv + spec.n_const)
    par = ca.SX.sym("par", spec.n_par)
    X = ca.reshape(xe[0:nl], m, nv)
    Y = ca.reshape(xe[nl : 2 * nl], m, nv)
    Xk = ca.reshape(xe[2 * nl : 3 * nl], m, nv)
    nq = spec.n_nodal * nv
    Q = ca.reshape(xe[3 * nl : 3 * nl + nq], spec.n_nodal, nv)
    c = xe[3 * nl + nq :]
    w, e = energy(X, Y, Xk, par, c, Q)
    z = xe[0 : 2 * nl]
    g = 0.5 * ca.gradient(e, xe[nl : 2 * nl])
    lf = ca.SX.sym("lf")
    lg = ca.SX.sym("lg", nl)
    H = ca.hessian(lf * w + ca.dot(lg, g), z)[0]
    iu = np.triu_indices(2 * nl)
    Hu = ca.vertcat(*[H[int(i), int(j)] for i, j in zip(*iu, strict=True)])
    return {
        "k_f": ca.Function(f"{name}_k_f", [xe, par], [w]),
        "k_g": ca.Function(f"{name}_k_g", [xe, par], [g]),
        "k_grad": ca.Function(f"{name}_k_grad", [xe, par], [w, ca.gradient(w, z)]),
        "k_jac": ca.Function(f"{name}_k_jac", [xe, par], [g, ca.vec(ca.jacobian(g, z))]),
        "k_hess": ca.Function(f"{name}_k_hess", [xe, par, lf, lg], [Hu]),
    }


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


@dataclass
class StepProblem:
    """A step NLP on a fixed topology with parameters (Xk, tau, tt, lam, extra).

    Parameters
    ----------
    simplices : (K, d + 1) int array
        All simplices on which element kernels are evaluated.
    n_vertices : int
    m : int
    energy : EnergyFn
        The local outer/inner energies (see :mod:`willmore_nlp.model.energies`).
    x_free : (N,) bool array
        Nodes whose position X is an unknown (default: all).
    y_free : (N,) bool array
        Nodes whose Y is an unknown and that carry a constraint row (default: all).
    element_const : (K, n_const) float array, optional
        Per-element constants passed to the energy (e.g. a weight of the outer objective).
    n_par : int
        Scalar parameters after Xk: at least (tau, tt, lam).
    n_nodal : int
        Per-node parameters after the scalar ones (``p`` carries an (N, n_nodal) block, node-major),
        gathered into every element with its nodes (the energy's ``Q``).
    g_extra : (N, m) bool mask or None
        If given, ``p`` carries an extra (N*m) block ``b`` and ``g -= tt * b`` on free-Y rows
        (the co-normal term of the boundary variant).
    name : str
    anisotropic : bool
        The inner energy is the anisotropic one (nonlinear in Y), not the linearised isotropic one.
    tangential_weight : float
        beta of the distance term (:func:`willmore_nlp.model.energies.distance`), 1 for the paper's.
    """

    simplices: np.ndarray
    n_vertices: int
    m: int
    energy: EnergyFn
    x_free: np.ndarray | None = None
    y_free: np.ndarray | None = None
    element_const: np.ndarray | None = None
    n_par: int = 3
    n_nodal: int = 0
    g_extra: bool = False
    name: str = "step"
    anisotropic: bool = False
    tangential_weight: float = 1.0
    kernels: dict[str, ca.Function] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        S = np.asarray(self.simplices, dtype=np.int64)
        self.simplices = S
        N, m = self.n_vertices, self.m
        self.K, nv = S.shape
        self.d = nv - 1
        self.x_free = np.ones(N, bool) if self.x_free is None else np.asarray(self.x_free, bool)
        self.y_free = np.ones(N, bool) if self.y_free is None else np.asarray(self.y_free, bool)
        C = np.zeros((self.K, 0)) if self.element_const is None else np.asarray(self.element_const, float)
        self.element_const = C.reshape(self.K, -1)
        self.spec = KernelSpec(self.d, m, self.n_par, self.element_const.shape[1], self.n_nodal)
        self.kernels = element_kernels(self.spec, self.energy, self.name)
        self._layout()

    # -- index maps (numpy, once per topology) -------------------------------------------
    def _layout(self) -> None:
        N, m, S, K = self.n_vertices, self.m, self.simplices, self.K
        nl = self.spec.nl
        self.x_index = np.cumsum(self.x_free) - 1  # free-X index of each node (valid where free)
        self.y_index = np.cumsum(self.y_free) - 1
        self.nX = int(self.x_free.sum())
        self.nY = int(self.y_free.sum())
        self.nx = (self.nX + self.nY) * m
        self.ng = self.nY * m
        self.np_ = N * m + self.n_par + N * self.n_nodal + (N * m if self.g_extra else 0)
        coord = np.arange(m)
        node_c = S[:, :, None] * m + coord  # K, nv, m: position of (node, c) in Xk block
        xfree_e = self.x_free[S][:, :, None].repeat(m, 2)
        yfree_e = self.y_free[S][:, :, None].repeat(m, 2)
        xvar = (self.x_index[S][:, :, None] * m + coord).reshape(K, nl)
        yvar = (self.nX * m + self.y_index[S][:, :, None] * m + coord).reshape(K, nl)
        xfree_e = xfree_e.reshape(K, nl)
        yfree_e = yfree_e.reshape(K, nl)
        pk = self.nx + node_c.reshape(K, nl)  # Xk entries in v = [z; p; consts]
        gx = np.where(xfree_e, xvar, pk)
        gy = np.where(yfree_e, yvar, pk)
        n_const = self.element_const.shape[1]
        q = self.n_nodal
        qidx = (self.nx + N * m + self.n_par + S[:, :, None] * q + np.arange(q)).reshape(K, (self.d + 1) * q)
        cidx = self.nx + self.np_ + np.arange(K * n_const).reshape(K, n_const)
        self.gather = np.hstack([gx, gy, pk, qidx, cidx])  # K x (3 nl + (d+1) n_nodal + n_const)
        # local z_T -> global variable (-1 when fixed)
        self.zmap = np.hstack([np.where(xfree_e, xvar, -1), np.where(yfree_e, yvar, -1)])  # K x 2nl
        self.gmap = np.where(yfree_e, (self.y_index[S][:, :, None] * m + coord).reshape(K, nl), -1)
        # gradient and constraint scatter maps (n = dropped)
        self.grad_map = np.where(self.zmap >= 0, self.zmap, self.nx)
        self.g_map = np.where(self.gmap >= 0, self.gmap, self.ng)
        # Jacobian: vec(dg/dz) column-major: entry (a, b) at b * nl + a
        rows = np.repeat(self.gmap[:, None, :], 2 * nl, axis=1)  # K, 2nl(b), nl(a)
        cols = np.repeat(self.zmap[:, :, None], nl, axis=2)
        jr, jc, self.jac_map = _pattern(rows.reshape(K, -1), cols.reshape(K, -1), self.ng)
        self.jac_sparsity = ca.Sparsity.triplet(self.ng, self.nx, jr.tolist(), jc.tolist())
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
        dict with ``f(z, p)``, ``g(z, p)``, ``grad_f(z, p) -> (f, grad)``,
        ``jac_g(z, p) -> (g, J)``, ``hess_lag(z, p, lam_f, lam_g) -> triu(H)`` and the
        symbols ``z``, ``p`` with expressions ``f_expr``, ``g_expr`` for ``nlpsol``.
        """
        k = self.kernels if kernels is None else kernels
        K, nl = self.K, self.spec.nl
        z = ca.MX.sym("z", self.nx)
        p = ca.MX.sym("p", self.np_)
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", self.ng)
        consts = ca.DM(self.element_const.ravel())
        v = ca.vertcat(z, p, consts)
        E = ca.reshape(v[self.gather.ravel().tolist()], self.gather.shape[1], K)
        N, m = self.n_vertices, self.m
        par = p[N * m : N * m + self.n_par]
        # lam_g per element (0 on dropped rows)
        lg_ext = ca.vertcat(lam_g, 0)
        LG = ca.reshape(lg_ext[self.g_map.ravel().tolist()], nl, K)

        f = ca.sum2(k["k_f"].map(K)(E, par))
        gl = k["k_g"].map(K)(E, par)
        g = _scatter_add(ca.vec(gl), self.g_map, self.ng)
        fg, gradl = k["k_grad"].map(K)(E, par)
        grad = _scatter_add(ca.vec(gradl), self.grad_map, self.nx)
        gj, jl = k["k_jac"].map(K)(E, par)
        gjac = _scatter_add(ca.vec(gj), self.g_map, self.ng)
        J = ca.sparsity_cast(_scatter_add(ca.vec(jl), self.jac_map, self.jac_sparsity.nnz()), self.jac_sparsity)
        hl = k["k_hess"].map(K)(E, par, lam_f, LG)
        H = ca.sparsity_cast(_scatter_add(ca.vec(hl), self.hess_map, self.hess_sparsity.nnz()), self.hess_sparsity)
        if self.g_extra:
            tt = p[N * m + 1]
            b = p[N * m + self.n_par + N * self.n_nodal :]
            rows = self._free_y_rows()
            g = g - tt * b[rows]
            gjac = gjac - tt * b[rows]
        io = dict(input_names=["x", "p"])
        return {
            "z": z,
            "p": p,
            "f_expr": f,
            "g_expr": g,
            "f": ca.Function("nlp_f", [z, p], [f], ["x", "p"], ["f"]),
            "g": ca.Function("nlp_g", [z, p], [g], ["x", "p"], ["g"]),
            "grad_f": ca.Function("nlp_grad_f", [z, p], [ca.sum2(fg), grad], io["input_names"], ["f", "grad"]),
            "jac_g": ca.Function("nlp_jac_g", [z, p], [gjac, J], io["input_names"], ["g", "jac"]),
            "hess_lag": ca.Function(
                "nlp_hess_l", [z, p, lam_f, lam_g], [H], ["x", "p", "lam_f", "lam_g"], ["hess"]
            ),
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

    def pack_p(self, Xk: np.ndarray, tau: float, tt: float, lam: float, extra: np.ndarray | None = None,
               more: tuple[float, ...] = (), nodal: np.ndarray | None = None) -> np.ndarray:
        """(np,) parameter vector; ``nodal`` is the (N, n_nodal) per-node block (needed when n_nodal > 0)."""
        parts = [np.asarray(Xk, float).ravel(), [tau, tt, lam], list(more)]
        if self.n_nodal:
            if nodal is None or np.shape(nodal) != (self.n_vertices, self.n_nodal):
                raise ValueError(f"this step problem needs the ({self.n_vertices}, {self.n_nodal}) per-node parameters")
            parts.append(np.asarray(nodal, float).ravel())
        if self.g_extra:
            if extra is None:
                raise ValueError("this step problem needs the extra nodal vector (co-normal term)")
            parts.append(np.asarray(extra, float).ravel())
        p = np.concatenate([np.asarray(a, float).ravel() for a in parts])
        if p.size != self.np_:
            raise ValueError(f"parameter vector has {p.size} entries, expected {self.np_}")
        return p
