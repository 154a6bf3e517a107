"""Tangential-control term of W (:mod:`willmore_nlp.tangential`): beta_c sum_i m_i |P_i (X_i - Xk_i - S_i)|^2."""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from willmore_nlp.fem.element import measure
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.terms.base import Element, Term
from willmore_nlp.tangential import SUBSTEPS, TangentialControl, n_nodal, nodal_parameters


class TangentialControlTerm(Term):
    """``patch * beta_c |T_k| / (d+1) sum_{i in T} |P_i (X_i - Xk_i - S_i)|^2``.

    Summed over the elements it is ``beta_c sum_i m_i |P_i (X_i - Xk_i - S_i)|^2`` with m_i the lumped
    mass of node i in Xk. The per-node data ``control`` is (m*m + m) per node: the row-major vertex
    tangent projector P_i and the tangential target S_i (:func:`willmore_nlp.tangential.nodal_parameters`).
    The gradient in X_i, ``2 m_i P_i (X_i - Xk_i - S_i)``, is tangent at node i, so the normal
    component of each nodal equation of the step is left as it was. ``beta_c`` is the scalar
    ``control_weight``.
    """

    label = "tangential control"
    moebius_invariant = True
    weight = "patch"
    hint = "use tangential_control=off"
    scalars = ("control_weight",)
    requires = frozenset({"variational"})

    def __init__(self, control: TangentialControl, m: int) -> None:
        if not isinstance(control, TangentialControl):
            raise TypeError(f"tangential_control must be a TangentialControl, got {type(control).__name__}")
        self.control = control
        self.name = control.tag.lstrip("_")
        self.nodal = (("control", n_nodal(m)),)

    def check(self, mesh: Mesh, variant: str | None) -> None:
        if mesh.d == 2 and mesh.m != 3:
            raise MeshError(f"{mesh.source}: tangential_control needs surfaces in R^3, got R^{mesh.m}")

    def outer(self, e: Element) -> ca.SX:
        m, nv = e.X.shape
        Q = e.nodal["control"]
        total = 0
        for i in range(nv):
            P = ca.reshape(Q[0 : m * m, i], m, m)  # symmetric: row- and column-major agree
            r = ca.mtimes(P, e.X[:, i] - e.Xk[:, i] - Q[m * m : m * m + m, i])
            total = total + ca.dot(r, r)
        return e.par["control_weight"] * (measure(e.Xk) / nv * total)

    def values(self, Xk: np.ndarray, tau: float, simplices: np.ndarray, x_free: np.ndarray) -> dict[str, Any]:
        """The weight and :func:`~willmore_nlp.tangential.nodal_parameters` at Xk (four mean-ratio sub-steps: the
        flow asks for them only for its steps; its inner solves, constraints and energy pack them as zeros, ``off``
        of :meth:`~willmore_nlp.model.step.StepProblem.pack_p`)."""
        Q = nodal_parameters(np.asarray(Xk, float), simplices, x_free, self.control.fraction(tau), SUBSTEPS)
        return {"control_weight": self.control.weight, "control": Q}
