"""Anisotropic Willmore flow: derivatives of A_gamma, closed forms, the isotropic limit, long-run shapes."""

import subprocess
import sys

import casadi as ca
import numpy as np
import pytest
from scipy.special import ellipe

from willmore_nlp import WillmoreFlow, registry
from willmore_nlp.analysis import axis_widths, fit_order
from willmore_nlp.anisotropy import (
    AnisotropyError,
    anisotropic_area,
    anisotropic_area_gradient,
    anisotropic_willmore_energy,
    get_anisotropy,
)
from willmore_nlp.fem.assembly import mass_stiffness
from willmore_nlp.geometry import enclosed_volume, willmore_energy
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator

PRESETS = ["gamma0", "gamma1", "gamma2", "gamma2:1e-2"]


def _mesh(m: int, seed: int = 0) -> Mesh:
    """A perturbed ellipse (m = 2) or icosphere (m = 3)."""
    rng = np.random.default_rng(seed)
    base = shapes.ellipse(14, 1.0, 0.7) if m == 2 else shapes.icosphere(1)
    return base.with_vertices(base.vertices + 0.05 * base.h * rng.normal(size=base.vertices.shape))


@pytest.mark.parametrize("m", [2, 3])
@pytest.mark.parametrize("spec", PRESETS)
def test_area_gradient_and_hessian_fd(spec: str, m: int) -> None:
    """grad A_gamma (numpy chain rule) against central differences of A_gamma; the step problem's
    inner residual g = M (Y - X) + tt grad A_gamma[Y] against that gradient (independent assembly);
    dg/dY = M + tt Hess A_gamma against central differences of g (the Hessian of A_gamma)."""
    an = get_anisotropy(spec, m)
    mesh = _mesh(m)
    V, S = mesh.vertices, mesh.simplices
    rng = np.random.default_rng(1)
    G = anisotropic_area_gradient(an, V, S)
    eps = 1e-6
    for _ in range(3):
        D = rng.normal(size=V.shape)
        fd = (anisotropic_area(an, V + eps * D, S) - anisotropic_area(an, V - eps * D, S)) / (2 * eps)
        assert abs(np.sum(G * D) - fd) <= 1e-7 * max(1.0, abs(fd))

    setup = build_step(mesh, anisotropy=spec)
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    X = V + 0.1 * mesh.h * rng.normal(size=V.shape)
    Y = X + 0.1 * mesh.h * rng.normal(size=V.shape)
    tt = 0.1 * mesh.h**2
    p = setup.params(V, 0.3, tt, 0.5)
    z = P.pack_z(X, Y)
    M, _ = mass_stiffness(X, S)
    expected = M @ (Y - X) + tt * anisotropic_area_gradient(an, Y, S)
    np.testing.assert_allclose(ev.g(z, p).reshape(-1, m), expected, rtol=1e-9, atol=1e-12)
    Jy = ev.jac_g(z, p)[:, P.nX * m :]
    for _ in range(3):
        d = rng.normal(size=z.size)
        d[: P.nX * m] = 0.0
        fd = (ev.g(z + eps * d, p) - ev.g(z - eps * d, p)) / (2 * eps)
        assert np.max(np.abs(Jy @ d[P.nX * m :] - fd)) <= 1e-5 * np.max(np.abs(fd))


@pytest.mark.parametrize("spec", ["gamma1", "gamma2:1e-2"])
def test_step_problem_derivatives_fd(spec: str) -> None:
    """Gradient of W, Jacobian of g and the Lagrangian Hessian (third derivatives of A_gamma) against FD."""
    mesh = _mesh(2)
    setup = build_step(mesh, anisotropy=spec)
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    rng = np.random.default_rng(2)
    X = mesh.vertices + 0.1 * mesh.h * rng.normal(size=mesh.vertices.shape)
    Y = X + 0.1 * mesh.h * rng.normal(size=X.shape)
    z, p = P.pack_z(X, Y), setup.params(mesh.vertices, 0.3, 0.1 * mesh.h**2, 0.5)
    eps = 1e-6
    d = rng.normal(size=z.size)
    fd = (ev.f(z + eps * d, p) - ev.f(z - eps * d, p)) / (2 * eps)
    np.testing.assert_allclose(ev.grad_f(z, p) @ d, fd, rtol=1e-6)
    lam_g = rng.normal(size=P.ng)

    def lag_grad(zz: np.ndarray) -> np.ndarray:
        return 0.7 * ev.grad_f(zz, p) + ev.jac_g(zz, p).T @ lam_g

    fdh = (lag_grad(z + eps * d) - lag_grad(z - eps * d)) / (2 * eps)
    assert np.max(np.abs(ev.hess_lag(z, p, 0.7, lam_g) @ d - fdh)) <= 1e-5 * np.max(np.abs(fdh))


def test_anisotropic_willmore_energy_converges_to_closed_forms() -> None:
    """On the Wulff shape R W_gamma, h_gamma = 1/R, so w_gamma = perimeter(W_gamma) / (2 R): for gamma1
    the ellipse with semi-axes 1 (x1) and 2 (x2); for gamma0 the circle, pi / R, equal to the isotropic
    discrete Willmore energy. Second-order convergence over four refinements."""
    g0, g1 = get_anisotropy("gamma0", 2), get_anisotropy("gamma1", 2)
    R = 1.5
    perimeter = 8 * ellipe(0.75)
    ns = [32, 64, 128, 256]
    err0, err1 = [], []
    for n in ns:
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        wulff = shapes.closed_curve(R * np.column_stack([np.cos(t), 2 * np.sin(t)]))
        circle = shapes.regular_polygon(n, R)
        err1.append(abs(anisotropic_willmore_energy(wulff, g1) - perimeter / (2 * R)))
        w0 = anisotropic_willmore_energy(circle, g0)
        assert w0 == pytest.approx(willmore_energy(circle), rel=1e-12)
        err0.append(abs(w0 - np.pi / R))
    h = 1.0 / np.array(ns)
    assert fit_order(h, err1) == pytest.approx(2.0, abs=0.1)
    assert fit_order(h, err0) == pytest.approx(2.0, abs=0.1)


def test_gamma0_tends_to_the_isotropic_step_as_tau_tilde_shrinks() -> None:
    """One step of the fully nonlinear scheme with gamma0 against the linearised isotropic scheme: the
    difference is O(tau_tilde) (the inner steps differ by tt (L[Y] - L[X]) Y = O(tt^2), i.e. O(tt) in
    (Y - X) / tt). Measured: 1.18e-3, 5.90e-4, 2.95e-4, 1.48e-4."""
    mesh = shapes.ellipse(32, 1.0, 0.7)
    h = mesh.h
    tts = np.array([0.04, 0.02, 0.01, 0.005]) * h * h
    diff = []
    for tt in tts:
        a = WillmoreFlow(mesh, h / 2, tt, lam=0.5, anisotropy="gamma0", tol=1e-11, max_iter=500).step()
        b = WillmoreFlow(mesh, h / 2, tt, lam=0.5, tol=1e-11, max_iter=500).step()
        diff.append(np.abs(a.vertices - b.vertices).max())
    assert np.abs(a.vertices - mesh.vertices).max() > 50 * diff[-1]  # the step itself is much larger
    assert fit_order(tts, diff) == pytest.approx(1.0, abs=0.1)


def test_long_runs_tend_to_the_expected_shapes() -> None:
    """gamma0: an ellipse becomes round; gamma1: the curve turns to the x2 axis, as the Wulff shape
    x1^2 + x2^2/4 <= 1 predicts, with axis ratio near 2; regularised l1 (eps = 1e-2): a square with
    rounded corners aligned with the axes (diagonal width / axial width between 1, the circle, and
    sqrt(2), the square). The discrete energy never increases."""
    mesh = shapes.ellipse(64, 3.0, 2.4)
    h = mesh.h
    out = {}
    for spec, tau, steps in (("gamma0", h, 40), ("gamma1", h, 40), ("gamma2:1e-2", h / 4, 40)):
        f = WillmoreFlow(mesh, tau, 0.1 * h * h, lam=0.05, anisotropy=spec)
        e = [f.state().energy]
        for _ in range(steps):
            r = f.step()
            e.append(r.energy)
        assert np.all(np.diff(e) <= 1e-9 * abs(e[0]))
        assert np.isfinite(r.willmore_gamma) and r.willmore_gamma > 0
        out[spec] = axis_widths(r.vertices)
    w0, w1, w2 = out["gamma0"], out["gamma1"], out["gamma2:1e-2"]
    assert w0[1] / w0[0] == pytest.approx(1.0, abs=0.05)  # started at 0.8
    assert 1.7 < w1[1] / w1[0] < 2.3  # started at 0.8, elongated along x1
    assert w2[2:].mean() / w2[:2].mean() > 1.2  # circle 1.0, square 1.414; started at 1.01
    assert w0[2:].mean() / w0[:2].mean() == pytest.approx(1.0, abs=0.02)


def test_surface_stretches_along_the_wulff_axis() -> None:
    """gamma1 in R^3 (Wulff shape x1^2 + x2^2/4 + x3^2 <= 1): a sphere stretches along x2 towards
    axis ratio 2 and stays round across x2 (measured 2.11 after 10 steps, x3/x1 1.008, min angle 37)."""
    pb = registry.get("anisotropic_sphere").factory(steps=10)
    f = pb.make_flow()
    for _ in range(pb.steps):
        r = f.step()
    w = axis_widths(r.vertices)
    assert 1.8 < w[1] / w[0] < 2.3
    assert w[2] / w[0] == pytest.approx(1.0, abs=0.02)
    assert r.quality["min_angle"] > 25


def test_bad_anisotropies_are_refused() -> None:
    cases = [
        (lambda z: ca.sumsqr(z), "not 1-homogeneous"),
        (lambda z: z[0], "not positive"),
        (lambda z: ca.fabs(z[0]), "not positive"),
        (lambda z: 1.0 + 0 * z[0], "not 1-homogeneous"),
        (lambda z: z, "must be a scalar"),
    ]
    for fn, msg in cases:
        with pytest.raises(AnisotropyError, match=msg):
            get_anisotropy(fn, 2)
    with pytest.raises(AnisotropyError, match="unknown anisotropy 'gamma9'"):
        get_anisotropy("gamma9", 2)
    with pytest.raises(AnisotropyError, match="gamma2:EPS"):
        get_anisotropy("gamma2:abc", 2)
    with pytest.raises(AnisotropyError, match="defined on R\\^3"):
        get_anisotropy(get_anisotropy("gamma1", 3), 2)
    with pytest.raises(MeshError, match="curve in R\\^2"):
        build_step(shapes.regular_polygon(8, m=3), anisotropy="gamma1")
    arc = shapes.open_curve(np.column_stack([np.linspace(0, 1, 5), np.zeros(5)]))
    with pytest.raises(MeshError, match="closed"):
        build_step(arc, anisotropy="gamma1")


def test_bunny_is_a_436_node_closed_curve() -> None:
    module = registry.problem_module("anisotropic")
    BUNNY_H, bunny_curve = module.BUNNY_H, module.bunny_curve
    b = bunny_curve()
    assert b.n_vertices == 436 and b.is_closed and b.m == 2
    assert b.h == pytest.approx(BUNNY_H, rel=0.01)
    e = np.linalg.norm(np.roll(b.vertices, -1, 0) - b.vertices, axis=1)
    assert e.max() / e.min() < 1.5  # resampled by arc length
    assert enclosed_volume(b) > 0  # counter-clockwise


def test_cli_runs_the_fig11_bunny_and_the_sphere(tmp_path) -> None:
    from willmore_nlp import load_run

    cli = [sys.executable, "-m", "willmore_nlp.cli"]
    for args in (["bunny", "--set", "gamma=gamma0"], ["bunny", "--set", "gamma=gamma1"],
                 ["bunny", "--set", "gamma=gamma2:0.1"], ["anisotropic_sphere", "--set", "subdivisions=1"]):
        out = tmp_path / "_".join(args).replace("=", "-")
        r = subprocess.run([*cli, "run", *args, "--steps", "2", "--out", str(out)],
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        run = load_run(out)
        assert len(run.states) == 3
        assert "willmore_gamma" in (out / "history.csv").read_text().splitlines()[0]
        if "gamma=gamma2:0.1" in args:
            assert run.config["effective_flow_options"]["tangential_weight"] == 1000.0
    bad = subprocess.run([*cli, "run", "bunny", "--set", "gamma=gamma7", "--steps", "1", "--out",
                          str(tmp_path / "bad")], capture_output=True, text=True, timeout=600)
    assert bad.returncode != 0 and "unknown anisotropy 'gamma7'" in bad.stderr
    assert not (tmp_path / "bad").exists()


def test_the_anisotropic_problems_take_their_anisotropy_from_gamma_only(tmp_path, capsys) -> None:
    """``run bunny --set gamma=gamma0 --set anisotropy=gamma2`` ran gamma2 with gamma0's tangential weight 1 and no
    redistribution, failed its first step (exit 1) and recorded params.gamma = 'gamma0' (a new-user check): the flow
    option ``anisotropy`` of ``bunny`` and ``anisotropic_sphere`` is refused in one line naming ``gamma``."""
    from willmore_nlp import cli
    from willmore_nlp.registry import ProblemError

    out = tmp_path / "r"
    assert cli.main(["run", "bunny", "--set", "gamma=gamma0", "--set", "anisotropy=gamma2", "--steps", "1",
                     "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "anisotropy is set by the problem's parameters; set gamma instead" in err, err
    assert not out.exists()
    pb, _ = registry.build("anisotropic_sphere", subdivisions=0)
    with pytest.raises(ProblemError, match="anisotropy is set by the problem's parameters; set gamma instead"):
        pb.make_flow(anisotropy="gamma0")


def test_a_clamped_anisotropic_flow_reports_its_anisotropic_energy() -> None:
    """willmore_gamma was NaN for every clamped anisotropic run (the clamped step setup did not carry the anisotropy;
    found by a new-user check). On a clamped cap with the ring variant gamma0's w_gamma equals the isotropic W over
    the same nodes (patch and Gamma) to round-off, and gamma1's is finite and larger."""
    from willmore_nlp.boundary import Boundary

    cap = shapes.spherical_cap(6, 60.0)
    out = {}
    for name in ("gamma0", "gamma1"):
        flow = WillmoreFlow(cap, 0.1 * cap.h, cap.h**2 / 100, anisotropy=name,
                            boundary=Boundary.outer_strip(cap, "ring"))
        out[name] = flow.state()
    assert out["gamma0"].willmore_gamma == pytest.approx(out["gamma0"].willmore, rel=1e-12)
    assert np.isfinite(out["gamma1"].willmore_gamma) and out["gamma1"].willmore_gamma > out["gamma1"].willmore


def test_a_clamped_anisotropic_patch_keeps_its_mesh_without_remeshing() -> None:
    """A clamped surface with an anisotropy gets the in-step control at weight 100 (``default_weight``). Found by a
    new-user check: ``sphere_cap`` with the ring variant and gamma1 slid its first free row toward Gamma in every step
    (stepped triangles at 7-8 deg), which the mesh control remeshed after every step, with 3 retries per step. With the
    default weight: steps at tau, no retry, no remeshing, every stepped state above 30 deg; weight 1 (given) keeps the
    behaviour before. Isotropic clamped patches and closed anisotropic surfaces keep weight 1."""
    from willmore_nlp.tangential import ANISOTROPIC_CLAMPED_CONTROL_WEIGHT, DEFAULT_CONTROL_WEIGHT

    pb, _ = registry.build("sphere_cap", rings=6, variant="ring")
    flow = pb.make_flow(anisotropy="gamma1")
    assert flow.tangential_control.weight == ANISOTROPIC_CLAMPED_CONTROL_WEIGHT
    steps = [flow.step() for _ in range(4)]
    assert [(r.retries, r.tau) for r in steps] == [(0, pb.tau)] * 4
    assert not any("remesh" in r.remeshed for r in steps)
    assert min(r.stats.get("min_angle_before_remesh", r.quality["min_angle"]) for r in steps) > 30.0  # (a paused
    # step, flow.REST_SPEED, has no mesh control)
    before = pb.make_flow(anisotropy="gamma1", tangential_control_weight=1.0)
    slid = [before.step() for _ in range(2)]
    assert all("remesh" in r.remeshed and r.stats["min_angle_before_remesh"] < 15.0 for r in slid)
    assert all(r.retries > 0 and r.tau < pb.tau for r in slid)
    assert pb.make_flow().tangential_control.weight == DEFAULT_CONTROL_WEIGHT
    ellipsoid = WillmoreFlow(shapes.icosphere(2), 0.1, 1e-3, anisotropy="gamma1")
    assert ellipsoid.tangential_control.weight == DEFAULT_CONTROL_WEIGHT


def test_the_report_of_an_anisotropic_flow_shows_w_gamma_and_the_wulff_reference(tmp_path) -> None:
    """An anisotropic run's report showed the isotropic W alone (rising: the flow lowers w_gamma) and "no closed-form
    value" (a new user's check). Now its summary has w_gamma first -> last from history.csv, its energy figure draws
    it, and a closed gamma1 surface gets the Wulff shape's w_gamma, 2 |W_1|: checked against the arcsin closed form
    of the prolate spheroid's area (semi-axes 1, 2, 1), and its mesh-matched value against w_gamma of a mesh whose
    vertices lie on a Wulff shape already (the projection leaves them: the same number). gamma2 has no reference."""
    from willmore_nlp import load_run
    from willmore_nlp.anisotropy import gamma1_wulff_energy
    from willmore_nlp.apps.report import write_report
    from willmore_nlp.references import references

    e = np.sqrt(3) / 2
    assert gamma1_wulff_energy() == pytest.approx(2 * 2 * np.pi * (1 + 2 * np.arcsin(e) / e), rel=1e-13)
    ico = shapes.icosphere(2)
    wulff = ico.with_vertices(1.7 * ico.vertices * [1.0, 2.0, 1.0] + [0.2, 0.0, -0.1])
    refs, note = references(wulff, 0.0, 1e-3, np.zeros(1), {"anisotropy": "gamma1"})
    assert [r.column for r in refs] == ["willmore_gamma"] and "Wulff" in note
    assert refs[0].smooth == pytest.approx(42.956870655767, rel=1e-12)
    assert refs[0].matched == pytest.approx(anisotropic_willmore_energy(wulff, get_anisotropy("gamma1", 3)),
                                            rel=1e-12)
    assert references(wulff, 0.0, 1e-3, np.zeros(1), {"anisotropy": "gamma2"})[0] == []
    assert references(wulff, 0.0, 1e-3, np.zeros(1), {"anisotropy": "gamma1", "volume": 1.0})[0] == []
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "run", "anisotropic_sphere", "--set",
                        "subdivisions=1", "--steps", "2", "--out", str(out), "--quiet"], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    md = write_report(out).read_text()
    h = load_run(out).history
    assert (f"| anisotropic Willmore energy w_gamma (first -> last; what the flow lowers) | "
            f"{h[0]['willmore_gamma']:.6g} -> {h[-1]['willmore_gamma']:.6g} |") in md
    assert f"| willmore_gamma | {h[-1]['willmore_gamma']:.6g} | 42.9569 (twice the area of the unit Wulff" in md


def test_an_anisotropy_of_a_huge_scale_is_refused_and_a_large_one_warned() -> None:
    """gamma -> s gamma acts as tau_tilde -> s tau_tilde. A new user's gamma2:1e20 (s = 3e10 from the regularisation,
    3e8 h^2 with the default tau_tilde) exited 70 with a CHOLMOD traceback from the first look at tau_c; caught, the
    IPOPT fallback's attempts then ran for minutes. Above ANISOTROPY_INNER_MAX h^2 the flow is refused (one line
    naming tau_tilde, the anisotropy and its scale); above 2 h^2 the StepSizeWarning names the scale. The scale is
    the largest gamma on unit normals: gamma1's 2, gamma2:EPS's sqrt(3 (1 + 3 EPS)) at the diagonals."""
    from willmore_nlp.errors import UserInputError
    from willmore_nlp.flow import StepSizeWarning

    assert get_anisotropy("gamma1", 3).scale == pytest.approx(2.0, rel=1e-6)
    assert get_anisotropy("gamma2:1e4", 3).scale == pytest.approx(np.sqrt(3 * (1 + 3e4)), rel=1e-3)
    mesh = shapes.icosphere(1)
    tt = mesh.h**2 / 100
    with pytest.raises(UserInputError, match=r"^tau_tilde = .* x the scale 3e\+10 of anisotropy gamma2_eps1e20 .* "
                                             r"above 10000 h\^2, where no step solves"):
        WillmoreFlow(mesh, mesh.h, tt, anisotropy="gamma2:1e20")
    with pytest.warns(StepSizeWarning, match=r"x the scale 300 of anisotropy gamma2_eps1e04 .* is 3 h\^2"):
        WillmoreFlow(mesh, mesh.h, tt, anisotropy="gamma2:1e4")


def test_a_flow_builds_and_validates_its_anisotropy_once(monkeypatch) -> None:
    """The step scales (the anisotropy's scale) and every build of the step problem (the first, and each after a
    remeshing) read one Anisotropy: its CasADi gamma was built and validated on 2,000 samples twice at start-up and
    once more at every rebuild. Counted through the validation, and the rebuilt problem's anisotropy is the same
    object."""
    import willmore_nlp.anisotropy as anisotropy

    calls = []
    real = anisotropy.validate
    monkeypatch.setattr(anisotropy, "validate", lambda an, *a, **k: (calls.append(an.name), real(an, *a, **k)))
    mesh = shapes.icosphere(1)
    flow = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, anisotropy="gamma1")
    assert calls == ["gamma1"]
    first = flow.setup.anisotropy
    flow._build(flow.mesh, flow.boundary)
    assert flow.setup.anisotropy is first and calls == ["gamma1"]


def test_the_wulff_nodes_lie_on_the_wulff_shape_about_the_centroid() -> None:
    """gamma1_wulff_nodes moves points along rays from their centroid to gauge 1 about it: each node keeps its
    direction from the centroid, its gauge about the input's centroid is 1, and points on the unit Wulff shape stay (the
    mesh-matched reference of such a mesh is its own w_gamma, the report test above)."""
    from willmore_nlp.anisotropy import gamma1_wulff_gauge, gamma1_wulff_nodes

    rng = np.random.default_rng(3)
    X = rng.normal(size=(200, 3)) * [1.0, 3.0, 0.5] + [0.4, -1.0, 2.0]
    c = X.mean(axis=0)
    W = gamma1_wulff_nodes(X)
    r = np.sqrt((((W - c) / [1.0, 2.0, 1.0]) ** 2).sum(axis=1))
    assert np.allclose(r, 1.0, atol=1e-13)
    assert np.allclose(gamma1_wulff_gauge(X) * np.linalg.norm(W - c, axis=1), np.linalg.norm(X - c, axis=1))
    cos = np.sum((W - c) * (X - c), axis=1) / np.linalg.norm(W - c, axis=1) / np.linalg.norm(X - c, axis=1)
    assert np.allclose(cos, 1.0, atol=1e-13)
    on = shapes.icosphere(2).vertices * [1.0, 2.0, 1.0]
    assert np.allclose(gamma1_wulff_nodes(on), on, atol=1e-13)
