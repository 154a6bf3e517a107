"""Step solvers: the reduced-space methods (adjoint gradient, Hessian-vector products) against FD and IPOPT."""

import warnings

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow, registry
from willmore_nlp.analysis import circle_step_radius, fit_order
from willmore_nlp.fem.assembly import lumped_mass
from willmore_nlp.mesh import shapes
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.solvers import make_solver, solver_names
from willmore_nlp.solvers.reduced import ReducedSolver


def _reduced(mesh, anisotropy=None, seed=0):
    setup = build_step(mesh, anisotropy=anisotropy)
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    solver = make_solver("newton", ev, {})
    h = mesh.h
    p = setup.params(mesh.vertices, 0.5 * h, 0.1 * h * h, 0.3)
    rng = np.random.default_rng(seed)
    X = mesh.vertices + 0.05 * h * rng.normal(size=mesh.vertices.shape)
    Y0 = ev.solve_y(X, p)
    return solver, p, P.pack_z(X, Y0)[: P.nX * P.m], Y0, rng


@pytest.mark.parametrize(("mesh", "anisotropy"), [
    pytest.param(shapes.ellipse(16, 1.0, 0.7), None, id="curve"),
    pytest.param(shapes.icosphere(1), None, id="sphere"),
    pytest.param(shapes.ellipse(16, 1.0, 0.7), "gamma1", id="curve-gamma1"),
])
def test_reduced_gradient_and_hessian_match_finite_differences(mesh, anisotropy) -> None:
    """grad W^ from the adjoint equals the FD gradient of W^(X) = W(Xk, X, Y[X]) (Y re-solved at every
    point); the second-order adjoint Hessian-vector product equals the FD of the reduced gradient."""
    solver, p, x, Y0, rng = _reduced(mesh, anisotropy)
    assert isinstance(solver, ReducedSolver)
    pt = solver._at(x, p, Y0)
    eps = 1e-6
    for _ in range(3):
        d = rng.normal(size=x.size)
        fp, fm = solver._at(x + eps * d, p, Y0), solver._at(x - eps * d, p, Y0)
        fd = (fp.f - fm.f) / (2 * eps)
        assert pt.grad @ d == pytest.approx(fd, rel=1e-6, abs=1e-9 * abs(pt.f))
        fdh = (fp.grad - fm.grad) / (2 * eps)
        assert np.max(np.abs(solver._hessp(pt, p, d) - fdh)) <= 1e-5 * np.max(np.abs(fdh))


CASES = [
    pytest.param(shapes.ellipse(32, 1.0, 0.7), 0.5, 0.1, 0.5, id="circle"),
    pytest.param(shapes.icosphere(2), 0.25, 0.1, 0.0, id="sphere"),
    pytest.param(shapes.torus(1.0, 0.5, 24, 12), None, 0.01, 0.0, id="torus"),
]


@pytest.mark.parametrize(("mesh", "tau_h", "tt_h2", "lam"), CASES)
def test_solvers_agree_with_ipopt(mesh, tau_h, tt_h2, lam) -> None:
    """One step by L-BFGS (|grad W^| <= 1e-6 relative), reduced Newton (1e-8) and the SQP (KKT residual
    1e-9) against IPOPT at 1e-12: the differences, relative to the step, are bounded by the tolerances
    (measured: L-BFGS <= 1.5e-5, Newton <= 1e-9, SQP <= 3e-8)."""
    h = mesh.h
    tau, tt = (1e-2 if tau_h is None else tau_h * h), tt_h2 * h * h
    off = {"mesh_control": "off"}  # one step of the scheme itself (the torus step would be repaired)
    ref = WillmoreFlow(mesh, tau, tt, lam=lam, tol=1e-12, max_iter=1000, max_retries=0, **off).step()
    step = np.abs(ref.vertices - mesh.vertices).max()
    for name, tol, bound in (("lbfgs", 1e-6, 1e-4), ("newton", 1e-8, 1e-7), ("sqp", 1e-9, 1e-7)):
        r = WillmoreFlow(mesh, tau, tt, lam=lam, solver=name, tol=tol, max_retries=0, **off).step()
        assert r.converged and r.stats["kkt_residual"] <= r.stats["gtol"]
        assert np.abs(r.vertices - ref.vertices).max() <= bound * step, name
        assert r.stats["n_factorizations"] >= 1 and r.stats["n_linear_solves"] >= r.stats["n_factorizations"]


def test_gradient_descent_error_follows_its_tolerance() -> None:
    """The paper's gradient descent with Armijo steps: the error of X^{k+1} against IPOPT scales linearly
    with the gradient tolerance (measured 1.6e-3, 1.6e-4, 1.6e-5 of the step for 1e-4, 1e-5, 1e-6)."""
    mesh = shapes.ellipse(16, 1.0, 0.7)
    h = mesh.h
    ref = WillmoreFlow(mesh, h / 2, h * h / 10, lam=0.5, tol=1e-12, max_iter=1000).step().vertices
    step = np.abs(ref - mesh.vertices).max()
    tols = [1e-4, 1e-5, 1e-6]
    err = []
    for tol in tols:
        r = WillmoreFlow(mesh, h / 2, h * h / 10, lam=0.5, solver="gd", tol=tol, max_iter=100000, max_retries=0).step()
        err.append(np.abs(r.vertices - ref).max() / step)
        assert err[-1] <= 100 * tol
    assert fit_order(tols, err) == pytest.approx(1.0, abs=0.15)


@pytest.mark.parametrize(("solver", "tol"), [("lbfgs", 1e-1), ("newton-krylov", 1e-2)])
def test_a_step_accepted_at_its_start_by_a_loose_tol_is_warned_of(solver, tol) -> None:
    """A loose ``tol`` can be met at a step's start: the step "converges" in 0 iterations and X does not move (a new
    user's 64-gon: R(0.1) = 1.000000 against the exact 1.046635). The flow warns once, naming the tolerance; with
    the default tolerance the same step moves as the time-discrete closed form says, without the warning."""
    mesh = shapes.regular_polygon(64, radius=1.0)
    flow = WillmoreFlow(mesh, mesh.h / 10, mesh.h**2 / 10, solver=solver, tol=tol)
    said = rf"step 1: solver {solver} accepted the step at its start .* tol = {tol:g}"
    with pytest.warns(UserWarning, match=said) as got:
        steps = flow.run(steps=3)
    assert sum("at its start" in str(w.message) for w in got) == 1
    assert all(r.iterations == 0 for r in steps) and np.array_equal(flow.X, mesh.vertices)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        r = WillmoreFlow(mesh, mesh.h / 10, mesh.h**2 / 10, solver=solver).step()
    assert r.iterations >= 1 and not any("at its start" in str(w.message) for w in got)
    motion = np.linalg.norm(r.vertices, axis=1).mean() - 1  # (the time-discrete closed form's, to O(h^2))
    assert motion == pytest.approx(circle_step_radius(1.0, mesh.h / 10, mesh.h**2 / 10) - 1, rel=0.02)


def test_solver_registry_and_options(octagon_evaluator) -> None:
    assert {"ipopt", "sqp", "gd", "lbfgs", "newton", "semi-implicit"} <= set(solver_names())
    _, ev = octagon_evaluator
    with pytest.raises(ValueError, match="unknown option\\(s\\) foo"):
        make_solver("lbfgs", ev, {"foo": 1})
    with pytest.raises(ValueError, match="unknown solver 'bfgs'"):
        make_solver("bfgs", ev, {})


def test_semi_implicit_baseline_reproduces_the_circle_ode_to_first_order() -> None:
    """R(t) = (R0^4 + 2t)^(1/4) at t = 0.05 for a 256-gon: the semi-implicit Euler error halves with tau
    (measured 2.87e-4, 1.45e-4, 7.43e-5: order 0.98); one linear solve per step, no energy inequality."""
    mesh = shapes.regular_polygon(256, 1.0)
    T = 0.05
    ks = [5, 10, 20]
    err = []
    for k in ks:
        f = WillmoreFlow(mesh, T / k, mesh.h**2, solver="semi-implicit")
        res = f.run(steps=k)
        assert all(r.iterations == 1 and r.stats["n_factorizations"] == 1 for r in res)
        R = np.linalg.norm(f.X, axis=1)
        assert R.std() < 1e-12  # stays a regular polygon
        err.append(abs(R.mean() - (1 + 2 * T) ** 0.25))
    assert fit_order([T / k for k in ks], err) == pytest.approx(1.0, abs=0.1)
    cap_mesh = registry.problem_module("boundary").cap_mesh
    from willmore_nlp.boundary import Boundary

    cap, free, _ = cap_mesh(4)
    with pytest.raises(ValueError, match="no clamped boundaries"):
        WillmoreFlow(cap, 0.1, 0.01, solver="semi-implicit", boundary=Boundary(free, "ring"))
    # (first, before a term it cannot take: a clamped arc was told to drop the tangential weight its problem had set,
    # and then that the baseline has no clamped boundaries; a new-user check)
    with pytest.raises(ValueError, match="no clamped boundaries"):
        WillmoreFlow(cap, 0.1, 0.01, solver="semi-implicit", boundary=Boundary(free, "ring"), tangential_weight=10)
    with pytest.raises(ValueError, match="isotropic"):
        WillmoreFlow(mesh, 0.1, 0.01, solver="semi-implicit", anisotropy="gamma1")


def test_semi_implicit_baseline_on_spheres() -> None:
    """Surfaces: a round sphere is stationary for lam = 0 up to the O(h^2) consistency error of the discrete
    H and Gauss curvature (radius drift over t = 0.1: 1.6e-2, 3.8e-3, 9.5e-4 for h = 0.30, 0.15, 0.075,
    order 2.0), and with lam > 0 the scheme converges at first order in tau (self-convergence against
    tau / 8 on a fixed mesh)."""
    from willmore_nlp.geometry import gauss_curvature

    hs, drift = [], []
    for s in (2, 3, 4):
        m = shapes.icosphere(s)
        assert np.sum(gauss_curvature(m.vertices, m.simplices) * lumped_mass(m.vertices, m.simplices)) == \
            pytest.approx(4 * np.pi, rel=1e-12)  # Gauss-Bonnet
        f = WillmoreFlow(m, 0.01, m.h**2, solver="semi-implicit", rest_dilation=False)  # (the scheme's own drift)
        f.run(steps=10)
        hs.append(m.h)
        drift.append(abs(np.linalg.norm(f.X, axis=1).mean() - 1.0))
    assert fit_order(hs, drift) == pytest.approx(2.0, abs=0.15)
    m = shapes.icosphere(3)
    T, radii = 0.05, {}
    for k in (5, 10, 20, 40):
        f = WillmoreFlow(m, T / k, m.h**2, lam=0.5, solver="semi-implicit")
        f.run(steps=k)
        radii[k] = np.linalg.norm(f.X, axis=1).mean()
    err = [abs(radii[k] - radii[40]) for k in (5, 10, 20)]
    assert radii[40] < 1.0  # the area term shrinks the sphere
    assert fit_order([T / k for k in (5, 10, 20)], err) > 0.9



def test_semi_implicit_normal_velocity_converges_to_the_nested_schemes_on_ellipsoids() -> None:
    """Off the sphere too: one step from the ellipsoid 1:1:1.5 at tau = 1e-3 h^2 (mesh control off), the semi-implicit
    baseline's normal velocity (X - Xk).n / tau against IPOPT's nested step's differs by 0.116 / 0.040 / 0.014 of the
    latter's norm at 162 / 642 / 2,562 vertices (measured; a new user had read its first step at tau = h, 4.6 / 2.4 /
    1.6 there, as an inconsistency): the difference falls with h at an order above 1."""
    from willmore_nlp import Mesh, geometry

    hs, diffs = [], []
    for sub in (2, 3, 4):
        s = shapes.icosphere(sub)
        m = Mesh(s.vertices * [1, 1, 1.5], s.simplices)
        n = geometry.vertex_normals(m)
        v = []
        for solver in ("ipopt", "semi-implicit"):
            f = WillmoreFlow(m, 1e-3 * m.h**2, m.h**2 / 100, solver=solver, mesh_control="off", max_retries=0)
            f.step()
            v.append(np.sum((f.X - m.vertices) * n, axis=1) / f.tau)
        hs.append(m.h)
        diffs.append(np.linalg.norm(v[1] - v[0]) / np.linalg.norm(v[0]))
    assert diffs[0] > diffs[1] > diffs[2] and diffs[2] < 0.03
    assert fit_order(hs, diffs) > 1.2


@pytest.mark.parametrize("method", ["gd", "lbfgs", "newton"])
def test_reduced_energy_is_exact_at_tiny_steps_in_every_reduced_solver(method: str) -> None:
    """The reduced solvers evaluate W^ with the inner solve's default, one exact Newton step from the warm Y0 for a
    linear inner equation (as newton-krylov): on a stretched 642-vertex icosphere the central difference of W^ at
    1e-11 along a random direction matches the adjoint gradient to 1e-3 (measured 2.5e-6). Before, Y0 passed the
    inner tolerance unchanged at such trial points and the difference was off by a factor 675 (lbfgs measured)."""
    mesh = shapes.icosphere(3)
    mesh = mesh.with_vertices(mesh.vertices * np.array([1.0, 1.0, 1.3]))
    flow = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, solver=method, mesh_control="off")
    solver = flow.solver
    p = flow.params(flow.X, flow.tau)
    x = flow.X.ravel().copy()
    d = np.random.default_rng(1).standard_normal(x.size)
    eps = 1e-11
    diff = (solver._at(x + eps * d, p, flow.Y).f - solver._at(x - eps * d, p, flow.Y).f) / (2 * eps)
    predicted = solver._at(x, p, flow.Y).grad @ d
    assert abs(diff - predicted) <= 1e-3 * abs(predicted)


@pytest.mark.parametrize(("mesh", "extra"), [
    pytest.param(shapes.ellipse(32, 1.0, 0.5), {}, id="curve"),
    pytest.param(shapes.icosphere(2).with_vertices(shapes.icosphere(2).vertices * [2 / 3, 2 / 3, 1.0]),
                 {"volume": "initial"}, id="surface-volume"),
])
def test_ipopt_takes_the_same_steps_at_every_size(mesh, extra) -> None:
    """IPOPT solves the steps of a mesh narrower than 1 or wider than 4 in the unit of length in which it is 2 wide
    (``length_unit``, set once per flow): a mesh 2 wide scaled by 1e-4, 2^-12 or 2^12 (t by s^4) takes the unit
    one's iterations, and its states, scaled, agree
    to IPOPT's tolerance (measured: 1e-10 h for the curve, whose rounding differs with the size, 1e-13 h for the
    surface; the steps' terms are homogeneous in the length; before, IPOPT's absolute tol = 1e-9 was met at the
    start point by the small one, 0 iterations, and the large one needed retries). The outer volume constraint keeps
    its relative residual at every size."""
    from willmore_nlp.solvers.ipopt import length_unit

    assert float(np.ptp(mesh.vertices, axis=0).max()) == pytest.approx(2.0, rel=1e-12)
    tau, tt = 0.05 * mesh.h, mesh.h**2 / 100
    runs = []
    for s in (1.0, 1e-4, 2.0**-12, 2.0**12):
        flow = WillmoreFlow(mesh.with_vertices(s * mesh.vertices), s**4 * tau, s**2 * tt, solver="ipopt",
                            adaptive=False, max_retries=0, **extra)
        assert flow.solver.length == length_unit(flow.X) == pytest.approx(s, rel=1e-12)
        runs.append((s, [flow.step() for _ in range(3)], flow))
    (_, ref, _), *others = runs
    for s, steps, flow in others:
        for a, b in zip(ref, steps, strict=True):
            assert b.iterations == a.iterations > 0 and b.retries == 0
            np.testing.assert_allclose(b.vertices / s, a.vertices, rtol=0, atol=1e-9 * mesh.h)
        assert flow.constraint_violation(flow.X) < 1e-10
