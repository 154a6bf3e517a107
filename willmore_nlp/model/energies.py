"""Element energies of the nested scheme (docs/theory/scheme.md), one function per variant.

Each takes the element's nodal matrices X, Y, Xk ((m, d+1) SX), the scalar parameters
``par = (tau, tt, lam, ...)`` and the per-element constants ``c``, and returns the local
outer objective ``w_T`` and inner energy ``e_T``:

    W = M[Xk](X-Xk).(X-Xk) + tau/tt^2 M[X](Y-X).(Y-X) + 2 tau lam A[X]
    E = M[X](Y-X).(Y-X) + tt L[X] Y.Y                      (isotropic)

With a tangential weight beta != 1 (:func:`distance`) the first term of W becomes
``sum_T int_T |X-Xk|^2 + (beta - 1) |P_T (X-Xk)|^2`` (P_T the tangent projector of T in Xk).
With tangential control (:func:`control_term`, :mod:`willmore_nlp.tangential`) W gains
``beta_c sum_i m_i |P_i (X_i - Xk_i - S_i)|^2`` (P_i the vertex tangent projector, S_i a tangential target).
    E = M[X](Y-X).(Y-X) + 2 tt A_gamma[Y]                  (anisotropic)

The constraint of the NLP is g = 1/2 dE/dY = (M + tt L) Y - M X (isotropic).
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca

from willmore_nlp.fem.element import mass_matrix, measure, quad, stiffness_matrix, tangent_projector


def distance(X: ca.SX, Xk: ca.SX, beta: float = 1.0) -> ca.SX:
    """Local squared distance of X to Xk: ``int_T |D|^2 + (beta - 1) |P_T D|^2`` with D = X - Xk.

    ``beta = 1`` is the paper's L^2 distance M[Xk](X-Xk).(X-Xk). ``beta > 1`` charges the
    tangential part of the displacement (P_T, the tangent projector of the element in Xk) beta
    times: the normal velocity, and with it the geometric flow in the limit h -> 0, is the same,
    but nodes can no longer slide along the curve or surface to where the discrete energy rewards
    them (the clustering of the nearly crystalline anisotropy gamma2; README, "Anisotropic flow").
    """
    Mk = mass_matrix(Xk)
    dist = quad(Mk, X - Xk, X - Xk)
    if beta == 1.0:
        return dist
    D = X - Xk
    return dist + (beta - 1.0) * quad(Mk, ca.mtimes(tangent_projector(Xk), D), D)


def control_term(X: ca.SX, Xk: ca.SX, Q: ca.SX) -> ca.SX:
    """Local tangential-control term ``|T_k| / (d+1) sum_{i in T} |P_i (X_i - Xk_i - S_i)|^2``.

    Summed over the elements it is ``sum_i m_i |P_i (X_i - Xk_i - S_i)|^2`` with m_i the lumped
    mass of node i in Xk. ``Q`` is (m*m + m, d+1): per node the row-major vertex tangent projector
    P_i and the tangential target S_i (:func:`willmore_nlp.tangential.nodal_parameters`). The
    gradient in X_i, ``2 m_i P_i (X_i - Xk_i - S_i)``, is tangent at node i, so the normal
    component of each nodal equation of the step is left as it was.
    """
    m, nv = X.shape
    total = 0
    for i in range(nv):
        P = ca.reshape(Q[0 : m * m, i], m, m)  # symmetric: row- and column-major agree
        r = ca.mtimes(P, X[:, i] - Xk[:, i] - Q[m * m : m * m + m, i])
        total = total + ca.dot(r, r)
    return measure(Xk) / nv * total


def outer_objective(X: ca.SX, Y: ca.SX, Xk: ca.SX, par: ca.SX, patch: ca.SX | float = 1.0,
                    beta: float = 1.0, Q: ca.SX | None = None) -> ca.SX:
    """Local W_T: squared distance to Xk (:func:`distance`), approximate Willmore term and length/area energy.

    ``patch`` weights the distance and length/area terms: 0 on the fixed outer ring of a clamped
    boundary, where they are constant; the Willmore term always counts (see :func:`isotropic`).
    With per-node control data ``Q`` (non-empty), ``par[3]`` is the control weight beta_c of
    :func:`control_term`, which is added (also weighted by ``patch``).
    """
    tau, tt, lam = par[0], par[1], par[2]
    M = mass_matrix(X)
    local = distance(X, Xk, beta) + 2 * tau * lam * measure(X)
    if Q is not None and Q.numel() > 0:
        local = local + par[3] * control_term(X, Xk, Q)
    return patch * local + tau / tt**2 * quad(M, Y - X, Y - X)


def isotropic_inner(X: ca.SX, Y: ca.SX, tt: ca.SX, stiff: ca.SX | float = 1.0) -> ca.SX:
    """Local E_T of the linearised (Dziuk) mean-curvature step: M(Y-X).(Y-X) + tt L Y.Y.

    ``stiff`` weights the stiffness term (0 on the outer ring of the co-normal variant).
    """
    return quad(mass_matrix(X), Y - X, Y - X) + stiff * tt * quad(stiffness_matrix(X), Y, Y)


def isotropic(beta: float = 1.0) -> Callable[..., tuple[ca.SX, ca.SX]]:
    """Energies of the isotropic scheme with tangential weight ``beta`` (:func:`distance`).

    Per-element constants ``c`` are empty for closed meshes; for clamped boundaries
    (:func:`willmore_nlp.model.build.build_step`) ``c = (patch, stiff)``: ``patch`` = 1 on the
    free patch and 0 on the fixed outer ring (distance and length/area terms of W, constant
    there), ``stiff`` = 0 on the ring of the co-normal variant, where the co-normal term replaces
    the ring's stiffness, and 1 otherwise. Ring elements keep their mass in W and E so that the
    boundary nodes Gamma carry their full mass (docs/theory/pitfalls.md, 'Boundary weights').
    """

    def energy(X: ca.SX, Y: ca.SX, Xk: ca.SX, par: ca.SX, c: ca.SX, Q: ca.SX) -> tuple[ca.SX, ca.SX]:
        if c.numel() == 0:
            return outer_objective(X, Y, Xk, par, beta=beta, Q=Q), isotropic_inner(X, Y, par[1])
        return outer_objective(X, Y, Xk, par, c[0], beta, Q), isotropic_inner(X, Y, par[1], c[1])

    return energy


def anisotropic(gamma: Callable[[ca.SX], ca.SX], beta: float = 1.0) -> Callable[..., tuple[ca.SX, ca.SX]]:
    """Energies of the fully nonlinear anisotropic scheme (docs/theory/scheme.md, 'Anisotropic flow'; paper (3.3)).

    ``E_T = M[X](Y-X).(Y-X) + 2 tt gamma(z_T(Y))`` with ``z_T = rot90(Y1 - Y0)`` (segments in R^2)
    or ``(Y1 - Y0) x (Y2 - Y0) / 2`` (triangles); the outer objective is the isotropic one (the
    approximate Willmore term measures Y - X, now the anisotropic mean-curvature step), with
    tangential weight ``beta`` (:func:`distance`).
    """

    def energy(X: ca.SX, Y: ca.SX, Xk: ca.SX, par: ca.SX, c: ca.SX, Q: ca.SX) -> tuple[ca.SX, ca.SX]:
        if Y.shape[1] == 2:
            e = Y[:, 1] - Y[:, 0]
            z = ca.vertcat(e[1], -e[0])
        else:
            z = 0.5 * ca.cross(Y[:, 1] - Y[:, 0], Y[:, 2] - Y[:, 0])
        inner = quad(mass_matrix(X), Y - X, Y - X) + 2 * par[1] * gamma(z)
        return outer_objective(X, Y, Xk, par, beta=beta, Q=Q), inner

    return energy
