"""Symbolic element kernels (CasADi SX) for P1 simplices of any dimension d in R^m.

All functions take the element's vertex positions as an (m, d + 1) SX matrix whose columns
are the vertices X_0..X_d, and return SX expressions. They are the only place where the
element geometry is written down; energies in :mod:`willmore_nlp.model` are built from them.
"""

from __future__ import annotations

from math import factorial

import casadi as ca
import numpy as np


def reference_gradients(d: int) -> np.ndarray:
    """(d + 1, d) gradients of the barycentric basis functions on the reference simplex."""
    return np.vstack([-np.ones((1, d)), np.eye(d)])


def reference_mass(d: int) -> np.ndarray:
    """(d + 1, d + 1) P1 mass matrix of a simplex of unit measure: (1 + delta_ij) / ((d+1)(d+2))."""
    return (np.ones((d + 1, d + 1)) + np.eye(d + 1)) / ((d + 1) * (d + 2))


def _metric(X: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Edge matrix D = [X_1 - X_0, ..., X_d - X_0] (m x d) and metric G = D^T D (d x d)."""
    d = X.shape[1] - 1
    D = ca.horzcat(*[X[:, i] - X[:, 0] for i in range(1, d + 1)])
    return D, ca.mtimes(D.T, D)


def _det_inv(G: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Determinant and inverse of a 1x1 or 2x2 symmetric matrix, in closed form."""
    d = G.shape[0]
    if d == 1:
        return G[0, 0], 1 / G
    if d == 2:
        det = G[0, 0] * G[1, 1] - G[0, 1] * G[1, 0]
        adj = ca.vertcat(ca.horzcat(G[1, 1], -G[0, 1]), ca.horzcat(-G[1, 0], G[0, 0]))
        return det, adj / det
    raise ValueError(f"simplices of dimension {d} are not supported (d must be 1 or 2)")


def measure(X: ca.SX) -> ca.SX:
    """Length (d = 1) or area (d = 2) of the simplex: sqrt(det G) / d!."""
    _, G = _metric(X)
    det, _ = _det_inv(G)
    return ca.sqrt(det) / factorial(X.shape[1] - 1)


def mass_matrix(X: ca.SX) -> ca.SX:
    """(d + 1, d + 1) consistent P1 mass matrix |T| (1 + delta_ij) / ((d+1)(d+2))."""
    d = X.shape[1] - 1
    return measure(X) * ca.DM(reference_mass(d))


def stiffness_matrix(X: ca.SX) -> ca.SX:
    """(d + 1, d + 1) P1 stiffness matrix |T| grad phi_i . grad phi_j = |T| Ghat G^-1 Ghat^T."""
    d = X.shape[1] - 1
    _, G = _metric(X)
    det, Ginv = _det_inv(G)
    vol = ca.sqrt(det) / factorial(d)
    Gh = ca.DM(reference_gradients(d))
    return vol * ca.mtimes([Gh, Ginv, Gh.T])


def tangent_projector(X: ca.SX) -> ca.SX:
    """(m, m) orthogonal projector onto the tangent space of the simplex: t t^T for a segment,
    I - n n^T (n the unit normal) for a triangle in R^3."""
    d, m = X.shape[1] - 1, X.shape[0]
    if d == 1:
        t = X[:, 1] - X[:, 0]
        return ca.mtimes(t, t.T) / ca.dot(t, t)
    if d == 2 and m == 3:
        n = ca.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
        return ca.SX.eye(3) - ca.mtimes(n, n.T) / ca.dot(n, n)
    raise ValueError(f"tangent projector: simplices of dimension {d} in R^{m} are not supported")


def quad(A: ca.SX, U: ca.SX, W: ca.SX) -> ca.SX:
    """Block bilinear form  A U . W = sum_c sum_ij A_ij U_ci W_cj  for (m, d+1) nodal matrices."""
    return ca.sum1(ca.sum2(ca.mtimes(U, A) * W))
