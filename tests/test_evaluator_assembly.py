"""The evaluator's numpy assembly against the MX functions, the lazily built functions, the Hessian operator,
the patterns without structural zeros and the Cholesky inner solve."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from willmore_nlp import WillmoreFlow, registry
from willmore_nlp.mesh import shapes
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator, to_scipy
from willmore_nlp.tangential import TangentialControl


def _ellipsoid(sub: int = 1):
    m = shapes.icosphere(sub)
    return m.with_vertices(m.vertices * np.array([1.0, 1.0, 1.3]))


def _problem(name: str):
    """(setup, mesh) of the cases: every kind of term and node set."""
    if name == "closed":
        mesh = _ellipsoid()
        return build_step(mesh), mesh
    if name == "volume-area":
        mesh = _ellipsoid()
        return build_step(mesh, volume=4.0, area=12.0), mesh
    if name == "anisotropic":
        mesh = shapes.ellipse(16, 1.0, 0.7)
        return build_step(mesh, anisotropy="gamma1"), mesh
    if name == "tangential-control":
        mesh = _ellipsoid()
        return build_step(mesh, tangential_control=TangentialControl("meanratio")), mesh
    pb, _ = registry.build("sphere_cap", rings=3, variant=name.split("-")[1], init="flat", amp=0.5)
    return build_step(pb.mesh, boundary=pb.flow_options["boundary"]), pb.mesh


CASES = ["closed", "volume-area", "anisotropic", "tangential-control", "cap-ring", "cap-conormal"]


def _point(setup, mesh, seed: int = 0):
    P = setup.problem
    rng = np.random.default_rng(seed)
    h = mesh.h
    X = mesh.vertices + 0.05 * h * rng.normal(size=mesh.vertices.shape)
    Y = X + 0.05 * h * rng.normal(size=X.shape)
    p = setup.params(mesh.vertices, 0.3 * h, 0.01 * h * h, 0.7)
    return P.pack_z(X, Y), p, rng.normal(size=P.nc)


def _dense(x) -> np.ndarray:
    return np.asarray(x, float).ravel()


@pytest.mark.parametrize("name", CASES)
def test_numpy_assembly_equals_the_mx_functions(name: str) -> None:
    """f, g, h, grad f, the constraint Jacobian and the Lagrangian Hessian of the numpy assembly (bincount over
    the element maps) equal the MX functions' (CasADi's scatter-add graph) to rounding, on the same patterns."""
    setup, mesh = _problem(name)
    P = setup.problem
    fn = P.functions()
    ev = StepEvaluator(P, fn)
    z, p, lam = _point(setup, mesh)
    assert ev.f(z, p) == pytest.approx(float(fn["f"](z, p)), rel=1e-14)
    np.testing.assert_allclose(ev.g(z, p), _dense(fn["g"](z, p)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(ev.h(z, p), _dense(fn["h"](z, p)), rtol=1e-14, atol=1e-15)
    f, grad = ev.f_grad(z, p)
    f_mx, grad_mx = fn["grad_f"](z, p)
    assert f == pytest.approx(float(f_mx), rel=1e-14)
    np.testing.assert_allclose(grad, _dense(grad_mx), rtol=0, atol=1e-14 * np.abs(grad).max())
    c, Jc = ev.c_jac(z, p)
    c_mx, Jc_mx = fn["jac_c"](z, p)
    np.testing.assert_allclose(c, _dense(c_mx), rtol=0, atol=1e-14 * max(1.0, np.abs(c).max()))
    Jc_mx = to_scipy(Jc_mx)  # (IPOPT's pattern also holds the kernels' structural zeros)
    assert Jc.shape == Jc_mx.shape and Jc.nnz <= Jc_mx.nnz
    assert abs(Jc - Jc_mx).max() <= 1e-14 * abs(Jc).max()
    U = ev.hess_lag_upper(z, p, 0.7, lam)
    U_mx = to_scipy(fn["hess_lag"](z, p, 0.7, lam))
    assert U.nnz <= U_mx.nnz and abs(U - U_mx).max() <= 1e-14 * abs(U).max()
    H = ev.hess_lag(z, p, 0.7, lam)
    assert abs(H - (U + sp.triu(U, 1).T)).max() == 0.0
    v = np.random.default_rng(3).normal(size=P.nx)
    np.testing.assert_allclose(ev.hess_lag_operator(z, p, 0.7, lam) @ v, H @ v, rtol=0,
                               atol=1e-13 * abs(H).max() * np.abs(v).max())


@pytest.mark.parametrize("name", ["volume-area", "cap-conormal"])
def test_assembly_in_element_blocks_is_bitwise_the_whole_map(name: str, monkeypatch) -> None:
    """The kernels run in blocks of ELEMENT_BLOCK elements and the matrices are summed block by block: with
    blocks of 7 elements (many blocks and a remainder) every value, vector and matrix is bit for bit the one of
    a single block over all elements."""
    from willmore_nlp.model import evaluator as evaluator_module

    setup, mesh = _problem(name)
    P = setup.problem
    z, p, lam = _point(setup, mesh)

    def values(ev: StepEvaluator) -> list[np.ndarray]:
        c, Jc = ev.c_jac(z, p)
        f, grad = ev.f_grad(z, p)
        return [np.array([ev.f(z, p), f]), ev.g(z, p), ev.h(z, p), grad, c, Jc.toarray(),
                ev.hess_lag_upper(z, p, 0.7, lam).toarray()]

    monkeypatch.setattr(evaluator_module, "ELEMENT_BLOCK", P.K)
    whole = values(StepEvaluator(P, P.functions()))
    monkeypatch.setattr(evaluator_module, "ELEMENT_BLOCK", 7)
    assert P.K % 7 and P.K > 14
    for a, b in zip(whole, values(StepEvaluator(P, P.functions())), strict=True):
        assert np.array_equal(a, b)


def test_evaluators_of_one_flow_share_the_mapped_kernels(monkeypatch) -> None:
    """A flow's evaluators (one per connectivity) take the kernels mapped over element blocks from one cache: the
    rebuild after Delaunay flips maps nothing again and evaluates bit for bit as the first evaluator; a kernel object
    other than the cached one's gets its own map, and the cache holds two entries per kernel (block and remainder)."""
    import casadi as ca

    from willmore_nlp.model import evaluator as evaluator_module

    monkeypatch.setattr(evaluator_module, "ELEMENT_BLOCK", 7)
    setup, mesh = _problem("volume-area")
    P = setup.problem
    z, p, lam = _point(setup, mesh)
    maps: dict = {}

    def values(ev: StepEvaluator) -> list[np.ndarray]:
        return [np.array([ev.f(z, p)]), ev.c_jac(z, p)[1].toarray(), ev.hess_lag_upper(z, p, 0.7, lam).toarray()]

    fn = P.functions()
    first = values(StepEvaluator(P, fn, maps))
    assert P.K % 7 and len(maps) == 2 * len({name for name, _ in maps})
    mapped = []
    original = ca.Function.map
    monkeypatch.setattr(ca.Function, "map", lambda f, *a: mapped.append(f.name()) or original(f, *a))
    again = values(StepEvaluator(P, fn, maps))
    assert not mapped and all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    kernels = dict(fn.kernels, k_f=fn.kernels["k_f"].expand())  # (another object of the same kernel)
    assert StepEvaluator(P, P.functions(kernels), maps).f(z, p) == pytest.approx(first[0][0], rel=1e-14)
    assert len(mapped) == 2 and maps[("k_f", True)][0] is kernels["k_f"] and len(maps) == 2 * len({n for n, _ in maps})


def test_functions_are_built_only_when_asked() -> None:
    """A newton-krylov flow never builds an MX function (the evaluator assembles in numpy); an IPOPT flow builds
    the ones nlpsol takes and nothing it does not use (g, h)."""
    mesh = _ellipsoid()
    nk = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, solver="newton-krylov", mesh_control="off")
    nk.step()
    assert nk.evaluator.fn.built() == ()
    ip = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, mesh_control="off")
    ip.step()
    built = set(ip.evaluator.fn.built())
    assert {"f_expr", "g_expr", "grad_f", "jac_c", "hess_lag"} <= built
    assert not {"g", "h"} & built


def test_isotropic_jacobian_has_no_coordinate_couplings() -> None:
    """The structural zeros of the element Jacobian stay out of the pattern: the isotropic J_Y is exactly
    (M + tt L) (x) I_3 with three times the nonzeros of its N x N block (a third of the 3 x 3 blocks'
    entries before), and the Cholesky inner solve of that block (newton-krylov's) gives Y[X] of the whole
    J_Y's sparse LU (the default)."""
    setup, mesh = _problem("closed")
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    z, p, _ = _point(setup, mesh)
    _, J = ev.g_jac(z, p)
    Jy = J[:, P.nX * 3:].tocsc()
    A = Jy[0::3, 0::3]
    assert Jy.nnz == 3 * A.nnz
    assert abs(Jy - sp.kron(A, sp.identity(3))).max() == 0.0
    r = np.random.default_rng(1).normal(size=Jy.shape[0])
    ev.cholesky = "auto"  # (newton-krylov's setting; None: the sparse LU)
    x = ev.linear_solve(Jy, r)
    np.testing.assert_allclose(x, spla.spsolve(Jy, r), rtol=0, atol=1e-12 * np.abs(x).max())
    X, _ = P.unpack_z(z, mesh.vertices)
    Y = ev.solve_y(X, p)
    Y_lu = ev.solve_y(X, p, linear_solve=lambda J_y, b: spla.spsolve(J_y, b))
    np.testing.assert_allclose(Y, Y_lu, rtol=0, atol=1e-13 * np.abs(Y).max())
