"""The interface of an energy term of the step problem (docs/guide/terms.md: how to write one)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

CAPABILITIES = frozenset({"variational", "nonlinear_inner", "constraints"})
"""What a step solver may be able to do: minimise W itself (``variational``; the semi-implicit baseline
does not), solve a nonlinear inner equation, handle outer equality constraints."""


@dataclass(frozen=True)
class Element:
    """The symbols of one element inside a kernel.

    Attributes
    ----------
    X, Y, Xk : (m, d + 1) SX, the element's nodal positions (columns = nodes)
    par : scalar parameters by name (SX)
    const : per-element constants by name (SX); :meth:`c` gives 1 for a constant the problem lacks
    nodal : per-node data by name, (width, d + 1) SX
    """

    X: ca.SX
    Y: ca.SX
    Xk: ca.SX
    par: dict[str, ca.SX]
    const: dict[str, ca.SX]
    nodal: dict[str, ca.SX]

    def c(self, name: str) -> ca.SX | float:
        """Per-element constant ``name``, 1.0 when the problem has none (closed meshes)."""
        return self.const.get(name, 1.0)


class Term:
    """One additive part of the step problem.

    A term contributes to the outer objective W (:meth:`outer`), to the inner energy E whose
    half-gradient in Y is the inner constraint g (:meth:`inner`), and/or outer equality
    constraints ``sum_T local - target = 0`` (:meth:`constraints`, one row per name in
    :attr:`constraint_targets`). It names the scalar parameters and per-node data it reads
    (:attr:`scalars`, :attr:`nodal`) and supplies their values for a step (:meth:`values`).

    Attributes
    ----------
    name : short identifier (also part of the problem's name, which keys compiled kernels)
    label : what a user calls it (for messages)
    hint : how a user switches it off (for messages)
    scalars : scalar parameters beyond tau, tt, lam
    nodal : (name, width) per-node data blocks
    vectors : (N, m) nodal vectors added to g as ``-tt * b`` on the free-Y rows
    constraint_targets : scalar parameter holding the target of each constraint row
    requires : solver capabilities (:data:`CAPABILITIES`) the term needs; by default ``variational``: only the
        solvers that minimise the step problem itself carry a term they do not know (the semi-implicit baseline
        has its own formulas and would drop it); the built-in terms it carries declare less
    nonlinear_inner : the inner energy is not quadratic in Y
    weight : name of a per-element constant that multiplies :meth:`outer` ("" for none); the
        problem sums the terms of one weight first and multiplies the sum once
    moebius_invariant : the term leaves the energy of a closed surface's step Moebius invariant (it adds nothing
        to W but the Willmore energy, or only the inner energy, the distance or a constraint). Where every term
        says so (and lam = 0) the flow treats the step's drift along the conformal fields, the zero modes of W, as
        motion to undo (``rest_dilation``, the drift rule) and ``relax`` watches W; a term that changes W otherwise
        (an area or a curvature term) leaves it False, the default, so that its own dilation is kept.
    """

    name = "term"
    label = "term"
    hint = ""
    scalars: tuple[str, ...] = ()
    nodal: tuple[tuple[str, int], ...] = ()
    vectors: tuple[str, ...] = ()
    constraint_targets: tuple[str, ...] = ()
    requires: frozenset[str] = frozenset({"variational"})
    nonlinear_inner = False
    weight = ""
    moebius_invariant = False

    def check(self, mesh: Any, variant: str | None) -> None:
        """Raise MeshError/UserInputError when the term does not support ``mesh`` or the boundary ``variant``
        (None: closed mesh; "conormal" or "ring": clamped boundary)."""

    def outer(self, e: Element) -> ca.SX | float:
        """Element contribution to W."""
        return 0.0

    def inner(self, e: Element) -> ca.SX | float:
        """Element contribution to E (g = 1/2 dE/dY)."""
        return 0.0

    def constraints(self, e: Element) -> list[ca.SX]:
        """Element contributions to the outer constraints, one per :attr:`constraint_targets`."""
        return []

    def values(self, Xk: np.ndarray, tau: float, simplices: np.ndarray, x_free: np.ndarray) -> dict[str, Any]:
        """Values of :attr:`scalars`, :attr:`nodal` and :attr:`vectors` for a step from Xk.

        ``simplices`` are all simplices of the mesh, ``x_free`` the (N,) free-node mask.
        """
        return {}
