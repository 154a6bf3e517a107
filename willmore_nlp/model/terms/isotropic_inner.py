"""Inner energy of the linearised (Dziuk) mean-curvature step: E_T = M(Y-X).(Y-X) + stiff tt L Y.Y."""

from __future__ import annotations

import casadi as ca

from willmore_nlp.fem.element import mass_matrix, quad, stiffness_matrix
from willmore_nlp.model.terms.base import Element, Term


class IsotropicInner(Term):
    """``g = (M + tt L) Y - M X``; ``stiff`` (per element) is 0 on the ring of the co-normal variant,
    where the co-normal term (:class:`~willmore_nlp.model.terms.conormal.Conormal`) replaces the
    ring's stiffness. Ring elements keep their mass so that the boundary nodes carry their full
    mass (docs/theory/pitfalls.md, 'Boundary weights')."""

    name = "iso"
    label = "isotropic inner energy"
    requires: frozenset[str] = frozenset()  # (the semi-implicit baseline carries it)
    moebius_invariant = True

    def inner(self, e: Element) -> ca.SX:
        return quad(mass_matrix(e.X), e.Y - e.X, e.Y - e.X) + e.c("stiff") * e.par["tt"] * quad(
            stiffness_matrix(e.X), e.Y, e.Y)
