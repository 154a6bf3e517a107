"""Length/area energy of W: 2 tau lam A[X] (the paper's length energy lam a[x], Sec. 5.2)."""

from __future__ import annotations

import casadi as ca

from willmore_nlp.fem.element import measure
from willmore_nlp.model.terms.base import Element, Term


class AreaEnergy(Term):
    """``patch * 2 tau lam |T|`` (``patch`` = 0 on the fixed ring of a clamped boundary)."""

    name = "area"
    label = "length/area energy"
    requires: frozenset[str] = frozenset()  # (the semi-implicit baseline carries it)
    moebius_invariant = True  # (lam A: the flow checks lam itself)
    weight = "patch"

    def outer(self, e: Element) -> ca.SX:
        return 2 * e.par["tau"] * e.par["lam"] * measure(e.X)
