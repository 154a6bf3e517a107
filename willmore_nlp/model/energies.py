"""Element energies of the nested scheme (DESIGN.md section 1), one function per variant.

Each takes the element's nodal matrices X, Y, Xk ((m, d+1) SX), the scalar parameters
``par = (tau, tt, lam, ...)`` and the per-element constants ``c``, and returns the local
outer objective ``w_T`` and inner energy ``e_T``:

    W = M[Xk](X-Xk).(X-Xk) + tau/tt^2 M[X](Y-X).(Y-X) + 2 tau lam A[X]
    E = M[X](Y-X).(Y-X) + tt L[X] Y.Y                      (isotropic)
    E = M[X](Y-X).(Y-X) + 2 tt A_gamma[Y]                  (anisotropic)

The constraint of the NLP is g = 1/2 dE/dY = (M + tt L) Y - M X (isotropic).
"""

from __future__ import annotations

import casadi as ca

from willmore_nlp.fem.element import mass_matrix, measure, quad, stiffness_matrix


def outer_objective(X: ca.SX, Y: ca.SX, Xk: ca.SX, par: ca.SX) -> ca.SX:
    """Local W_T: squared distance to Xk, approximate Willmore term and length/area energy."""
    tau, tt, lam = par[0], par[1], par[2]
    M = mass_matrix(X)
    Mk = mass_matrix(Xk)
    return quad(Mk, X - Xk, X - Xk) + tau / tt**2 * quad(M, Y - X, Y - X) + 2 * tau * lam * measure(X)


def isotropic_inner(X: ca.SX, Y: ca.SX, tt: ca.SX) -> ca.SX:
    """Local E_T of the linearised (Dziuk) mean-curvature step: M(Y-X).(Y-X) + tt L Y.Y."""
    return quad(mass_matrix(X), Y - X, Y - X) + tt * quad(stiffness_matrix(X), Y, Y)


def isotropic(X: ca.SX, Y: ca.SX, Xk: ca.SX, par: ca.SX, c: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Isotropic closed-surface energies; ``c[0]``, if present, weights W_T (0 on a fixed ring)."""
    w = outer_objective(X, Y, Xk, par)
    if c.numel() > 0:
        w = c[0] * w
    return w, isotropic_inner(X, Y, par[1])
