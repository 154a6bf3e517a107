"""Spontaneous curvature (Canham-Helfrich) term of W: turns tau int |Hvec|^2 into tau int |Hvec + c0 n|^2.

With the nested scheme's curvature vector ``Hvec = (Y - X)/tt`` (Y - X ~ tt Delta Y, and Delta X = -h n
with h = k1 + k2 > 0 on a sphere with its outward normal n), the Willmore term of W is
``tau/tt^2 M[X](Y-X).(Y-X) = tau int |Hvec|^2 ~ 2 tau w``. The Helfrich energy
``1/2 int (h - c0)^2 = 1/2 int (Hvec . n + c0)^2`` (sign: h = -Hvec . n) becomes, keeping the tangential
part of Hvec as the Willmore term does, ``1/2 int |Hvec + c0 n|^2``; this term adds the difference

    tau (2 c0 int Hvec . n + c0^2 |X|)  =  tau (2 c0 / tt  sum_T 1/(d+1) sum_{i in T} (Y_i - X_i) . a_T  +  c0^2 |T|)

with a_T = |T| n_T the element's area vector (:func:`~willmore_nlp.model.terms.anisotropic_inner.area_vector`,
polynomial in X), n_T outward for outward-oriented meshes. c0 = 0 adds exact zeros: the Willmore flow
bit for bit. A sphere of radius R has energy 8 pi (1 - c0 R / 2)^2; c0 > 0 favours curvature h = c0.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.fem.element import measure
from willmore_nlp.geometry import require_outward
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.terms.anisotropic_inner import area_vector
from willmore_nlp.model.terms.base import Element, Term


class Helfrich(Term):
    """Spontaneous curvature ``c0`` (scalar parameter): see the module docstring."""

    name = "helfrich"
    label = "spontaneous curvature"
    hint = "use c0=0"
    scalars = ("c0",)
    requires = frozenset({"variational"})

    def __init__(self, c0: float) -> None:
        if isinstance(c0, bool) or not isinstance(c0, (int, float)) or not np.isfinite(c0):
            raise UserInputError(f"c0 must be a finite number (spontaneous curvature), got {c0!r}")
        self.c0 = float(c0)

    def check(self, mesh: Mesh, variant: str | None) -> None:
        if variant is not None or not mesh.is_closed or mesh.m != mesh.d + 1:
            raise MeshError(f"{mesh.source}: c0 (spontaneous curvature) needs a closed curve in R^2 or a closed "
                            f"surface in R^3 (an oriented normal)")
        require_outward(mesh, "c0 (spontaneous curvature)")  # (inward, c0 = 1 flowed as c0 = -1: a new-user check)

    def outer(self, e: Element) -> ca.SX:
        tau, tt, c0 = e.par["tau"], e.par["tt"], e.par["c0"]
        nv = e.X.shape[1]
        hn = ca.dot(ca.sum2(e.Y - e.X), area_vector(e.X)) / (nv * tt)  # int_T Hvec . n
        return tau * (2 * c0 * hn + c0**2 * measure(e.X))

    def values(self, Xk: np.ndarray, tau: float, simplices: np.ndarray, x_free: np.ndarray) -> dict[str, Any]:
        return {"c0": self.c0}
