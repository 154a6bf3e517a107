"""Outer equality constraints of closed meshes: enclosed volume V[X] = V0 and total area A[X] = A0."""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.fem.element import measure
from willmore_nlp.geometry import require_outward
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.terms.base import Element, Term


# --8<-- [start:constraint]
class _Constraint(Term):
    """An outer equality constraint ``sum_T local - target = 0`` whose target is the scalar :attr:`scalars` [0]."""

    requires = frozenset({"constraints"})
    what = ""

    def __init__(self, target: float) -> None:
        self.target = target  # (checked by :meth:`check`, after the mesh: "initial" of an open mesh is nan)

    def check(self, mesh: Mesh, variant: str | None) -> None:
        self._check_mesh(mesh, variant)
        target = self.target
        if isinstance(target, bool) or not isinstance(target, (int, float)) or not (np.isfinite(target) and target > 0):
            raise UserInputError(f"{self.what} must be a positive number, \"initial\" or None, got {target!r}")
        self.target = float(target)

    def _check_mesh(self, mesh: Mesh, variant: str | None) -> None:
        raise NotImplementedError

    def values(self, Xk: np.ndarray, tau: float, simplices: np.ndarray, x_free: np.ndarray) -> dict[str, Any]:
        return {self.scalars[0]: self.target}


class VolumeConstraint(_Constraint):
    """``sum_T det(X_0, ..., X_d) / (d + 1)! = V0``: the signed enclosed volume (area for a curve in R^2),
    positive for outward-oriented meshes. Target: scalar ``volume0``."""

    name = "vol"
    label = "volume constraint"
    moebius_invariant = True
    hint = "leave volume out (no --set/--option volume or config key; volume=None in Python)"
    what = "volume"
    scalars = ("volume0",)
    constraint_targets = ("volume0",)

    def _check_mesh(self, mesh: Mesh, variant: str | None) -> None:
        if variant is not None or not mesh.is_closed or mesh.m != mesh.d + 1:
            raise MeshError(f"{mesh.source}: volume needs a closed curve in R^2 or a closed surface in R^3")
        require_outward(mesh, "the volume constraint")

    def constraints(self, e: Element) -> list[ca.SX]:
        X = e.X
        if X.shape[1] == 2:
            return [0.5 * (X[0, 0] * X[1, 1] - X[1, 0] * X[0, 1])]
        return [ca.dot(X[:, 0], ca.cross(X[:, 1], X[:, 2])) / 6]
# --8<-- [end:constraint]


class AreaConstraint(_Constraint):
    """``sum_T |T| = A0`` (length for a curve). Target: scalar ``area0``."""

    name = "are"
    label = "area constraint"
    moebius_invariant = True
    hint = "leave area out (no --set/--option area or config key; area=None in Python)"
    what = "area"
    scalars = ("area0",)
    constraint_targets = ("area0",)

    def _check_mesh(self, mesh: Mesh, variant: str | None) -> None:
        if variant is not None or not mesh.is_closed:
            raise MeshError(f"{mesh.source}: area needs a closed curve or surface")

    def constraints(self, e: Element) -> list[ca.SX]:
        return [measure(e.X)]
