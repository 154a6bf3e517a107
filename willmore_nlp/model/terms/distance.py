"""Distance term of W: the squared (optionally tangentially weighted) distance of X to Xk."""

from __future__ import annotations

import casadi as ca

from willmore_nlp.errors import UserInputError
from willmore_nlp.fem.element import mass_matrix, quad, tangent_projector
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.terms.base import Element, Term
from willmore_nlp.settings import MAX_TANGENTIAL_WEIGHT


class Distance(Term):
    """``patch * (int_T |D|^2 + (beta - 1) |P_T D|^2)``, D = X - Xk, P_T the tangent projector of T in Xk.

    ``beta = 1`` is the paper's M[Xk](X-Xk).(X-Xk). ``beta > 1`` charges the tangential part of the
    displacement beta times: the normal velocity (the geometric flow as h -> 0) is unchanged, but
    nodes can no longer slide to where the discrete energy rewards them (docs/guide/anisotropy.md).
    ``patch`` (per element) is 0 on the fixed outer ring of a clamped boundary, where the term is constant.
    """

    name = "dist"
    label = "tangential weight"
    moebius_invariant = True
    weight = "patch"
    hint = "use tangential_weight=1"

    def __init__(self, beta: float = 1.0) -> None:
        beta = float(beta)
        if not (beta == beta and 1.0 <= beta <= MAX_TANGENTIAL_WEIGHT):
            raise UserInputError(f"tangential_weight must be a number in [1, {MAX_TANGENTIAL_WEIGHT:g}] (1 = the "
                                 f"paper's L^2 distance), got {beta!r}")
        self.beta = beta
        self.requires = frozenset() if beta == 1.0 else frozenset({"variational"})
        # (kernel names must be identifiers: f"tw{beta:g}" made "tw1.5", which CasADi refused, exit 70)
        tag = str(int(beta)) if beta.is_integer() and beta < 1e15 else \
            repr(beta).replace(".", "p").replace("+", "").replace("-", "m")
        self.name = "" if beta == 1.0 else f"tw{tag}"

    def check(self, mesh: Mesh, variant: str | None) -> None:
        if self.beta != 1.0 and mesh.d == 2 and mesh.m != 3:
            raise MeshError(f"{mesh.source}: tangential_weight needs surfaces in R^3, got R^{mesh.m}")

    def outer(self, e: Element) -> ca.SX:
        Mk = mass_matrix(e.Xk)
        dist = quad(Mk, e.X - e.Xk, e.X - e.Xk)
        if self.beta == 1.0:
            return dist
        D = e.X - e.Xk
        return dist + (self.beta - 1.0) * quad(Mk, ca.mtimes(tangent_projector(e.Xk), D), D)
