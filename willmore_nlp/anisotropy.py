"""Anisotropies gamma for the fully nonlinear anisotropic scheme (paper Secs. 2.3, 3.3).

An anisotropy is a positive, 1-homogeneous function gamma(z) of the (unnormalised) normal z in
R^2 (curves in the plane) or R^3 (surfaces), written with CasADi operations so that the step
problem differentiates it symbolically (gradient, Hessian and, through the Lagrangian, third
derivatives). The anisotropic area is ``A_gamma[X] = sum_T |T| gamma(n_T)``; by homogeneity
``|T| gamma(n_T) = gamma(z_T)`` with ``z_T = rot90(X1 - X0)`` for a segment (the outward normal of a
counter-clockwise curve, rotated clockwise) and ``z_T = (X1 - X0) x (X2 - X0) / 2`` for a triangle.

Presets (paper Sec. 5.3 and their 3-D analogues): ``gamma0`` = |z| (isotropic), ``gamma1`` =
sqrt(z1^2 + 4 z2^2) (Wulff shape: the ellipse x1^2 + x2^2/4 <= 1, elongated along x2; in 3-D
sqrt(z1^2 + 4 z2^2 + z3^2)), ``gamma2`` = sum_i sqrt(1e-7 |z|^2 + z_i^2) (regularised l1 norm,
Wulff shape close to the axis-aligned square / cube; ``"gamma2:EPS"`` picks another regularisation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.fem.assembly import lumped_mass
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.topology import scatter_sum
from willmore_nlp.mesh.validate import face_normals

GammaFn = Callable[[ca.SX], ca.SX]
"""gamma(z) for a column z (m x 1, CasADi SX/DM) -> scalar."""


class AnisotropyError(UserInputError):
    """An anisotropy is not positive or not 1-homogeneous; the message names the failing direction."""


def _gamma0(z: ca.SX) -> ca.SX:
    return ca.sqrt(ca.sumsqr(z))


def _gamma1(z: ca.SX) -> ca.SX:
    w = [1.0, 4.0, 1.0][: z.numel()]
    return ca.sqrt(sum(w[i] * z[i] ** 2 for i in range(z.numel())))


def regularized_l1(eps: float = 1e-7) -> GammaFn:
    """gamma(z) = sum_i sqrt(eps |z|^2 + z_i^2), the paper's gamma2 for eps = 1e-7.

    The kinks of the l1 norm are smoothed over normal angles of about sqrt(eps); where that is far
    below the angle between neighbouring element normals the discrete problem is effectively
    non-smooth (see docs/guide/anisotropy.md).
    """
    if not (np.isfinite(eps) and eps > 0):
        raise AnisotropyError(f"gamma2: the regularisation eps must be > 0, got {eps!r}")

    def gamma(z: ca.SX) -> ca.SX:
        r = eps * ca.sumsqr(z)
        return sum(ca.sqrt(r + z[i] ** 2) for i in range(z.numel()))

    return gamma


_gamma2 = regularized_l1(1e-7)


PRESETS: dict[str, GammaFn] = {"gamma0": _gamma0, "gamma1": _gamma1, "gamma2": _gamma2}
"""Preset anisotropies by name; each works in R^2 and R^3."""


@dataclass(frozen=True, eq=False)
class Anisotropy:
    """A validated anisotropy gamma on R^m.

    Parameters
    ----------
    gamma : callable
        gamma(z) with z an (m, 1) CasADi SX; use CasADi operations (``ca.sqrt``, ``ca.fabs``, ...).
    m : int
        Dimension of z: 2 for curves in R^2, 3 for surfaces in R^3.
    name : str
        Identifier used in kernel names and reports.
    """

    gamma: GammaFn
    m: int
    name: str = "custom"
    fn: ca.Function = field(init=False, repr=False)
    grad: ca.Function = field(init=False, repr=False)
    scale: float = field(init=False, repr=False)
    """The largest gamma(n) over the unit normals :func:`validate` samples (gamma0: 1, gamma1: 2)."""

    def __post_init__(self) -> None:
        if self.m not in (2, 3):
            raise AnisotropyError(f"anisotropy {self.name}: dimension must be 2 or 3, got {self.m}")
        if not self.name.isidentifier():
            raise AnisotropyError(f"anisotropy name must be an identifier, got {self.name!r}")
        z = ca.SX.sym("z", self.m)
        try:
            g = self.gamma(z)
        except (TypeError, ValueError, RuntimeError, AttributeError) as exc:
            raise AnisotropyError(f"anisotropy {self.name}: gamma(z) fails on a CasADi symbol "
                                  f"(write it with casadi operations): {exc}") from exc
        g = ca.SX(g)
        if g.numel() != 1:
            raise AnisotropyError(f"anisotropy {self.name}: gamma(z) must be a scalar, got shape {g.shape}")
        object.__setattr__(self, "fn", ca.Function(f"gamma_{self.name}", [z], [g]))
        object.__setattr__(self, "grad", ca.Function(f"dgamma_{self.name}", [z], [ca.gradient(g, z)]))
        validate(self)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """gamma at the rows of ``z`` ((n, m) numpy) -> (n,)."""
        Z = np.atleast_2d(np.asarray(z, float))
        return np.asarray(self.fn.map(Z.shape[0])(Z.T)).ravel()

    def gradient(self, z: np.ndarray) -> np.ndarray:
        """Gradient of gamma at the rows of ``z`` ((n, m)) -> (n, m)."""
        Z = np.atleast_2d(np.asarray(z, float))
        return np.asarray(self.grad.map(Z.shape[0])(Z.T)).T


def validate(an: Anisotropy, n_samples: int = 2000, seed: int = 0) -> None:
    """Check positivity on the unit sphere and 1-homogeneity gamma(s z) = s gamma(z) numerically, and set
    ``an.scale`` (the largest gamma on the sampled unit vectors).

    Raises
    ------
    AnisotropyError
        Naming the first failing direction and value.
    """
    rng = np.random.default_rng(seed)
    Z = rng.normal(size=(n_samples, an.m))
    axes = np.vstack([np.eye(an.m), -np.eye(an.m)])
    Z = np.vstack([axes, Z / np.linalg.norm(Z, axis=1, keepdims=True)])
    g = an(Z)
    bad = np.flatnonzero(~np.isfinite(g) | (g <= 1e-12))
    if bad.size:
        i = bad[0]
        raise AnisotropyError(f"anisotropy {an.name} is not positive on the unit sphere: "
                              f"gamma({np.round(Z[i], 4).tolist()}) = {g[i]:.3g}")
    for s in (0.01, 0.5, 3.0, 100.0):
        gs = an(s * Z)
        err = np.abs(gs - s * g) / (s * g)
        i = int(np.argmax(err))
        if err[i] > 1e-6:
            raise AnisotropyError(f"anisotropy {an.name} is not 1-homogeneous: gamma({s:g} z) = {gs[i]:.6g} but "
                                  f"{s:g} gamma(z) = {s * g[i]:.6g} at z = {np.round(Z[i], 4).tolist()}")
    object.__setattr__(an, "scale", float(g.max()))


def get_anisotropy(spec: str | Anisotropy | GammaFn, m: int) -> Anisotropy:
    """An :class:`Anisotropy` on R^m from a preset name, a callable or an Anisotropy (checked for m).

    Strings: ``"gamma0"``, ``"gamma1"``, ``"gamma2"`` or ``"gamma2:EPS"`` (regularised l1 norm with
    regularisation EPS instead of the paper's 1e-7).
    """
    if isinstance(spec, Anisotropy):
        if spec.m != m:
            raise AnisotropyError(f"anisotropy {spec.name} is defined on R^{spec.m}, the normals live in R^{m}")
        return spec
    if isinstance(spec, str):
        if spec.startswith("gamma2:"):
            try:
                eps = float(spec.split(":", 1)[1])
            except ValueError:
                raise AnisotropyError(f"anisotropy {spec!r}: write gamma2:EPS with a number EPS > 0") from None
            return Anisotropy(regularized_l1(eps), m, "gamma2_eps" + f"{eps:.0e}".replace("-", "m").replace("+", ""))
        if spec not in PRESETS:
            raise AnisotropyError(f"unknown anisotropy {spec!r}; presets: {', '.join(PRESETS)} "
                                  f"(and gamma2:EPS for another regularisation)")
        return Anisotropy(PRESETS[spec], m, spec)
    if callable(spec):
        return Anisotropy(spec, m, getattr(spec, "__name__", "custom").strip("_<>") or "custom")
    raise AnisotropyError(f"anisotropy must be a preset name, a callable or an Anisotropy, got {type(spec).__name__}")


def element_normal(X: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(K, m) unnormalised normals z_T: rot90(X1 - X0) for segments in R^2, cross/2 for triangles."""
    X = np.asarray(X, float)
    if S.shape[1] == 2:
        e = X[S[:, 1]] - X[S[:, 0]]
        return np.column_stack([e[:, 1], -e[:, 0]])
    return 0.5 * face_normals(X, S)


def anisotropic_area(an: Anisotropy, X: np.ndarray, S: np.ndarray) -> float:
    """A_gamma[X] = sum_T gamma(z_T)."""
    return float(an(element_normal(X, S)).sum())


def anisotropic_area_gradient(an: Anisotropy, X: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(N, m) gradient of A_gamma with respect to the vertex positions (numpy chain rule)."""
    X = np.asarray(X, float)
    G = an.gradient(element_normal(X, S))
    N = X.shape[0]
    if S.shape[1] == 2:
        g1 = np.column_stack([-G[:, 1], G[:, 0]])  # d gamma(rot(X1 - X0)) / d X1 = rot^T grad
        return scatter_sum(N, [(S[:, 1], g1), (S[:, 0], -g1)])
    e1, e2 = X[S[:, 1]] - X[S[:, 0]], X[S[:, 2]] - X[S[:, 0]]
    g1 = 0.5 * np.cross(e2, G)
    g2 = 0.5 * np.cross(G, e1)
    return scatter_sum(N, [(S[:, 1], g1), (S[:, 2], g2), (S[:, 0], -(g1 + g2))])


GAMMA1_WULFF_AXES = np.array([1.0, 2.0, 1.0])
"""Semi-axes of gamma1's unit Wulff shape in R^3, the ellipsoid x1^2 + x2^2 / 4 + x3^2 <= 1."""


def gamma1_wulff_energy() -> float:
    """w_gamma of every Wulff shape of gamma1 in R^3, its least value among closed surfaces: its anisotropic mean
    curvature is 2 / R, so w_gamma = 1/2 int h_gamma^2 dA (:func:`anisotropic_willmore_energy`, the Euclidean area
    element) = 1/2 (2/R)^2 |W_R| = 2 |W_1| (|W_R| = R^2 |W_1| the Euclidean area), twice the area of the prolate
    spheroid with semi-axes 1, 2, 1 (42.9569). (It read "1/2 (2/R)^2 |W_R|_gamma, |W_R|_gamma = 3 vol / R", which gives
    6 vol(W_1) = 16 pi: a new user's check; the value was right. Nodes on the Wulff shape: 42.767 / 42.909 / 42.945 at
    642 / 2,562 / 10,242 vertices.)"""
    from willmore_nlp.mesh.shapes import spheroid_area_volume

    return 2 * spheroid_area_volume(GAMMA1_WULFF_AXES[0], GAMMA1_WULFF_AXES[1])[0]


def gamma1_wulff_gauge(X: np.ndarray) -> np.ndarray:
    """(N,) the Wulff gauge sqrt(x1^2 + x2^2 / 4 + x3^2) of the points X ((N, 3)) about their centroid (1 on the
    unit Wulff shape of gamma1 centred there)."""
    Y = np.asarray(X, float) - np.mean(X, axis=0)
    return np.sqrt(((Y / GAMMA1_WULFF_AXES) ** 2).sum(axis=1))


def gamma1_wulff_nodes(X: np.ndarray) -> np.ndarray:
    """(N, 3) the points X ((N, 3)) moved along rays from their centroid onto the unit Wulff shape of gamma1 centred
    there (:func:`gamma1_wulff_gauge` 1): the mesh-matched Wulff shape of a mesh with these vertices."""
    X = np.asarray(X, float)
    c = X.mean(axis=0)
    return c + (X - c) / gamma1_wulff_gauge(X)[:, None]


def anisotropic_willmore_energy(mesh: Mesh, an: Anisotropy, nodes: np.ndarray | None = None) -> float:
    """w_gamma = 1/2 int h_gamma^2, independent of the scheme.

    h_gamma is the anisotropic mean curvature, the first variation of A_gamma: nodally
    ``h_gamma_i = |grad_i A_gamma| / m_i`` with the lumped mass m_i, so
    ``w_gamma = 1/2 sum_i |grad_i A_gamma|^2 / m_i`` (for gamma0 this is
    :func:`willmore_nlp.geometry.willmore_energy`, as grad A = L X), over the interior vertices, or over
    ``nodes`` ((N,) bool, e.g. a clamped patch and its boundary nodes) among them.
    """
    V, S = np.asarray(mesh.vertices), np.asarray(mesh.simplices)
    G = anisotropic_area_gradient(an, V, S)
    e = 0.5 * np.sum(G**2, axis=1) / lumped_mass(V, S)
    if not mesh.is_closed:
        e[mesh.boundary_vertices] = 0.0
    if nodes is not None:
        e = e[np.asarray(nodes, bool)]
    return float(e.sum())
