"""Element kernels against closed forms, and against the independent numpy assembly."""

import casadi as ca
import numpy as np
import pytest

from willmore_nlp.fem.assembly import lumped_mass, mass_stiffness, stiffness_action
from willmore_nlp.fem.element import mass_matrix, measure, stiffness_matrix
from willmore_nlp.mesh import shapes


def _eval(fn, P: np.ndarray) -> np.ndarray:
    X = ca.SX.sym("X", P.shape[1], P.shape[0])
    return np.array(ca.Function("f", [X], [fn(X)])(P.T))


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q * np.sign(np.diag(R))


@pytest.mark.parametrize("m", [2, 3])
def test_segment_closed_form(m: int) -> None:
    rng = np.random.default_rng(1)
    P = rng.normal(size=(2, m))
    ell = np.linalg.norm(P[1] - P[0])
    np.testing.assert_allclose(_eval(measure, P), ell, rtol=1e-14)
    np.testing.assert_allclose(_eval(mass_matrix, P), ell / 6 * np.array([[2, 1], [1, 2]]), rtol=1e-14)
    np.testing.assert_allclose(_eval(stiffness_matrix, P), np.array([[1, -1], [-1, 1]]) / ell, rtol=1e-13)


def test_triangle_closed_form_any_orientation() -> None:
    """Right isosceles triangle with legs a, rotated and translated arbitrarily in R^3.

    Area a^2/2, mass a^2/24 [[2,1,1],[1,2,1],[1,1,2]], cotangent stiffness
    1/2 [[2,-1,-1],[-1,1,0],[-1,0,1]] (independent of a), with the right angle at vertex 0.
    """
    rng = np.random.default_rng(2)
    a = 0.7
    P0 = np.array([[0.0, 0, 0], [a, 0, 0], [0, a, 0]])
    Mref = a * a / 24 * np.array([[2, 1, 1], [1, 2, 1], [1, 1, 2]])
    Lref = 0.5 * np.array([[2, -1, -1], [-1, 1, 0], [-1, 0, 1]])
    for _ in range(5):
        P = P0 @ _random_rotation(rng).T + rng.normal(size=3)
        np.testing.assert_allclose(_eval(measure, P), a * a / 2, rtol=1e-13)
        np.testing.assert_allclose(_eval(mass_matrix, P), Mref, rtol=1e-13)
        np.testing.assert_allclose(_eval(stiffness_matrix, P), Lref, atol=1e-13)


def test_equilateral_cotangent_weights() -> None:
    """Equilateral triangle: every cot = 1/sqrt(3), so off-diagonal stiffness -1/(2 sqrt 3)."""
    P = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]])
    L = _eval(stiffness_matrix, P)
    off = -1 / (2 * np.sqrt(3))
    np.testing.assert_allclose(L, [[-2 * off, off, off], [off, -2 * off, off], [off, off, -2 * off]], rtol=1e-13)


def test_global_matrices_properties() -> None:
    """Assembled M sums to the area, L annihilates constants and reproduces the area via X.LX / 2."""
    mesh = shapes.icosphere(2)
    M, L = mass_stiffness(mesh.vertices, mesh.simplices)
    V, S = mesh.vertices, mesh.simplices
    area = 0.5 * np.linalg.norm(np.cross(V[S[:, 1]] - V[S[:, 0]], V[S[:, 2]] - V[S[:, 0]]), axis=1).sum()
    np.testing.assert_allclose(M.sum(), area, rtol=1e-13)
    np.testing.assert_allclose(L @ np.ones(mesh.n_vertices), 0, atol=1e-12)
    # Dirichlet energy of the coordinate functions: int |grad_M x|^2 = d * area for a surface
    np.testing.assert_allclose(np.einsum("ic,ic->", V, L @ V), 2 * area, rtol=1e-12)


@pytest.mark.parametrize("mesh", [shapes.icosphere(2), shapes.regular_polygon(24, m=3), shapes.spherical_cap(4)],
                         ids=["sphere", "curve-in-R3", "cap"])
def test_stiffness_action_is_the_assembled_stiffness_applied(mesh) -> None:
    """stiffness_action (element by element, nothing assembled) gives the assembled L V and the lumped mass, on a
    closed surface, a curve in R^3 and a surface with boundary, to rounding."""
    V = mesh.vertices + 0.01 * np.random.default_rng(1).normal(size=mesh.vertices.shape)
    LV, mass = stiffness_action(V, mesh.simplices)
    L = mass_stiffness(V, mesh.simplices)[1]
    np.testing.assert_allclose(LV, L @ V, rtol=0, atol=1e-13 * np.abs(L @ V).max())
    np.testing.assert_allclose(mass, lumped_mass(V, mesh.simplices), rtol=1e-14)
