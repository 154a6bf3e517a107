"""Approximate Willmore term of W: tau/tt^2 M[X](Y-X).(Y-X) = tau int |(Y - X)/tt|^2 ~ 2 tau w."""

from __future__ import annotations

import casadi as ca

from willmore_nlp.fem.element import mass_matrix, quad
from willmore_nlp.model.terms.base import Element, Term


class Willmore(Term):
    """``tau/tt^2 M[X](Y-X).(Y-X)`` on every element, the fixed ring of a clamped boundary included."""

    name = "willmore"
    label = "Willmore energy"
    requires: frozenset[str] = frozenset()  # (the semi-implicit baseline carries it)
    moebius_invariant = True

    def outer(self, e: Element) -> ca.SX:
        return e.par["tau"] / e.par["tt"] ** 2 * quad(mass_matrix(e.X), e.Y - e.X, e.Y - e.X)
