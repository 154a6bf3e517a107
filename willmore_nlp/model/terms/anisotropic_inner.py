"""Inner energy of the fully nonlinear anisotropic scheme (paper (3.3)): E_T = M(Y-X).(Y-X) + 2 tt gamma(z_T(Y))."""

from __future__ import annotations

import casadi as ca

from willmore_nlp.anisotropy import Anisotropy
from willmore_nlp.errors import UserInputError
from willmore_nlp.fem.element import mass_matrix, quad
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.terms.base import Element, Term


def area_vector(Y: ca.SX) -> ca.SX:
    """|T| n_T of a simplex: ``rot90(Y1 - Y0)`` for a segment in R^2, ``(Y1 - Y0) x (Y2 - Y0) / 2`` for a triangle.

    Outward for counter-clockwise curves and outward-oriented surfaces; polynomial in Y (no division).
    """
    if Y.shape[1] == 2:
        e = Y[:, 1] - Y[:, 0]
        return ca.vertcat(e[1], -e[0])
    return 0.5 * ca.cross(Y[:, 1] - Y[:, 0], Y[:, 2] - Y[:, 0])


class AnisotropicInner(Term):
    """``E_T = M[X](Y-X).(Y-X) + 2 tt gamma(z_T)``, z_T = :func:`area_vector` (gamma 1-homogeneous,
    so gamma(z_T) = |T| gamma(n_T)). The outer objective stays the isotropic one: the approximate
    Willmore term measures Y - X, now the anisotropic mean-curvature step. Closed meshes, or a clamped
    patch with the fixed-ring variant (A_gamma over patch and ring); the co-normal variant is refused:
    its co-normal term would have to be gamma's Cahn-Hoffman vector."""

    label = "anisotropy"
    hint = "the semi-implicit baseline is isotropic"
    requires = frozenset({"nonlinear_inner"})
    nonlinear_inner = True

    def __init__(self, anisotropy: Anisotropy) -> None:
        self.anisotropy = anisotropy
        self.name = f"aniso_{anisotropy.name}"

    def check(self, mesh: Mesh, variant: str | None) -> None:
        if variant == "conormal":
            raise UserInputError("anisotropy: the co-normal boundary variant is not supported with anisotropy "
                                 "(its co-normal term would be gamma's Cahn-Hoffman vector); use the ring variant: "
                                 "Boundary(free, \"ring\") in Python, --set clamp=ring for a mesh file, --set "
                                 "variant=ring for a clamped registered problem")
        if variant is None and not mesh.is_closed:
            raise MeshError(f"{mesh.source}: anisotropic flow needs a closed curve or surface")
        if mesh.d == 1 and mesh.m != 2:
            raise MeshError(f"{mesh.source}: anisotropic curve flow needs a curve in R^2 (the normal of a curve "
                            f"in R^{mesh.m} is not a vector), got R^{mesh.m}")

    def inner(self, e: Element) -> ca.SX:
        return quad(mass_matrix(e.X), e.Y - e.X, e.Y - e.X) + 2 * e.par["tt"] * self.anisotropy.gamma(area_vector(e.Y))
