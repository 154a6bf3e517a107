"""Assembled derivatives of W and g against central finite differences."""

import numpy as np
import pytest

from willmore_nlp.fem.assembly import mass_stiffness
from willmore_nlp.mesh import shapes
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator


def _setup(mesh, seed=0):
    setup = build_step(mesh)
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    rng = np.random.default_rng(seed)
    Xk = mesh.vertices
    h = mesh.h
    X = Xk + 0.05 * h * rng.normal(size=Xk.shape)
    Y = X + 0.05 * h * rng.normal(size=Xk.shape)
    p = setup.params(Xk, 0.3, 0.01 * h * h, 0.7)
    return P, ev, P.pack_z(X, Y), p, rng


MESHES = [
    pytest.param(lambda: shapes.ellipse(12, 2.0, 1.0), id="curve-R2"),
    pytest.param(lambda: shapes.hypocycloid(15, 0.3), id="curve-R3"),
    pytest.param(lambda: shapes.icosphere(1), id="surface"),
]


@pytest.mark.parametrize("make", MESHES)
def test_gradient_jacobian_hessian_fd(make) -> None:
    P, ev, z, p, rng = _setup(make())
    eps = 1e-6
    d = rng.normal(size=z.size)
    # gradient: directional derivative
    fd = (ev.f(z + eps * d, p) - ev.f(z - eps * d, p)) / (2 * eps)
    np.testing.assert_allclose(ev.grad_f(z, p) @ d, fd, rtol=1e-6)
    # Jacobian of g: J d vs central difference
    fdg = (ev.g(z + eps * d, p) - ev.g(z - eps * d, p)) / (2 * eps)
    Jd = ev.jac_g(z, p) @ d
    assert np.max(np.abs(Jd - fdg)) <= 1e-6 * np.max(np.abs(fdg))
    # Hessian of the Lagrangian: H d vs difference of Lagrangian gradients
    lam_f, lam_g = 0.8, rng.normal(size=P.ng)

    def lag_grad(zz):
        return lam_f * ev.grad_f(zz, p) + ev.jac_g(zz, p).T @ lam_g

    fdh = (lag_grad(z + eps * d) - lag_grad(z - eps * d)) / (2 * eps)
    Hd = ev.hess_lag(z, p, lam_f, lam_g) @ d
    assert np.max(np.abs(Hd - fdh)) <= 1e-5 * np.max(np.abs(fdh))


@pytest.mark.parametrize("make", MESHES)
def test_constraint_is_dziuk_step(make) -> None:
    """g = (M + tt L) Y - M X with M, L from the independent numpy assembly; W likewise."""
    mesh = make()
    P, ev, z, p, _ = _setup(mesh)
    X, Y = P.unpack_z(z, mesh.vertices)
    tau, tt, lam = (P.params.scalar(p, k) for k in ("tau", "tt", "lam"))
    M, L = mass_stiffness(X, mesh.simplices)
    g = (M + tt * L) @ Y - M @ X
    np.testing.assert_allclose(ev.g(z, p), g.ravel(), atol=1e-13 * np.abs(M @ X).max())
    Mk, _ = mass_stiffness(mesh.vertices, mesh.simplices)
    D = X - mesh.vertices
    V = Y - X
    from willmore_nlp.fem.assembly import element_geometry

    area = element_geometry(X, mesh.simplices)[0].sum()
    W = np.einsum("ic,ic->", D, Mk @ D) + tau / tt**2 * np.einsum("ic,ic->", V, M @ V) + 2 * tau * lam * area
    np.testing.assert_allclose(ev.f(z, p), W, rtol=1e-12)
