"""Co-normal term of the clamped boundary's first variant: g -= tt Nco on the free-Y rows."""

from __future__ import annotations

from typing import Any

import numpy as np

from willmore_nlp.model.terms.base import Term


class Conormal(Term):
    """The prescribed co-normal ``Nco_i = int_{boundary} N^co Phi_i`` (:mod:`willmore_nlp.boundary`),
    the nodal vector ``conormal``: it stands for the stiffness of the outer ring (whose elements
    carry ``stiff = 0``). Its inner energy would be ``-2 tt Nco . Y``; being nodal, not per element,
    it is added to g directly."""

    name = ""
    label = "co-normal boundary term"
    requires: frozenset[str] = frozenset()  # (the semi-implicit baseline carries it)
    moebius_invariant = True
    vectors = ("conormal",)

    def __init__(self, nco: np.ndarray) -> None:
        self.nco = np.asarray(nco, float)

    def values(self, Xk: np.ndarray, tau: float, simplices: np.ndarray, x_free: np.ndarray) -> dict[str, Any]:
        return {"conormal": self.nco}
