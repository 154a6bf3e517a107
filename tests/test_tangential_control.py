"""Tangential control inside the step: exact form of the term, derivatives, tangency, options, unchanged flow."""

import subprocess
import sys

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow, registry
from willmore_nlp import flow as flow_module
from willmore_nlp.boundary import Boundary
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.io import save_mesh
from willmore_nlp.mesh.topology import euler_characteristic
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.model.terms.tangential_control import TangentialControlTerm
from willmore_nlp.tangential import SUBSTEPS, TangentialControl, mean_ratio, nodal_parameters, unresolved_nodes

ON = TangentialControl("meanratio", 7.0)


def _perturbed(mesh: Mesh, seed: int, size: float = 0.1) -> Mesh:
    rng = np.random.default_rng(seed)
    return mesh.with_vertices(mesh.vertices + size * mesh.h * rng.normal(size=mesh.vertices.shape))


def _control_value(Xk: np.ndarray, X: np.ndarray, S: np.ndarray, Q: np.ndarray, cells: np.ndarray) -> float:
    """sum_i m_i |P_i (X_i - Xk_i - S_i)|^2, m_i the lumped mass over ``cells`` (a numpy loop over nodes)."""
    N, m = Xk.shape
    mass = np.zeros(N)
    for s in S[cells]:
        E = Xk[s[1:]] - Xk[s[0]]
        size = np.linalg.norm(E[0]) if len(s) == 2 else 0.5 * np.linalg.norm(np.cross(E[0], E[1]))
        mass[s] += size / len(s)
    total = 0.0
    for i in range(N):
        P = Q[i, : m * m].reshape(m, m)
        r = P @ (X[i] - Xk[i] - Q[i, m * m :])
        total += mass[i] * float(r @ r)
    return total


def _pair(mesh: Mesh, **kw: object) -> tuple:
    out = []
    for control in (None, ON):
        setup = build_step(mesh, tangential_control=control, **kw)
        out.append((setup, StepEvaluator(setup.problem, setup.problem.functions())))
    return out


def _cap() -> tuple[Mesh, np.ndarray]:
    """A spherical cap of 6 rings (10 degrees each): free inside polar angle 35 degrees, two fixed rings outside."""
    mesh = shapes.spherical_cap(6, 60.0)
    return mesh, np.degrees(np.arccos(np.clip(mesh.vertices[:, 2], -1, 1))) < 35.0


@pytest.mark.parametrize("case", ["curve", "surface", "clamped conormal", "clamped ring", "anisotropic curve"])
def test_control_term_matches_numpy_and_derivatives_fd(case: str, check_step_derivatives) -> None:
    """W(on) - W(off) = beta_c sum_i m_i |P_i (X_i - Xk_i - S_i)|^2 (independent numpy assembly); the
    gradient of W and the Lagrangian Hessian against central differences; the difference of the
    gradients is tangent at every node (normal components of the nodal equations unchanged)."""
    kw: dict = {}
    if case == "surface":
        mesh = _perturbed(shapes.icosphere(1), 0)
    elif case.startswith("clamped"):
        cap, free = _cap()
        mesh = _perturbed(cap, 0, 0.03)
        kw = {"boundary": Boundary(free, case.split()[1])}
    else:
        mesh = _perturbed(shapes.ellipse(14, 1.0, 0.7), 0)
        if case == "anisotropic curve":
            kw = {"anisotropy": "gamma1"}
    (s0, ev0), (s1, ev1) = _pair(mesh, **kw)
    P = s1.problem
    rng = np.random.default_rng(3)
    V = mesh.vertices
    X = V + 0.2 * mesh.h * rng.normal(size=V.shape)
    Y = X + 0.1 * mesh.h * rng.normal(size=V.shape)
    X[~P.x_free] = V[~P.x_free]
    z = P.pack_z(X, Y)
    tau, tt, lam = 0.3, 0.1 * mesh.h**2, 0.5
    p0, p1 = s0.params(V, tau, tt, lam), s1.params(V, tau, tt, lam)
    Q = nodal_parameters(V, mesh.simplices, P.x_free, substeps=SUBSTEPS)  # the target as the step takes it
    cells = np.arange(mesh.n_simplices)
    if P.element_const:  # clamped: the term lives on the patch (the ring's nodes are fixed anyway)
        key = {tuple(s) for s in P.simplices[P.element_const["patch"] > 0]}
        cells = np.array([k for k, s in enumerate(mesh.simplices) if tuple(s) in key])
    expected = ON.weight * _control_value(V, X, mesh.simplices, Q, cells)
    assert expected > 1e-5 * ev1.f(z, p1)  # well above the 1e-10 relative check below
    assert ev1.f(z, p1) - ev0.f(z, p0) == pytest.approx(expected, rel=1e-10)

    check_step_derivatives(ev1, z, p1, rng)

    m = mesh.m
    diff = (ev1.grad_f(z, p1) - ev0.grad_f(z, p0))[: P.nX * m].reshape(-1, m)
    Pfree = Q[P.x_free, : m * m].reshape(-1, m, m)
    normal_part = diff - np.einsum("nab,nb->na", Pfree, diff)
    assert np.abs(diff).max() > 1e-5 * np.abs(ev0.grad_f(z, p0)).max()
    assert np.abs(normal_part).max() <= 1e-12 * np.abs(diff).max()


def test_parameters_follow_every_input() -> None:
    """The term's nodal data are nodal_parameters of its inputs: equal inputs give equal data, a change of Xk (one
    coordinate of one node, by 1e-12), of tau (with a relaxation time), of the free nodes or of the simplices gives
    the data of the new inputs."""
    mesh = _perturbed(shapes.icosphere(1), 1)
    V, S = mesh.vertices, mesh.simplices
    setup = build_step(mesh, tangential_control=TangentialControl("meanratio", 2.0, time=0.5))
    (term,) = [t for t in setup.problem.terms if isinstance(t, TangentialControlTerm)]
    first = term.values(V, 0.1, S, None)["control"]
    assert np.array_equal(first, nodal_parameters(V, S, None, 0.2, SUBSTEPS))
    assert np.array_equal(term.values(V.copy(), 0.1, S.copy(), None)["control"], first)
    W = V.copy()
    W[7, 2] += 1e-12
    flipped = S.copy()
    flipped[0] = flipped[0, [0, 2, 1]]
    free = np.ones(mesh.n_vertices, bool)
    free[:3] = False
    for Xk, tau, simplices, x_free in [(W, 0.1, S, None), (V, 0.2, S, None), (V, 0.1, flipped, None),
                                       (V, 0.1, S, free), (V, 0.1, S, None)]:
        got = term.values(Xk, tau, simplices, x_free)["control"]
        fresh = nodal_parameters(Xk, simplices, x_free, min(1.0, tau / 0.5), SUBSTEPS)
        assert np.array_equal(got, fresh)
        if Xk is not V or tau != 0.1 or simplices is not S or x_free is not None:
            assert not np.array_equal(fresh, first)


def test_mean_ratio_is_one_for_equilateral_and_its_gradient_fd() -> None:
    """q_T = 1 on an equilateral triangle, > 1 otherwise, scale invariant; gradient by central differences."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]])
    S = np.array([[0, 1, 2]])
    q, g = mean_ratio(V, S)
    assert q[0] == pytest.approx(1.0, rel=1e-14)
    assert np.abs(g).max() < 1e-12
    mesh = _perturbed(shapes.torus(1.0, 0.5, 12, 6), 1)
    q, g = mean_ratio(mesh.vertices, mesh.simplices)
    assert q.min() > 1.0
    assert mean_ratio(3.0 * mesh.vertices, mesh.simplices)[0] == pytest.approx(q, rel=1e-12)
    rng = np.random.default_rng(0)
    d = rng.normal(size=mesh.vertices.shape)
    eps = 1e-6
    fd = (mean_ratio(mesh.vertices + eps * d, mesh.simplices)[0].sum()
          - mean_ratio(mesh.vertices - eps * d, mesh.simplices)[0].sum()) / (2 * eps)
    assert np.sum(g * d) == pytest.approx(fd, rel=1e-7)


def test_target_is_tangent_and_zero_on_fixed_nodes() -> None:
    """P_i is an orthogonal projector of rank 2 (nearly annihilating the radius on an icosphere), S_i is
    tangent (P_i S_i = S_i), both vanish on fixed nodes, and S = 0 on a regular polygon (nothing to improve)."""
    mesh = _perturbed(shapes.icosphere(2), 2)
    V = mesh.vertices
    free = np.ones(mesh.n_vertices, bool)
    free[:5] = False
    Q = nodal_parameters(V, mesh.simplices, free)
    P = Q[:, :9].reshape(-1, 3, 3)
    T = Q[:, 9:]
    assert np.abs(np.einsum("nab,nb->na", P, T) - T).max() < 1e-15
    assert np.abs(T[:5]).max() == 0 and np.abs(P[:5]).max() == 0
    Pf = P[5:]
    assert np.abs(Pf - Pf.transpose(0, 2, 1)).max() < 1e-15
    assert np.abs(Pf @ Pf - Pf).max() < 1e-14
    assert np.allclose(np.trace(Pf, axis1=1, axis2=2), 2.0)
    ico = shapes.icosphere(2)  # vertex normals of the unperturbed icosphere are nearly radial
    Pi = nodal_parameters(ico.vertices, ico.simplices)[:, :9].reshape(-1, 3, 3)
    assert np.abs(np.einsum("nab,nb->na", Pi, ico.vertices)).max() < 0.05
    poly = shapes.regular_polygon(16)
    assert np.abs(nodal_parameters(poly.vertices, poly.simplices)[:, 4:]).max() < 1e-15


def test_control_improves_a_distorted_sphere_mesh() -> None:
    """An icosphere(2) with its nodes pushed towards the equator (min angle 35.6 deg), three steps at
    tau = h: with the control the min angle rises every step (measured 38.0, 39.5, 40.7); without it
    it first drops (34.1, 33.9, 35.4)."""
    base = shapes.icosphere(2)
    V = base.vertices.copy()
    V[:, 2] += 0.6 * (1 - V[:, 2] ** 2)
    V /= np.linalg.norm(V, axis=1)[:, None]
    mesh = base.with_vertices(V)
    h = mesh.h
    angles = {}
    for control in ("off", "meanratio"):
        flow = WillmoreFlow(mesh, h, 0.1 * h * h, tangential_control=control, tangential_control_weight=10.0,
                            mesh_control="off")  # the in-step control alone
        angles[control] = [flow.state().quality["min_angle"]] + [r.quality["min_angle"] for r in flow.run(steps=3)]
    assert np.all(np.diff(angles["meanratio"]) > 0.5)
    assert angles["off"][1] < angles["off"][0]
    assert angles["meanratio"][-1] > angles["off"][-1] + 3.0


@pytest.mark.parametrize("weight", [0.3, 10.0])
def test_control_changes_the_nodes_not_the_curve(weight: float, curves_agree_before_nodes) -> None:
    """Willmore flow of an ellipse with nodes equally spaced in angle, control off and on, up to t = 0.04
    (tau = h/8): the curves converge to each other under refinement, faster than the nodes. Measured
    (n = 32, 64, 128, 256), beta_c = 10: curve distance 4.4e-3, 1.1e-3, 2.4e-4, 8.2e-5 (order 1.95), node
    distance 3.1e-2, 1.4e-2, 7.2e-3, 3.7e-3 (order 1.0); beta_c = 0.3: curve 1.6e-3, 3.6e-4, 7.6e-5, then
    9.0e-5 at n = 256 (not understood yet; the test uses n <= 128), nodes 9.3e-3 ... 1.3e-3."""
    curves_agree_before_nodes({"tangential_control": "off"},
                              {"tangential_control": "meanratio", "tangential_control_weight": weight})


def test_bad_control_options_are_refused(tmp_path) -> None:
    mesh = shapes.ellipse(16, 1.0, 0.7)
    with pytest.raises(ValueError, match="tangential_control must be one of 'auto', 'off', 'meanratio', got 'smooth'"):
        WillmoreFlow(mesh, mesh.h, 0.1 * mesh.h**2, tangential_control="smooth")
    for bad in (0.0, -1.0, float("nan"), "x"):
        with pytest.raises(ValueError, match="tangential_control_weight must be a number > 0"):
            WillmoreFlow(mesh, mesh.h, 0.1 * mesh.h**2, tangential_control="meanratio", tangential_control_weight=bad)
    with pytest.raises(ValueError, match="semi-implicit: the baseline has no tangential control"):
        WillmoreFlow(mesh, mesh.h, 0.1 * mesh.h**2, tangential_control="meanratio", solver="semi-implicit")
    for key, val, msg in (("tangential_control", "smooth", "must be one of 'auto', 'off', 'meanratio'"),
                          ("tangential_control_weight", "-2", "tangential_control_weight must be a number > 0")):
        cmd = [sys.executable, "-m", "willmore_nlp.cli", "run", "circle", "--set", f"{key}={val}", "--steps", "1",
               "--out", str(tmp_path / "bad")]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert r.returncode == 2 and msg in r.stderr, r.stderr
        assert not (tmp_path / "bad").exists()


def test_auto_is_the_meanratio_control_on_surfaces_and_off_elsewhere() -> None:
    """The default ``tangential_control = "auto"``: on a genus-0 surface in R^3 (or one with a boundary) the flow is
    that of "meanratio" at weight 1 bit for bit; the paper's scheme on
    curves, on closed surfaces of genus >= 1, with
    ``mesh_control = "off"`` and with the semi-implicit baseline (which refuses an explicit "meanratio")."""
    ico = shapes.icosphere(2)
    ell = ico.with_vertices(ico.vertices * [1.0, 1.0, 2.0])  # ellipsoid 1:1:2, 162 v
    tau, tt = ell.h, 0.01 * ell.h**2
    auto = WillmoreFlow(ell, tau, tt)
    explicit = WillmoreFlow(ell, tau, tt, tangential_control="meanratio", tangential_control_weight=1.0)
    assert auto.settings.tangential_control == "auto" and auto._control == explicit._control
    a, b = auto.step(), explicit.step()
    np.testing.assert_array_equal(a.vertices, b.vertices)
    off = WillmoreFlow(ell, tau, tt, tangential_control="off").step()
    assert np.abs(off.vertices - a.vertices).max() > 1e-3 * ell.h
    assert WillmoreFlow(ell, tau, tt, mesh_control="off")._control.method == "off"
    # genus >= 1 closed surfaces keep the paper's tangential freedom (Euler characteristic 0 and -2); a boundary: on
    torus, lawson = shapes.torus(1.0, 0.5, 24, 12), shapes.lawson_genus2()
    assert [euler_characteristic(m.simplices) for m in (torus, lawson, ell)] == [0, -2, 2]
    assert WillmoreFlow(torus, 1e-3, 1e-4)._control.method == "off"
    disk = shapes.disk(4)
    bd = Boundary(np.linalg.norm(disk.vertices[:, :2], axis=1) < 0.6)
    assert WillmoreFlow(disk, disk.h, 0.01 * disk.h**2, boundary=bd)._control.method == "meanratio"
    # a clamped patch of a closed torus (torus_hole): the patch moves, the control is on
    pb, _ = registry.build("torus_hole")
    assert pb.make_flow()._control.method == "meanratio"
    assert WillmoreFlow(ell, tau, tt, solver="semi-implicit")._control.method == "off"
    curve = shapes.ellipse(32, 1.0, 0.7)
    c_auto = WillmoreFlow(curve, curve.h, 0.1 * curve.h**2)
    c_off = WillmoreFlow(curve, curve.h, 0.1 * curve.h**2, tangential_control="off")
    assert c_auto._control.method == "off"
    np.testing.assert_array_equal(c_auto.step().vertices, c_off.step().vertices)


def test_discrete_energy_leaves_the_control_term_out() -> None:
    """e(X) = 1/(2 tt^2) M (Y[X] - X).(Y[X] - X) is the scheme's energy whether or not the step carries the control:
    W at X^k = X still contains beta_c sum_i m_i |P_i S_i|^2 (S the mean-ratio target, not 0 on an ellipsoid),
    which e must not (it did: a flat clamped disk reported e = 3e-5 instead of 1e-9)."""
    ico = shapes.icosphere(2)
    ell = ico.with_vertices(ico.vertices * [1.0, 1.0, 2.0])  # ellipsoid 1:1:2, 162 v
    tau, tt = ell.h, 0.01 * ell.h**2
    on = WillmoreFlow(ell, tau, tt, tangential_control="meanratio")
    off = WillmoreFlow(ell, tau, tt, tangential_control="off")
    X = ell.vertices
    Y = off.evaluator.solve_y(X, off.params(X, 1.0))
    e_off = off.evaluator.f(off.problem.pack_z(X, Y), off.params(X, 1.0)) / 2
    with_term = on.evaluator.f(on.problem.pack_z(X, Y), on.params(X, 1.0)) / 2
    assert with_term - e_off > 1e-5 * e_off  # measured 7.3e-5
    np.testing.assert_allclose(on.discrete_energy(X), e_off, rtol=1e-12)
    np.testing.assert_allclose(off.discrete_energy(X), e_off, rtol=1e-12)


def test_parameters_with_the_control_off_change_no_evaluation_it_does_not_enter() -> None:
    """``off = ("control_weight",)`` (the flow's inner solves, outer constraints and energy e) packs weight 0 and
    zero data without computing them: Y[X] is the same to the last bit as with the data, and so is the objective
    with the weight set to 0; the step's own parameters (weight 7, the data) are left alone."""
    mesh = _perturbed(shapes.icosphere(1), 4)
    setup = build_step(mesh, tangential_control=ON)
    P, ev = setup.problem, StepEvaluator(setup.problem, setup.problem.functions())
    V = mesh.vertices
    full = setup.params(V, 0.2, 0.01 * mesh.h**2, 0.0)
    off = setup.params(V, 0.2, 0.01 * mesh.h**2, 0.0, ("control_weight",))
    assert P.params.scalar(full, "control_weight") == 7.0 and P.params.scalar(off, "control_weight") == 0.0
    changed = np.flatnonzero(P.params.replace(full, control_weight=0.0) != off)  # beside the weight: nodal data
    assert changed.size > 10 and changed.min() >= P.params.nodal_start and np.all(off[changed] == 0.0)
    Y_full, Y_off = ev.solve_y(V, full), ev.solve_y(V, off)
    assert np.array_equal(Y_full, Y_off)
    z = P.pack_z(V + 0.1 * mesh.h, Y_full)
    assert ev.f(z, P.params.replace(full, control_weight=0.0)) == ev.f(z, off)
    assert ev.f(z, full) > ev.f(z, off)


def _trimesh_box(subdivisions: int) -> Mesh:
    import trimesh

    box = trimesh.creation.box(extents=[1.0, 1.4, 0.8])
    for _ in range(subdivisions):
        box = box.subdivide()
    return Mesh(np.array(box.vertices), np.array(box.faces), f"trimesh box, {subdivisions} subdivisions")


def test_auto_leaves_meshes_without_tangent_planes_to_the_papers_scheme() -> None:
    """A box's edges and corners (45 and 55 degrees between the vertex normal and a face's) have no tangent plane,
    resolved smooth meshes do (largest angle 21 degrees): "auto" is off on the box. Measured on the box subdivided
    three times (386 v): with the control its first step failed at every tau from h to h/256 (IPOPT over its
    first-step budget, then edge ratio 4e3); fading the term at those nodes instead cost `torus_hole`'s noisy fill
    its rest (2.8e-5 per step at step 100, 8.8 deg) and the vesicle cup its run (failed at t = 0.21)."""
    box = _trimesh_box(2)
    bad = unresolved_nodes(box)
    on_edge = (np.isclose(np.abs(box.vertices), [0.5, 0.7, 0.4]).sum(axis=1)) >= 2
    assert on_edge.sum() == 44
    np.testing.assert_array_equal(bad, on_edge)
    for mesh in (shapes.icosphere(1), shapes.icosphere(3), shapes.torus(1.0, 0.5, 24, 12), shapes.disk(6)):
        assert not unresolved_nodes(mesh).any()
    assert WillmoreFlow(box, box.h, 0.01 * box.h**2)._control.method == "off"
    # a clamped patch counts only its free nodes: the box's bottom face clamped, the rest still has the edges
    free = box.vertices[:, 2] > -0.39
    assert WillmoreFlow(box, box.h, 0.01 * box.h**2, boundary=Boundary(free))._control.method == "off"
    smooth = shapes.icosphere(2)
    assert WillmoreFlow(smooth, smooth.h, 0.01 * smooth.h**2)._control.method == "meanratio"


def test_a_weight_given_where_auto_leaves_the_control_off_is_named() -> None:
    """``tangential_control_weight`` with ``tangential_control = "auto"`` on a flow where "auto" is "off" (here a
    torus, genus 1) does nothing; it warns instead of being silently unused (found by a new-user check on a trimesh
    cylinder, whose sharp rims keep the control off: weights 1, 10 and 100 gave the same 40 steps bit for bit). An
    explicit "off", or a flow where the control runs, does not warn."""
    import warnings

    torus = shapes.torus(1.0, 0.5, 16, 8)
    with pytest.warns(UserWarning, match="tangential_control_weight = 5 is not used: tangential_control = 'auto'"):
        flow = WillmoreFlow(torus, 0.01, 1e-4, tangential_control_weight=5.0)
    assert flow.tangential_control.method == "off"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        WillmoreFlow(torus, 0.01, 1e-4, tangential_control="off", tangential_control_weight=5.0)
        sphere = WillmoreFlow(shapes.icosphere(2), 0.01, 1e-4, tangential_control_weight=5.0)
    assert sphere.tangential_control.method == "meanratio" and sphere.tangential_control.weight == 5.0


def test_a_first_step_the_control_makes_hard_is_solved_from_the_step_without_it() -> None:
    """``sphere_cap`` from its flat start (12 rings, conormal): from the state, the step with the control wanders on
    IPOPT's path (255 iterations without a budget; three budget cuts and tau / 8 with the default budget of 100, here
    30); from the step without the control (13 iterations) it takes 4 at tau, the attempt reporting all three."""
    pb, _ = registry.build("sphere_cap", init="flat", amp=0.5)
    flow = pb.make_flow(first_step_budget=30)
    assert flow.tangential_control.enabled
    r = flow.step()
    assert (r.retries, r.tau) == (0, flow.tau)
    assert r.iterations <= 30 + 25 and r.stats["n_eval_hess"] == r.iterations  # the counts of the three solves
    assert flow.step().iterations <= 9  # (a second step starts from the flow's own state)


def test_the_control_free_start_is_for_ipopt_only(monkeypatch) -> None:
    """newton-krylov's failed first attempts (its guarded pass is its own way) are not solved again without the
    control: on a 10,242-vertex ellipsoid both failed attempts failed without it too and step 1 took 297 s for 160."""
    pb, _ = registry.build("sphere_cap", init="flat", amp=0.5, rings=4)
    flow = pb.make_flow(solver="newton-krylov")
    assert flow.tangential_control.enabled
    calls: list[int] = []
    monkeypatch.setattr(flow.solver, "solve", lambda *a, **k: calls.append(1))
    cold = object()
    z0 = flow.problem.pack_z(flow.X, flow.Y)
    assert flow._from_control_free_step(cold, z0, flow.params(flow.X, flow.tau), flow.tau) is cold and not calls


def test_with_the_control_a_step_lowers_the_energy_plus_the_controls_term(tmp_path, monkeypatch) -> None:
    """A new user's clamped saddle z = 0.2 (x^2 - y^2) on a 15 x 15 grid (225 v, ``clamp = conormal``, the ``file``
    problem's defaults: the control on, the light repair between steps). The energy inequality of a step with the
    control is 2 tau e(X^{k+1}) + |X^{k+1} - X^k|_M^2 + c(X^{k+1}) <= W_c(X^k) = 2 tau e(X^k) + c(X^k): the energy
    alone may rise by up to c(X^k) / (2 tau), and after the repairs it does (measured: 18 of 20 steps, by up to
    1.9e-4 of e, the control's share up to 0.43 e); the inequality holds in every step. Without the control no step
    raises e (the README's and mesh_quality.md's statements). The saddle is a healthy state at rest: with the defaults
    the controls pause after the first step (``flow.REST_SPEED``) and no step raises e either, so the control's steps
    are taken with the pause off (REST_SPEED = 0)."""
    n = 15
    x = np.linspace(-1.0, 1.0, n)
    gx, gy = np.meshgrid(x, x)
    V = np.c_[gx.ravel(), gy.ravel(), 0.2 * (gx.ravel() ** 2 - gy.ravel() ** 2)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):  # the square a, b = a + 1, c = a + n, d = c + 1, its diagonal alternating
            a = i * n + j
            b, c, d = a + 1, a + n, a + n + 1
            F += [[a, b, d], [a, d, c]] if (i + j) % 2 == 0 else [[a, b, c], [b, d, c]]
    path = tmp_path / "saddle.obj"
    save_mesh(Mesh(V, np.array(F)), path)
    pb, _ = registry.build("file", path=str(path), clamp="conormal")
    rises = {}
    for control, pause in (("auto", 0.0), ("off", 0.0), ("auto", flow_module.REST_SPEED)):
        monkeypatch.setattr(flow_module, "REST_SPEED", pause)
        flow = pb.make_flow(tangential_control=control)
        e, count = flow.discrete_energy(flow.X), 0
        for _ in range(6):
            X = flow.X
            p = flow.params(X, flow.tau)
            w0 = flow.evaluator.f(flow.problem.pack_z(X, flow.evaluator.solve_y(X, p)), p)  # W_c(X^k) (e's 2 tau)
            r = flow.step()
            stepped = float(r.stats.get("energy_before_remesh", r.energy))  # (no mesh control after a paused step)
            assert 2 * r.tau * stepped <= w0 * (1 + 1e-9)
            count += stepped > e * (1 + 1e-8)
            e = r.energy
        rises[control, pause] = count
    assert rises["auto", 0.0] >= 3 and rises["off", 0.0] == 0 and rises["auto", flow_module.REST_SPEED] == 0
