"""The ``newton-krylov`` step solver against IPOPT, the energy inequality and the circle's radius equation."""

import subprocess
import sys
import warnings

import numpy as np
import pytest
import trimesh

from willmore_nlp import WillmoreFlow, registry
from willmore_nlp.analysis import circle_step_radius, fit_order
from willmore_nlp.errors import UserInputError
from willmore_nlp.flow import FlowError
from willmore_nlp.mesh import shapes
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.solvers import make_solver, newton_krylov
from willmore_nlp.solvers.cholesky import SymmetricFactor


def _ellipsoid(sub: int = 2):
    m = shapes.icosphere(sub)
    return m.with_vertices(m.vertices * np.array([1.0, 1.0, 1.3]))


def _cap(variant: str):
    pb, _ = registry.build("sphere_cap", rings=4, variant=variant, init="flat", amp=0.5)
    return pb.mesh, pb.tau, pb.tau_tilde, pb.lam, pb.flow_options


def _case(name: str):
    """(mesh, tau, tt, lam, flow options) of the one-step comparisons."""
    if name == "ellipsoid":
        mesh = _ellipsoid()
        return mesh, 0.2 * mesh.h, mesh.h**2 / 100, 0.0, {}
    if name == "curve":
        mesh = shapes.ellipse(32, 1.0, 0.7)
        return mesh, 0.5 * mesh.h, 0.1 * mesh.h**2, 0.5, {}
    if name in ("cap-ring", "cap-conormal"):
        return _cap(name.split("-")[1])
    if name == "blend-conormal":  # the step's simplices (patch and ring) leave nodes out: a MeshError once
        pb, _ = registry.build("surface_blending", n_around=16, n_gap=4)
        return pb.mesh, pb.tau, pb.tau_tilde, pb.lam, pb.flow_options
    if name == "anisotropic-curve":
        mesh = shapes.ellipse(24, 1.0, 0.7)
        return mesh, 0.5 * mesh.h, 0.1 * mesh.h**2, 0.5, {"anisotropy": "gamma1"}
    if name == "tangential-weight":
        mesh = _ellipsoid(1)
        return mesh, 0.5 * mesh.h, 0.1 * mesh.h**2, 0.0, {"tangential_weight": 4.0}
    if name == "tangential-control":
        mesh = _ellipsoid()
        return mesh, 0.2 * mesh.h, mesh.h**2 / 100, 0.0, {"tangential_control": "meanratio"}
    raise ValueError(name)


CASES = ["ellipsoid", "curve", "cap-ring", "cap-conormal", "blend-conormal", "anisotropic-curve", "tangential-weight",
         "tangential-control"]


@pytest.mark.parametrize("name", CASES)
def test_one_step_matches_ipopt(name: str) -> None:
    """X^{k+1} of newton-krylov (tol 1e-10) equals IPOPT's at tol 1e-12 to 1e-8 of the step's displacement
    (measured 5e-14 to 3.4e-9; tangential control "meanratio" 2.3e-10), with the CHOLMOD factorisation and
    with the SuperLU fallback (``cholesky="scipy"``); the reduced gradient meets the stopping test and
    Y = Y[X] holds to rounding. At the default tol 1e-9 the difference was up to 5e-8 of the step (the
    flattened caps, whose gradient scale is large)."""
    mesh, tau, tt, lam, opts = _case(name)
    off = {"mesh_control": "off", "max_retries": 0, **opts}
    ref = WillmoreFlow(mesh, tau, tt, lam=lam, tol=1e-12, max_iter=1000, **off).step()
    step = np.abs(ref.vertices - mesh.vertices).max()
    assert step > 1e-3 * mesh.h  # the step moves: the comparison is not between two copies of X^k
    r = WillmoreFlow(mesh, tau, tt, lam=lam, solver="newton-krylov", tol=1e-10, **off).step()
    assert r.converged and r.stats["kkt_residual"] <= r.stats["gtol"]
    assert r.stats["inf_pr"] <= 1e-10 * max(1.0, np.abs(r.Y).max())
    assert np.abs(r.vertices - ref.vertices).max() <= 1e-8 * step
    s = WillmoreFlow(mesh, tau, tt, lam=lam, solver="newton-krylov", tol=1e-10, cholesky="scipy", **off).step()
    assert s.stats["cholesky"] == "scipy" and r.stats["cholesky"] in ("cholmod", "scipy")
    assert np.abs(s.vertices - ref.vertices).max() <= 1e-8 * step


def test_energy_inequality_and_stats() -> None:
    """W(X^{k+1}, Y^{k+1}) <= W(X^k, Y[X^k]) with Y = Y[X] at the solution (the scheme's energy inequality,
    reached from a feasible start by a monotone line search), and the reported counts are consistent."""
    mesh = _ellipsoid()
    h = mesh.h
    setup = build_step(mesh)
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    solver = make_solver("newton-krylov", ev, {})
    p = setup.params(mesh.vertices, 0.2 * h, h * h / 100, 0.0)
    Y0 = ev.solve_y(mesh.vertices, p)
    z0 = P.pack_z(mesh.vertices, Y0)
    res = solver.solve(z0, p)
    assert res.converged and res.status == "converged"
    assert res.f < ev.f(z0, p)
    assert res.f == pytest.approx(ev.f(res.z, p), rel=1e-14)
    X, Y = P.unpack_z(res.z, mesh.vertices)
    assert np.abs(Y - ev.solve_y(X, p, Y)).max() <= 1e-12 * np.abs(Y).max()
    st = res.stats
    assert res.iterations == st["newton_iterations"] >= 2
    assert st["n_cg"] >= res.iterations  # at least one CG iteration per Newton system
    assert st["n_factorizations"] >= res.iterations + 1 and st["n_precond_builds"] >= 1
    assert st["n_eval_hess"] >= res.iterations
    parts = st["t_wall_eval"] + st["t_wall_factor"] + st["t_wall_cg"]
    assert 0 < parts <= st["t_wall_total"]


def test_circle_follows_the_time_discrete_radius_equation() -> None:
    """Regular n-gons stay regular and after 4 steps their radius differs from the time-discrete,
    space-continuous radius equation of Sec. 2.1 by O(h^2) (measured 0.626 h^2 tau for n = 64, 128, 256:
    fitted order 2.00); the newton-krylov flow equals IPOPT's to 1e-10 (measured 9e-12)."""
    tau, tt = 0.01, 1e-4
    hs, errs = [], []
    for n in (64, 128, 256):
        mesh = shapes.regular_polygon(n, 1.0)
        flows = {s: WillmoreFlow(mesh, tau, tt, solver=s) for s in ("newton-krylov", "ipopt")}
        R_exact = 1.0
        for _ in range(4):
            R_exact = circle_step_radius(R_exact, tau, tt)
            out = {s: f.step().vertices for s, f in flows.items()}
            assert np.abs(out["newton-krylov"] - out["ipopt"]).max() <= 1e-10
        R = np.linalg.norm(out["newton-krylov"], axis=1)
        assert R.std() < 1e-12
        hs.append(mesh.h)
        errs.append(abs(R.mean() - R_exact))
    assert fit_order(hs, errs) == pytest.approx(2.0, abs=0.05)


def test_short_surface_flow_matches_ipopt() -> None:
    """Five steps on the ellipsoid, both solvers at tol 1e-11: the newton-krylov flow stays on IPOPT's to
    1e-9 h (measured 1.1e-10 h; 4e-8 h with newton-krylov at its default tol 1e-9) and the Willmore energy
    decreases at every step."""
    mesh = _ellipsoid()
    h = mesh.h
    a = WillmoreFlow(mesh, 0.2 * h, h * h / 100, solver="newton-krylov", tol=1e-11)
    b = WillmoreFlow(mesh, 0.2 * h, h * h / 100, tol=1e-11, max_iter=1000)
    energy = [a.discrete_energy(a.X)]
    for _ in range(5):
        ra, rb = a.step(), b.step()
        assert ra.t == rb.t and np.abs(ra.vertices - rb.vertices).max() <= 1e-9 * h
        energy.append(a.discrete_energy(a.X))
    assert np.all(np.diff(energy) < 0)


def test_bad_options_are_one_line_user_errors(octagon_evaluator) -> None:
    mesh, ev = octagon_evaluator
    with pytest.raises(UserInputError, match="newton-krylov: unknown option\\(s\\) foo"):
        make_solver("newton-krylov", ev, {"foo": 1})
    with pytest.raises(UserInputError, match="option cholesky must be one of"):
        make_solver("newton-krylov", ev, {"cholesky": "mumps"})
    with pytest.raises(UserInputError, match="option tol must be a number > 0"):
        make_solver("newton-krylov", ev, {"tol": -1})
    with pytest.raises(UserInputError, match="option cg_max_iter must be an integer"):
        make_solver("newton-krylov", ev, {"cg_max_iter": 0.5})
    with pytest.raises(UserInputError, match="unknown option"):
        WillmoreFlow(mesh, 0.1, 0.01, solver="newton-krylov", foo=1)


@pytest.mark.parametrize("backend", ["cholmod", "scipy"])
def test_factorisation_solves_spd_systems(backend: str) -> None:
    """Both backends solve a random SPD sparse system (one and three right-hand sides) to rounding."""
    import scipy.sparse as sp

    if backend == "cholmod":
        pytest.importorskip("sksparse_minimal")

    rng = np.random.default_rng(1)
    n = 200
    A = sp.random(n, n, density=0.03, random_state=2)
    A = (A @ A.T + sp.identity(n)).tocsc()
    F = SymmetricFactor(backend).factor(A)
    b = rng.normal(size=(n, 3))
    assert np.abs(A @ F.solve(b) - b).max() <= 1e-12 * np.abs(b).max()
    assert np.abs(A @ F.solve(b[:, 0]) - b[:, 0]).max() <= 1e-12 * np.abs(b).max()


def test_cholmod_reports_an_indefinite_matrix_by_the_error_alone() -> None:
    """A matrix that is not positive definite (a dense 300 x 300, factorised supernodally) raises LinAlgError naming
    the leading minor, and CHOLMOD prints nothing: it had printed "CHOLMOD warning: matrix not positive definite.
    file: /project/ext/..." to stderr beside each such error (a new user's check, an anisotropic clamped patch). In a
    fresh process, whose stderr is read (CHOLMOD's printf writes to the C stream)."""
    pytest.importorskip("sksparse_minimal")
    code = ("import numpy as np, scipy.sparse as sp\n"
            "from willmore_nlp.solvers.cholesky import SymmetricFactor\n"
            "Q = np.random.default_rng(0).normal(size=(300, 300))\n"
            "A = sp.csc_matrix(Q @ Q.T / 300 - 0.5 * np.eye(300))\n"
            "try:\n    SymmetricFactor('cholmod').factor(A)\n"
            "except np.linalg.LinAlgError as e:\n    print(e)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.startswith("matrix not positive definite (CHOLMOD: leading minor "), r
    assert r.stderr == "", r.stderr


def test_cholmod_with_openblas_solves_like_its_reference_blas(tmp_path) -> None:
    """CHOLMOD's BLAS is CasADi's OpenBLAS when CasADi ships it (:data:`cholesky.BLAS`); its supernodal factor
    (the preconditioner's form) and simplicial form (J_Y's) solve a 4,800 x 4,800 system with the structure of
    B (a grid's two-ring operator (x) a 3 x 3 coupling; its factor has dense supernodes: BLAS calls) to
    rounding, and agree to 1e-12 with the factor computed in a fresh process with the wheel's reference BLAS
    (``WILLMORE_NLP_CHOLMOD_BLAS=reference``)."""
    import glob
    import json
    import os
    import subprocess
    import sys

    import casadi
    import scipy.sparse as sp

    from willmore_nlp.solvers import cholesky

    pytest.importorskip("sksparse_minimal")
    if glob.glob(os.path.join(os.path.dirname(casadi.__file__), "libcasadi-tp-openblas.so*")):
        assert cholesky.BLAS == "openblas"
    n = 40
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    L = sp.kronsum(T, T)
    C = np.array([[2.0, 0.5, 0.1], [0.5, 2.0, 0.3], [0.1, 0.3, 2.0]])
    A = sp.kron(L @ L + sp.identity(n * n), C).tocsc()
    b = np.random.default_rng(3).normal(size=A.shape[0])
    x = {}
    for simplicial in (False, True):
        x[simplicial] = SymmetricFactor("cholmod", simplicial=simplicial).factor(A).solve(b)
        assert np.abs(A @ x[simplicial] - b).max() <= 1e-12 * abs(A).max() * np.abs(x[simplicial]).max()
    sp.save_npz(tmp_path / "A.npz", A)
    np.save(tmp_path / "b.npy", b)
    code = ("import json, sys, numpy as np, scipy.sparse as sp; from willmore_nlp.solvers import cholesky; "
            "A = sp.load_npz(sys.argv[1]); b = np.load(sys.argv[2]); "
            "print(json.dumps([cholesky.BLAS, cholesky.SymmetricFactor('cholmod').factor(A).solve(b).tolist()]))")
    env = dict(os.environ, WILLMORE_NLP_CHOLMOD_BLAS="reference")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "A.npz"), str(tmp_path / "b.npy")],
                       capture_output=True, text=True, env=env, check=True)
    blas, x_ref = json.loads(r.stdout.strip().splitlines()[-1])
    assert blas == "reference"
    for simplicial in (False, True):
        assert np.abs(x[simplicial] - np.array(x_ref)).max() <= 1e-12 * np.abs(x_ref).max()


def test_cholmod_analyses_a_pattern_once_and_refactorises_its_values() -> None:
    """CHOLMOD's symbolic analysis is kept per sparsity pattern: refactorising new values of the same pattern,
    or of a pattern contained in it (scipy drops entries that come out exactly zero), does no analysis and
    solves to rounding, as SuperLU does; a pattern with new entries is analysed once, as the union, after which
    the old pattern is contained again; an indefinite matrix is a LinAlgError, not a wrong factor; in both forms
    (supernodal and simplicial)."""
    import gc

    import scipy.sparse as sp

    pytest.importorskip("sksparse_minimal")
    n = 30
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    G = sp.kronsum(T, T)
    base = sp.kron(G @ G, np.eye(3) + 0.2).tocsc()
    eye = sp.identity(base.shape[0], format="csc")
    upper = sp.triu(base, 1).tocoo()
    keep = np.arange(upper.nnz) % 5 > 0  # a contained pattern: a fifth of the off-diagonal pairs dropped
    thin = sp.coo_matrix((upper.data[keep], (upper.row[keep], upper.col[keep])), shape=base.shape)
    thin = (thin + thin.T + sp.diags(base.diagonal()) + 20.0 * eye).tocsc()
    wide = (base @ base + eye).tocsc()  # the four-ring: new entries
    b = np.random.default_rng(5).normal(size=(base.shape[0], 3))

    def check(F: SymmetricFactor, A: sp.csc_matrix) -> None:
        x = F.factor(A).solve(b)
        x_lu = SymmetricFactor("scipy").factor(A).solve(b)
        assert np.abs(x - x_lu).max() <= 1e-10 * np.abs(x_lu).max()
        assert np.abs(A @ F.solve(b[:, 1]) - b[:, 1]).max() <= 1e-11 * np.abs(b).max()
        one = F.solve(b[:, :1])  # an (n, 1) right-hand side keeps its shape and owns its memory
        F.solve(b)
        assert one.shape == (b.shape[0], 1) and one.flags.owndata
        assert np.abs(A @ one - b[:, :1]).max() <= 1e-11 * np.abs(b).max()

    for simplicial in (False, True):
        F = SymmetricFactor("cholmod", simplicial=simplicial)
        for shift in (1.0, 0.01, 3.0):
            check(F, (base + shift * eye).tocsc())
        assert (F.n_symbolic, F.n_numeric) == (1, 3)
        check(F, thin)
        check(F, thin)
        assert (F.n_symbolic, F.n_numeric) == (1, 5)
        check(F, wide)
        check(F, (base + eye).tocsc())
        assert (F.n_symbolic, F.n_numeric) == (2, 7)
        with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
            F.factor((base - 2.0 * eye).tocsc())
        del F
        gc.collect()  # the finaliser frees CHOLMOD's factors and workspace


def test_cholmod_solves_run_on_one_blas_thread_whatever_the_process_count(monkeypatch) -> None:
    """CHOLMOD's supernodal solves run with one OpenBLAS thread (two made newton-krylov's CG 2.7-3.1x slower on
    the 10,242-vertex sphere): every solve enters :func:`cholesky.one_blas_thread`, which sees one thread inside
    under a process count of 2 and leaves the count as it was; the solves under counts 1 and 2 are bitwise
    equal."""
    import scipy.sparse as sp

    from willmore_nlp.solvers import cholesky

    pytest.importorskip("sksparse_minimal")
    lib = cholesky._OPENBLAS
    if lib is None:
        pytest.skip("CHOLMOD does not run on CasADi's OpenBLAS here")
    n = 30
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    A = sp.kron(sp.kronsum(T, T) @ sp.kronsum(T, T) + sp.identity(n * n), np.eye(3) + 0.2).tocsc()
    b = np.random.default_rng(4).normal(size=(A.shape[0], 3))
    F = SymmetricFactor("cholmod", simplicial=False).factor(A)
    before = lib.openblas_get_num_threads()
    seen = []
    try:
        x = {}
        for count in (1, 2):
            lib.openblas_set_num_threads(count)
            with cholesky.one_blas_thread():
                seen.append(lib.openblas_get_num_threads())
            x[count] = F.solve(b)
            assert lib.openblas_get_num_threads() == count
    finally:
        lib.openblas_set_num_threads(before)
    assert seen == [1, 1]
    np.testing.assert_array_equal(x[1], x[2])
    entered = []
    real = cholesky.one_blas_thread
    monkeypatch.setattr(cholesky, "one_blas_thread", lambda: entered.append(1) or real())
    F.solve(b)
    assert entered == [1]
    assert np.abs(A @ x[2] - b).max() <= 1e-11 * np.abs(b).max()


def test_numpy_and_scipy_blas_run_on_one_thread_during_a_solve_and_cholmods_keeps_its_count(monkeypatch) -> None:
    """newton-krylov's solve runs with numpy's and scipy's BLAS on one thread (their idle threads spinning after a
    vector product slowed CHOLMOD's two-thread refactorisations of M + tt L 5-7x on this 2-core machine): seen
    from inside a solve every library threadpoolctl controls has one thread, CHOLMOD's OpenBLAS (CasADi's) keeps
    the process count, and the counts are as before after the solve."""
    threadpoolctl = pytest.importorskip("threadpoolctl")
    from willmore_nlp.solvers import cholesky

    lib = cholesky._OPENBLAS
    if lib is None or cholesky._Cholmod is None:
        pytest.skip("CHOLMOD does not run on CasADi's OpenBLAS here")
    before = {d["filepath"]: d["num_threads"] for d in threadpoolctl.threadpool_info() if d["user_api"] == "blas"}
    assert before, "threadpoolctl finds numpy's BLAS"
    assert not any("casadi" in path for path in before)
    saved = lib.openblas_get_num_threads()
    lib.openblas_set_num_threads(2)
    seen = []
    real = StepEvaluator.f_grad

    def f_grad(self, z, p):
        seen.append(({d["num_threads"] for d in threadpoolctl.threadpool_info() if d["user_api"] == "blas"},
                     lib.openblas_get_num_threads()))
        return real(self, z, p)

    monkeypatch.setattr(StepEvaluator, "f_grad", f_grad)
    try:
        mesh = shapes.icosphere(1)
        flow = WillmoreFlow(mesh.with_vertices(mesh.vertices * [1.0, 1.0, 1.3]), 0.05, 0.01,
                            solver="newton-krylov", mesh_control="off")
        assert flow.step().converged
        after = lib.openblas_get_num_threads()
    finally:
        lib.openblas_set_num_threads(saved)
    assert seen and all(s == ({1}, 2) for s in seen)
    assert after == 2
    assert before == {d["filepath"]: d["num_threads"] for d in threadpoolctl.threadpool_info()
                      if d["user_api"] == "blas"}


def test_stale_preconditioner_is_rebuilt_and_steps_agree() -> None:
    """A CG solve with a preconditioner built at another point that reaches ``cg_stale`` iterations restarts
    with B rebuilt at the current point: with cg_stale=2 the rule fires (more builds than with the default),
    and two steps land on the same X as with the default rule and as the SuperLU fallback, to 1e-8 of the
    step (all at tol 1e-10: the iterates differ, the solution does not)."""
    mesh = _ellipsoid()
    args = (mesh, 0.2 * mesh.h, mesh.h**2 / 100)
    off = {"mesh_control": "off", "max_retries": 0, "solver": "newton-krylov", "tol": 1e-10}
    runs = {}
    for name, extra in (("default", {}), ("stale", {"cg_stale": 2}), ("scipy", {"cholesky": "scipy"})):
        flow = WillmoreFlow(*args, **off, **extra)
        steps = [flow.step(), flow.step()]
        assert all(r.converged for r in steps)
        runs[name] = steps
    builds = {k: sum(r.stats.get("n_precond_builds", 0) for r in v) for k, v in runs.items()}
    assert builds["stale"] > builds["default"]
    step = np.abs(runs["default"][1].vertices - runs["default"][0].vertices).max()
    assert step > 1e-3 * mesh.h
    for name in ("stale", "scipy"):
        for a, b in zip(runs[name], runs["default"], strict=True):
            assert np.abs(a.vertices - b.vertices).max() <= 1e-8 * step


def test_preconditioner_is_rebuilt_after_the_first_newton_step_of_a_time_step() -> None:
    """``precond_move`` (0.1 h) rebuilds B at the second Newton system of a time step, whose first Newton step
    moved X by 0.16-0.42 h: with the earlier 0.5 h the previous step's B served that system and then failed the
    next, tighter one after ``cg_stale`` iterations. On the 642-vertex ellipsoid 1:1:1.3 at tau = 0.2 h (tol
    1e-10), steps 2-4: measured 53 / 62 / 79 CG iterations with 0.5 h, 22 / 19 / 17 with 0.1 h, one build of B per
    step either way; the steps land on the same X (the iterates differ, the solution does not). The factorisations
    after the first step need (almost) no symbolic analysis."""
    mesh = _ellipsoid(3)
    args = (mesh, 0.2 * mesh.h, mesh.h**2 / 100)
    off = {"mesh_control": "off", "max_retries": 0, "solver": "newton-krylov", "tol": 1e-10}
    runs = {}
    for name, extra in (("default", {}), ("0.5 h", {"precond_move": 0.5})):
        flow = WillmoreFlow(*args, **off, **extra)
        runs[name] = [flow.step() for _ in range(4)]
        assert all(r.converged for r in runs[name])
    cg = {k: [r.stats["n_cg"] for r in v[1:]] for k, v in runs.items()}
    builds = {k: [r.stats["n_precond_builds"] for r in v[1:]] for k, v in runs.items()}
    assert builds["default"] == builds["0.5 h"] == [1, 1, 1]
    # CHOLMOD analyses J_Y's and B's patterns once (measured: 3, 0, 0, 0 analyses, the third B's union with an
    # entry that came out exactly zero in the first B) against 33 factorisations in the four steps
    if runs["default"][0].stats["cholesky"] == "cholmod":
        analyses = [r.stats["n_symbolic"] for r in runs["default"]]
        factorisations = sum(r.stats["n_factorizations"] + r.stats["n_precond_builds"] for r in runs["default"])
        assert sum(analyses) <= 4 and analyses[-1] == 0 and factorisations >= 5 * sum(analyses)
    assert all(2 * a < b for a, b in zip(cg["default"], cg["0.5 h"], strict=True))
    step = np.abs(runs["default"][-1].vertices - runs["default"][-2].vertices).max()
    for a, b in zip(runs["default"], runs["0.5 h"], strict=True):
        assert np.abs(a.vertices - b.vertices).max() <= 1e-7 * step


def test_missing_cholmod_falls_back_to_scipy(monkeypatch) -> None:
    """Without sksparse-minimal "auto" resolves to SuperLU and asking for cholmod is a one-line error."""
    from willmore_nlp.solvers import cholesky

    monkeypatch.setattr(cholesky, "_Cholmod", None)
    assert cholesky.resolve_backend("auto") == "scipy"
    with pytest.raises(UserInputError, match="needs the package sksparse-minimal"):
        cholesky.resolve_backend("cholmod")
    mesh = shapes.regular_polygon(8)
    setup = build_step(mesh)
    solver = make_solver("newton-krylov", StepEvaluator(setup.problem, setup.problem.functions()), {})
    assert solver.backend == "scipy"


def test_cli_runs_newton_krylov(tmp_path) -> None:
    """``--set solver=newton-krylov`` reaches the flow: a 32-gon circle grows as R(t) = (R0^4 + 2t)^(1/4)."""
    import csv

    from willmore_nlp import cli, load_run

    out = tmp_path / "run"
    assert cli.main(["run", "circle", "--out", str(out), "--steps", "3", "--set", "n=32", "--set", "tau=0.01",
                     "--set", "solver=newton-krylov", "--quiet"]) == 0
    run = load_run(out)
    assert run.config["flow_options"]["solver"] == "newton-krylov"
    with open(out / "history.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [row["status"] for row in rows] == ["initial", "converged", "converged", "converged"]  # IPOPT: Solve_...
    for row in rows[1:]:  # its own counts and time split (CG iterations, Cholesky factorisations) per step
        assert int(row["n_cg"]) >= int(row["iterations"]) >= 1 and int(row["n_factorizations"]) >= 1
        assert row["n_guarded"] == row["n_guard"] == "0"  # (a circle's steps need no guarded pass)
        assert float(row["t_wall_factor"]) > 0 and float(row["t_wall_cg"]) > 0 and row["solver"] == "newton-krylov"
    R = [np.linalg.norm(s.vertices, axis=1).mean() for s in run.states]
    assert len(R) == 4 and np.all(np.diff(R) > 0)
    np.testing.assert_allclose(R[-1], (2.0**4 + 2 * 0.03) ** 0.25, rtol=1e-3)


def test_shift_cap_ends_an_indefinite_solve_and_the_flow_retries() -> None:
    """The first step of the ellipsoid needs a shift delta = 1 (its reduced Hessian is indefinite at X^k): with
    max_shift = 0.5 the solve stops at once, unconverged, with the reason, and the flow retries with tau/2 (where
    it then also stops: the cap is the only thing that fails; ``guarded=False``: no guarded second pass); with the
    default cap (1e3) the step converges with its largest shift in (0, max_shift]."""
    mesh = _ellipsoid()
    args = (mesh, 0.2 * mesh.h, mesh.h**2 / 100)
    capped = WillmoreFlow(*args, solver="newton-krylov", mesh_control="off", max_retries=1, max_shift=0.5,
                          guarded=False)
    with pytest.raises(FlowError) as info:
        capped.step()
    assert len(info.value.rejected) == 2
    assert all("reduced Hessian too indefinite" in r for r in info.value.rejected)
    r = WillmoreFlow(*args, solver="newton-krylov", mesh_control="off", max_retries=0).step()
    assert r.converged and 0.5 < r.stats["delta_max"] <= 1e3


@pytest.mark.parametrize("min_steps", [0, 1])
def test_reduced_energy_is_exact_at_tiny_steps(min_steps: int, monkeypatch) -> None:
    """W^ at points 2e-11 apart (2,562-vertex ellipsoid after one step): its central difference along a random
    direction equals the adjoint gradient's prediction to 20 % (measured 8 %: the rounding of W^ over such a
    step) when the inner solve takes its one (exact) Newton step from the warm Y0 (``min_steps=1``, what
    newton-krylov does). Without it (``min_steps=0``, the old behaviour) Y0 passes an inner tolerance it meets
    unchanged and the difference is off by a factor 4.5e4 (on a 10,242-vertex sphere already at 2e-10
    apart: 7.6e-8 where 2.5e-13 was predicted). The inner tolerance is 1e-10 here: with the default 1e-12, relative
    to |J_Y| |Y| since 2026-11-30 (before: to max(1, |J_Y| |Y|), which Y0 met), Y0 no longer passes at this size and
    both take the step (measured 0.117 each)."""
    mesh = shapes.icosphere(4)
    mesh = mesh.with_vertices(mesh.vertices * np.array([1.0, 1.0, 1.3]))
    flow = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, solver="newton-krylov", mesh_control="off")
    flow.step()
    solver, ev = flow.solver, flow.solver.ev
    inner = ev.inner_solve
    monkeypatch.setattr(ev, "inner_solve", lambda *a, **k: inner(*a, **{**k, "min_steps": min_steps, "tol": 1e-10}))
    p = flow.params(flow.X, flow.tau)
    x = flow.X.ravel().copy()
    d = np.random.default_rng(1).standard_normal(x.size)
    pt = solver._feasible(x, p, flow.Y)
    eps = 1e-11
    diff = (solver._feasible(x + eps * d, p, flow.Y).f - solver._feasible(x - eps * d, p, flow.Y).f) / (2 * eps)
    err = abs(diff - pt.grad @ d) / abs(pt.grad @ d)
    if min_steps:
        assert err <= 0.2
    else:
        assert err > 100


def test_the_default_first_shift_is_larger_above_ten_thousand_free_vertices() -> None:
    """``first_shift`` unset: 300 D up to FIRST_SHIFT_VERTICES = 10,242 free vertices (the 10,242-vertex benchmark
    sphere itself), 1000 above (a 10,368-vertex torus); a given one is kept at any size. (Measured in step 1: 13 -> 10
    Newton iterations at 40,962 v, 34 -> 17 on a remeshed 19,476-v ellipsoid; docs/guide/performance.md.)"""
    shifts = {}
    for name, mesh in (("sphere", shapes.icosphere(5)), ("torus", shapes.torus(1.0, 0.5, 128, 81))):
        P = build_step(mesh).problem
        ev = StepEvaluator(P, P.functions())
        shifts[name, len(mesh.vertices)] = make_solver("newton-krylov", ev, {}).first_shift
        shifts[name, "given"] = make_solver("newton-krylov", ev, {"first_shift": 30.0}).first_shift
    assert shifts == {("sphere", 10_242): newton_krylov.FIRST_SHIFT, ("sphere", "given"): 30.0,
                      ("torus", 10_368): newton_krylov.FIRST_SHIFT_LARGE, ("torus", "given"): 30.0}


def test_first_step_of_an_indefinite_solve_is_the_dense_shifted_kkt_step() -> None:
    """On the ellipsoid the reduced Hessian at X^0 with the adjoint multiplier is indefinite (measured: 29
    negative eigenvalues relative to D, the smallest -0.71). The solver's first step (CG to 1e-12) equals
    the dense solve of the KKT system with H + first_shift D in the X block (measured 1.3e-12 of the step in
    z, 4e-14 in the multiplier), and that step's multiplier - the one the full-space iteration uses next -
    makes the Hessian of the Lagrangian positive definite on the constraint's tangent space at X^0 and at
    X^1 (measured: no negative eigenvalue, the smallest +0.64 and +0.63)."""
    mesh = _ellipsoid()
    h = mesh.h
    setup = build_step(mesh)
    P = setup.problem
    ev = StepEvaluator(P, P.functions())
    p = setup.params(mesh.vertices, 0.2 * h, h * h / 100, 0.0)
    z0 = P.pack_z(mesh.vertices, ev.solve_y(mesh.vertices, p))
    n, ng = P.nX * P.m, P.ng
    res = make_solver("newton-krylov", ev, {"max_iter": 1, "first_cg_tol": 1e-12}).solve(z0, p)
    assert res.stats["iteration"] == "full-space" and res.stats["n_full_space"] == 1
    shift = res.stats["delta_max"]
    assert shift == 300.0  # the default first_shift: CG met negative curvature in the unshifted system

    _, gf = ev.f_grad(z0, p)
    J = ev.jac_g(z0, p).toarray()
    lam0 = np.linalg.solve(J[:, n:].T, -gf[n:])  # the adjoint multiplier at X^0
    D = ev.hess_lag(z0, P.params.replace(p, tau=0.0), 1.0, np.zeros(ng)).toarray()[:n, :n]
    L = np.linalg.cholesky(D)

    def tangent_eigenvalues(z: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Eigenvalues of Z^T H(z, lam) Z relative to D, Z = [I; -J_Y^-1 J_X] (dense)."""
        Jz = ev.jac_g(z, p).toarray()
        Z = np.vstack([np.eye(n), -np.linalg.solve(Jz[:, n:], Jz[:, :n])])
        A = Z.T @ ev.hess_lag(z, p, 1.0, lam).toarray() @ Z
        return np.linalg.eigvalsh(np.linalg.solve(L, np.linalg.solve(L, 0.5 * (A + A.T)).T))

    assert tangent_eigenvalues(z0, lam0).min() < -0.1
    K = np.block([[ev.hess_lag(z0, p, 1.0, lam0).toarray(), J.T], [J, np.zeros((ng, ng))]])
    K[:n, :n] += shift * D
    sol = np.linalg.solve(K, -np.concatenate([gf, ev.g(z0, p)]))
    dz, lam1 = sol[: n + ng], sol[n + ng :]
    assert np.abs(np.asarray(res.z) - (z0 + dz)).max() <= 1e-9 * np.abs(dz).max()
    assert np.abs(np.asarray(res.lam_g)[:ng] - lam1).max() <= 1e-9 * np.abs(lam1).max()
    assert np.abs(lam1 - lam0).max() > 1e-2 * np.abs(lam0).max()  # not the adjoint multiplier
    assert tangent_eigenvalues(z0, lam1).min() > 0.1
    assert tangent_eigenvalues(z0 + dz, lam1).min() > 0.1


@pytest.mark.parametrize("name", ["cap-ring", "cap-conormal", "blend-conormal"])
def test_both_exits_of_the_full_space_iteration_match_ipopt(name: str, monkeypatch) -> None:
    """When a full-space system meets negative curvature again, the solve leaves the full-space iteration: right
    after its first step by the reduced iteration restarted from X^0 (``n_replay``), after ``HANDBACK_AFTER`` or
    more steps by the reduced iteration at the current iterate with Y = Y[X] (``n_handback``; the 40,962-v
    sphere's first step). On the flattened caps and the co-normal blend the recurrence comes right after the
    first full-space step: by default they replay; with ``HANDBACK_AFTER = 1`` they take the hand-back exit.
    Either exit ends at IPOPT's X (tol 1e-12) to 1e-8 of the step's displacement."""
    mesh, tau, tt, lam, opts = _case(name)
    off = {"mesh_control": "off", "max_retries": 0, **opts}
    ref = WillmoreFlow(mesh, tau, tt, lam=lam, tol=1e-12, max_iter=1000, **off).step()
    step = np.abs(ref.vertices - mesh.vertices).max()
    for handback_after, exit_count in ((2, "n_replay"), (1, "n_handback")):
        monkeypatch.setattr(newton_krylov, "HANDBACK_AFTER", handback_after)
        r = WillmoreFlow(mesh, tau, tt, lam=lam, solver="newton-krylov", tol=1e-10, **off).step()
        other = "n_handback" if exit_count == "n_replay" else "n_replay"
        assert r.stats[exit_count] == 1 and r.stats.get(other, 0) == 0
        assert r.converged and r.stats["kkt_residual"] <= r.stats["gtol"]
        assert np.abs(r.vertices - ref.vertices).max() <= 1e-8 * step


def _noisy_torus_problem(tmp_path):
    """The ``file`` problem of a noisy stretched trimesh torus (40 x 16 sections, z x 1.2, noise 0.01; 640 v)."""
    t = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=40, minor_sections=16)
    V = t.vertices * [1.0, 1.0, 1.2]
    trimesh.Trimesh(V + 0.01 * np.random.default_rng(1).standard_normal(V.shape), t.faces,
                    process=False).export(tmp_path / "torus.obj")
    return registry.build("file", path=str(tmp_path / "torus.obj"))[0]


def test_a_noisy_first_step_that_both_passes_fail_is_taken_by_the_guarded_pass(tmp_path) -> None:
    """A noisy stretched trimesh torus (40 x 16 sections, z x 1.2, noise 0.01; 640 v, the ``file`` problem's options)
    at tau = h/32: the reduced/full-space passes fail (the reduced Hessian is far from convex at X^0: shifts above
    ``max_shift``), the guarded pass (no hand-back, trial points that flip or crush a triangle shortened, steps of
    at most 0.3 h, shifted systems' CG cut at 50) converges, to IPOPT's solution of the same step (measured 0.73 h
    from X^0, smallest angle 9.07 deg both), and no angle of it is below GUARD_ANGLE x the initial smallest one.
    At h/64 the first pass converges and the guarded one never runs."""
    from willmore_nlp import geometry

    pb = _noisy_torus_problem(tmp_path)
    steps = {}
    for solver in ("newton-krylov", "ipopt"):
        flow = pb.make_flow(solver=solver)
        for k in (32, 64):
            res = flow.solver.solve(flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, flow.tau / k), None)
            assert res.converged, (solver, k, res.status)
            steps[solver, k] = (flow.problem.unpack_z(res.z, flow.X)[0], res.stats)
    X0, h, S = flow.X, flow.mesh.h, flow.mesh.simplices
    assert steps["newton-krylov", 32][1]["n_guarded"] == 1 and steps["newton-krylov", 64][1]["n_guarded"] == 0
    X = steps["newton-krylov", 32][0]
    assert np.linalg.norm(X - X0, axis=1).max() > 0.5 * h
    assert geometry.min_angles(X, S).min() >= newton_krylov.GUARD_ANGLE * geometry.min_angles(X0, S).min()
    for k in (32, 64):
        assert np.abs(steps["newton-krylov", k][0] - steps["ipopt", k][0]).max() <= 1e-6 * h


@pytest.mark.parametrize("tau", [0.0125, pytest.param(0.05, marks=pytest.mark.slow)])
def test_an_anisotropic_step_that_the_first_pass_fails_is_taken_by_the_guarded_pass(tau: float) -> None:
    """A new user's check: the 642-vertex ellipsoid 1:1:1.4 with gamma1 (a nonlinear inner equation), tau_tilde =
    h^2/100, the flow's options (tangential control "meanratio"). The reduced first pass fails: at tau = 0.0125 "too
    indefinite", at 0.05 its Armijo steps crush a triangle (area 0.31 -> 0.0036 h^2, its Y triangle 1.7e-11 h^2: J_Y
    up to 1.3e7, B's eigenvalues up to 6e22 against D's 0.011) and B's factorisation fails. Both had ended the solve
    (no guarded pass for a nonlinear inner equation). The guarded pass takes both steps, to IPOPT's X (tol 1e-12;
    1e-11 at 0.05, where 1e-12 ends at the acceptable level) to 1e-8 h: measured 3.1e-11 h and 4.4e-10 h, the
    vertices moving up to 0.86 h and 2.6 h (0.05: about 25 s, the slow mark)."""
    m = shapes.icosphere(3)
    mesh = m.with_vertices(m.vertices * np.array([1.0, 1.0, 1.4]))
    h = mesh.h
    X = {}
    for solver, tol in (("newton-krylov", 1e-10), ("ipopt", 1e-12 if tau < 0.05 else 1e-11)):
        flow = WillmoreFlow(mesh, tau, h * h / 100, anisotropy="gamma1", solver=solver, tol=tol)
        res = flow.solver.solve(flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, tau), None)
        assert res.converged, (solver, res.status)
        X[solver] = flow.problem.unpack_z(res.z, flow.X)[0]
        if solver == "newton-krylov":
            assert res.stats["n_guarded"] == 1 and res.stats["n_full_space"] > 0
    assert np.abs(X["newton-krylov"] - X["ipopt"]).max() <= 1e-8 * h < np.linalg.norm(X["ipopt"] - mesh.vertices,
                                                                                       axis=1).max()


def test_a_grown_step_runs_without_the_guarded_pass(tmp_path, monkeypatch) -> None:
    """Adaptive steps on the noisy torus above (the ``file`` problem's flow: newton-krylov, adaptive): the first step's
    attempts may run the guarded pass (its step at h/32 is the guarded pass's), an attempt above the last accepted
    step size (the adaptive control's doubling) may not (a grown step that needs the guard is retried at the size
    that worked: in two genus-2 flows of 351 and 380 steps no step after the first was taken by a guarded pass,
    docs/guide/performance.md), and a retry at or below that size may again."""
    pb = _noisy_torus_problem(tmp_path)
    flow = pb.make_flow()
    assert flow.solver.name == "newton-krylov" and flow.settings.adaptive
    seen = []
    attempt = WillmoreFlow._attempt

    def recorded(self, tau, last):
        k, before = self.k, self._last_tau
        out = attempt(self, tau, last)
        seen.append((k, before, tau, self.solver.guard_allowed, (out[2].stats if out[2] is not None else {})))
        return out

    monkeypatch.setattr(WillmoreFlow, "_attempt", recorded)
    while flow.k < 8 and all(allowed for *_, allowed, _ in seen):  # (the first step's retries hold tau for two)
        flow.step()
    for k, before, tau, allowed, _ in seen:
        assert allowed == (not (k > 0 and 0 < before < tau)), (k, before, tau)
    assert any(k == 0 and stats.get("n_guarded") == 1 for k, _, _, _, stats in seen)
    grown = [stats for _, _, _, allowed, stats in seen if not allowed]
    assert grown and all(stats.get("n_guarded", 0) == 0 for stats in grown)


def test_a_guarded_pass_that_the_guard_keeps_refusing_ends_early(tmp_path, monkeypatch) -> None:
    """The noisy torus of the test above at tau = h, where the guarded pass fails: it ends once the mesh guard has
    refused GUARD_REFUSALS trial points, with that status, in fewer Newton iterations than the same pass without the
    limit, which fails as well (measured: converged passes need 0-4 refusals, failed ones ran to 366-477)."""
    pb = _noisy_torus_problem(tmp_path)
    default = newton_krylov.GUARD_REFUSALS
    runs = {}
    for limit in (default, 10**9):
        monkeypatch.setattr(newton_krylov, "GUARD_REFUSALS", limit)
        flow = pb.make_flow(solver="newton-krylov")
        runs[limit] = flow.solver.solve(flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, flow.tau), None)
    cut, full = runs[default], runs[10**9]
    assert not cut.converged and not full.converged
    assert cut.status.startswith(f"guarded pass: the mesh guard refused {default} trial points")
    assert cut.stats["n_guarded"] == 1 and cut.stats["n_guard"] == default < full.stats["n_guard"]
    assert cut.iterations < full.iterations


@pytest.mark.slow
def test_the_guarded_pass_runs_in_the_full_space_also_from_a_positive_definite_start(tmp_path) -> None:
    """A clean trimesh torus (128 x 64 sections, r/R 0.4; 8,192 v, the ``file`` problem) at tau/2: the first Newton
    system at X^k is positive definite, so the first pass stays in the reduced iteration and fails later (negative
    curvature, never in the full space). Its guarded pass had replayed that reduced iteration with larger shifts: 50
    iterations in 75 s, failed (the flow took the step at tau/4). It now runs the full-space iteration from its first
    step, converges to IPOPT's solution of the same step (measured 7e-9 h apart; the vertices move up to 6 h) and keeps
    every angle above GUARD_ANGLE x the initial smallest one (about 60 s: the slow mark)."""
    from willmore_nlp import geometry

    trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=128,
                           minor_sections=64).export(tmp_path / "torus.obj")
    pb = registry.build("file", path=str(tmp_path / "torus.obj"))[0]
    runs = {}
    for solver, options in (("newton-krylov", {"guarded": False}), ("newton-krylov", {}), ("ipopt", {})):
        flow = pb.make_flow(solver=solver, **options)
        res = flow.solver.solve(flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, flow.tau / 2), None)
        runs[solver, bool(options)] = (flow.problem.unpack_z(res.z, flow.X)[0], res)
    first, guarded, ipopt = runs["newton-krylov", True][1], runs["newton-krylov", False][1], runs["ipopt", False][1]
    assert not first.converged and first.stats.get("n_full_space", 0) == 0 and first.stats["delta_max"] > 0
    assert guarded.converged and ipopt.converged, (guarded.status, ipopt.status)
    assert guarded.stats["n_guarded"] == 1 and guarded.stats["n_full_space"] > 0
    X0, h, S = flow.X, flow.mesh.h, flow.mesh.simplices
    X, Xi = runs["newton-krylov", False][0], runs["ipopt", False][0]
    assert np.abs(X - Xi).max() <= 1e-6 * h < np.linalg.norm(X - X0, axis=1).max()
    assert geometry.min_angles(X, S).min() >= newton_krylov.GUARD_ANGLE * geometry.min_angles(X0, S).min()


def test_a_factor_that_is_not_positive_definite_ends_the_solve_and_the_flow_retries(monkeypatch) -> None:
    """CHOLMOD's "not positive definite" (a preconditioner at an iterate whose triangles degenerate; the h = 0.07
    double torus of reports/genus2_handles_study.py crashed the run with a traceback) ends the solve unconverged with
    the reason; the flow retries at tau/2, where the factor works again, and takes the step."""
    mesh = _ellipsoid()
    flow = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, solver="newton-krylov", mesh_control="off")
    pre = flow.solver._pre
    factor, calls = pre.factor, []

    def fails_once(A):
        calls.append(1)
        if len(calls) == 1:
            raise np.linalg.LinAlgError("matrix not positive definite (CHOLMOD: leading minor 7 of 486)")
        return factor(A)

    monkeypatch.setattr(pre, "factor", fails_once)
    r = flow.step()
    assert r.converged and r.retries == 1 and r.tau == pytest.approx(0.1 * mesh.h)
    assert r.rejected == [f"tau={0.2 * mesh.h:.6g}: solver did not converge (factorisation failed (matrix not "
                          "positive definite (CHOLMOD: leading minor 7 of 486)), 0 iterations)"]


def test_a_flow_at_exact_rest_takes_its_steps_where_they_start() -> None:
    """A flat clamped disc is at rest: the gradient at a step's start is 0. newton-krylov's stopping test is relative
    to that gradient, floored at the distance term's gradient for a motion of ``REST_MOTION`` h: each step is taken
    at its first attempt without a Newton iteration (found by a new-user check: the floor was 1e-300, round-off
    4e-20 never met the tolerance 1e-309, and every step at rest failed 7 attempts, "line search failed", before
    the IPOPT fallback took it)."""
    from willmore_nlp.boundary import Boundary

    disk = shapes.disk(6)
    flow = WillmoreFlow(disk, 0.2 * disk.h, disk.h**2 / 100, boundary=Boundary.outer_strip(disk, "conormal"),
                        solver="newton-krylov", fallback_solver="", tangential_control="off")
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        steps = flow.run(steps=3)
    for r in steps:
        assert r.retries == 0 and r.iterations == 0 and r.stats["solver"] == "newton-krylov"
        assert np.array_equal(r.vertices, disk.vertices)
    assert not any("at its start" in str(w.message) for w in got)  # (at rest, not by a loose tol)
