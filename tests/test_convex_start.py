"""``convex_start``: the first step of a noisy input below the step problem's convexity limit tau_c.

The cylinder's and the box's first steps were measured at tau = h (``length = 1``; the ``file`` problem's default
tau = h L^3 is 0.35 h and 0.27 h on them)."""

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sl
import trimesh

from willmore_nlp import geometry, registry
from willmore_nlp.solvers.reduced import ReducedSettings, ReducedSolver, convexity_limit


def _noisy_sphere(tmp_path: Path) -> str:
    """OBJ of a trimesh icosphere(2) (162 v) with normal noise 0.03 (about 0.16 h; seed 1)."""
    s = trimesh.creation.icosphere(2)
    s.vertices += 0.03 * np.random.default_rng(1).standard_normal(s.vertices.shape)
    s.export(tmp_path / "sphere.obj")
    return str(tmp_path / "sphere.obj")


def _cylinder(tmp_path: Path) -> str:
    """OBJ of a trimesh cylinder (24 sections) subdivided twice: 741 v after the input repair, its rims sharp."""
    c = trimesh.creation.cylinder(radius=0.5, height=1.5, sections=24).subdivide().subdivide()
    c.export(tmp_path / "cylinder.obj")
    return str(tmp_path / "cylinder.obj")


def _fd_reduced_hessian(red: ReducedSolver, x0: np.ndarray, p: np.ndarray, Y0: np.ndarray,
                        eps: float = 1e-6) -> np.ndarray:
    """The reduced Hessian of W^ at x0 by central differences of its adjoint gradient (not the second-order adjoint
    that :func:`convexity_limit` uses), symmetrised."""
    n = x0.size
    H = np.empty((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        H[:, i] = (red._at(x0 + e, p, Y0).grad - red._at(x0 - e, p, Y0).grad) / (2 * eps)
    return (H + H.T) / 2


def test_convexity_limit_is_where_a_finite_difference_reduced_hessian_stops_being_positive_definite(tmp_path) -> None:
    """On a noisy icosphere (162 v) the reduced Hessian of the first step's W^, by finite differences of the adjoint
    gradient at two step sizes, is D + tau R with R independent of tau (to 1e-6 relative), and the generalised
    eigenvalues of (FD Hessian, D) give tau_c: positive definite at 0.95 tau_c, not at 1.05 tau_c. The Lanczos
    estimate agrees to 1 % (measured: tau_c = tau / 282, 0.1 s)."""
    pb, _ = registry.build("file", path=_noisy_sphere(tmp_path))
    flow = pb.make_flow()
    z0, P = flow.problem.pack_z(flow.X, flow.Y), flow.problem
    red = ReducedSolver(flow.evaluator, ReducedSettings(), "newton")
    x0, Y0 = z0[: red.nxm], P.unpack_z(z0, flow.X)[1]
    tau = flow.tau
    p1, p2 = flow.params(flow.X, tau), flow.params(flow.X, tau / 8)
    H1, H2 = _fd_reduced_hessian(red, x0, p1, Y0), _fd_reduced_hessian(red, x0, p2, Y0)
    D = red._distance_hessian(red._at(x0, p1, Y0).z, p1).toarray()
    R = (H1 - D) / tau
    assert np.abs(H2 - (D + tau / 8 * R)).max() <= 1e-6 * np.abs(H2).max()  # linear in tau
    smallest = sl.eigh(H1, D, eigvals_only=True, subset_by_index=[0, 0])[0]
    assert smallest < 1 - 16  # strongly indefinite at tau = h
    tau_fd = tau / (1 - smallest)
    for factor, definite in ((0.95, True), (1.05, False)):
        assert bool(sl.eigh(D + factor * tau_fd * R, D, eigvals_only=True, subset_by_index=[0, 0])[0] > 0) is definite
    tau_c = convexity_limit(flow.evaluator, z0, p1)
    assert tau_c == pytest.approx(tau_fd, rel=1e-2)


def test_a_smooth_surface_has_no_strongly_negative_mode_and_is_flowed_as_before(tmp_path) -> None:
    """A smooth ellipsoid (trimesh icosphere(3) stretched 1.5, 642 v): no tau_c below tau / 16 (none or a weak mode;
    the first look's two Lanczos cycles find none); a flow whose first attempt succeeds never looks (the noisy
    sphere above is taken at tau although its tau_c is tau / 282): the states with and without ``convex_start`` are
    equal bit for bit."""
    from willmore_nlp.flow import CONVEX_JUMP
    from willmore_nlp.solvers.reduced import CONVEXITY_FIRST_RESTARTS

    s = trimesh.creation.icosphere(3)
    s.vertices[:, 2] *= 1.5
    s.export(tmp_path / "ellipsoid.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "ellipsoid.obj"))
    flow = pb.make_flow()
    z0, p = flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, flow.tau)
    assert not convexity_limit(flow.evaluator, z0, p) < flow.tau / CONVEX_JUMP  # (nan: not converged)
    assert np.isnan(convexity_limit(flow.evaluator, z0, p, CONVEXITY_FIRST_RESTARTS))
    pb, _ = registry.build("file", path=_noisy_sphere(tmp_path))
    runs = [pb.make_flow(convex_start=flag) for flag in (True, False)]
    for flow in runs:
        for _ in range(2):
            assert flow.step().retries == 0
    assert runs[0]._tau_c is None  # never computed
    assert np.array_equal(runs[0].X, runs[1].X)


def test_a_first_step_that_fails_at_tau_is_retried_below_tau_c(tmp_path) -> None:
    """The subdivided trimesh cylinder (741 v, newton-krylov): its step problem is convex at X^0 only below
    tau / 5e4; the attempts at tau and tau / 2 fail and the next is at the largest tau / 2^j not above tau_c / 2
    (here below the floor min_tau = 0.01 h^4: not above tau_c), where it converges (2 retries; measured:
    tau / 65,536); the adaptive steps then hold it for two steps and double, each taken at its first attempt, W
    falling at every step. With
    ``convex_start = false`` the halvings take it at tau / 8 after 3 retries (measured), as before."""
    pb, _ = registry.build("file", path=_cylinder(tmp_path), length=1.0)
    flow = pb.make_flow()
    tau = flow.tau
    tau_c = convexity_limit(flow.evaluator, flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, tau))
    assert tau_c < tau / 1e4
    w = flow.discrete_energy(flow.X)
    with pytest.warns(UserWarning, match=r"convex at the initial state only below tau = .*the next attempt is at tau"):
        first = flow.step()
    j = round(np.log2(tau / first.tau))
    floor = min(flow.min_tau, tau)
    # the largest tau / 2^j not above tau_c / 2, or (that one below the floor min_tau) not above tau_c
    expected = tau / 2 ** np.ceil(np.log2(2 * tau / tau_c))
    expected = expected if expected >= floor else tau / 2 ** np.ceil(np.log2(tau / tau_c))
    assert first.retries == 2 and first.tau == tau / 2**j == expected and first.tau <= tau_c
    assert [r.split(":")[0] for r in first.rejected] == [f"tau={tau:.6g}", f"tau={tau / 2:.6g}"]
    taus = [first.tau]
    assert first.energy < w
    for _ in range(5):
        r = flow.step()
        assert r.retries == 0 and r.energy < w
        w = r.energy
        taus.append(r.tau)
    assert taus == [first.tau] * 3 + [2 * first.tau, 4 * first.tau, 8 * first.tau]
    old = pb.make_flow(convex_start=False).step()
    assert old.retries > 1 and old.tau == tau / 2**old.retries > first.tau


def test_the_first_look_before_the_first_attempt_jumps_only_far_below(tmp_path, monkeypatch) -> None:
    """The first look (two Lanczos cycles, before newton-krylov's first attempt) gives the cylinder's tau_c exactly
    (the same deterministic iteration; with newton-krylov's factorisations to rounding); tau / 5e4 is not below tau /
    ``CONVEX_FAR`` (1e5), so the cylinder keeps its attempts at tau and tau / 2 (the test above). With ``CONVEX_FAR``
    lowered to 1e4 its first step starts at the step size that two failures give: no retry, the same accepted
    state; with IPOPT the look follows its first failed attempt (one retry). D is factorised with newton-krylov's
    ``cholesky`` backend (scipy here: the same tau_c)."""
    import willmore_nlp.flow as flow_module
    from willmore_nlp.solvers import reduced
    from willmore_nlp.solvers.reduced import CONVEXITY_FIRST_RESTARTS

    pb, _ = registry.build("file", path=_cylinder(tmp_path), length=1.0)
    flow = pb.make_flow()
    z0, p = flow.problem.pack_z(flow.X, flow.Y), flow.params(flow.X, flow.tau)
    tau_c = convexity_limit(flow.evaluator, z0, p, CONVEXITY_FIRST_RESTARTS)
    assert tau_c == convexity_limit(flow.evaluator, z0, p)
    assert flow.solver.name == "newton-krylov"  # its Cholesky factors of J_Y's block: the same value
    assert convexity_limit(flow.evaluator, z0, p, solver=flow.solver) == pytest.approx(tau_c, rel=1e-6)
    assert flow.tau / flow_module.CONVEX_FAR < tau_c < flow.tau / 1e4
    # D is factorised with the backend the user chose for newton-krylov (``cholesky``), not CHOLMOD regardless
    backends, factor = [], reduced.SymmetricFactor
    monkeypatch.setattr(reduced, "SymmetricFactor", lambda backend="auto", **kw: backends.append(backend)
                        or factor(backend, **kw))
    scipy = pb.make_flow(cholesky="scipy")
    assert convexity_limit(scipy.evaluator, z0, p, solver=scipy.solver) == pytest.approx(tau_c, rel=1e-6)
    assert backends == ["scipy"]
    monkeypatch.undo()
    with pytest.warns(UserWarning, match="convex at the initial state only below"):
        two = flow.step()
    monkeypatch.setattr(flow_module, "CONVEX_FAR", 1e4)
    flow = pb.make_flow()
    with pytest.warns(UserWarning, match="convex at the initial state only below"):
        one = flow.step()
    assert (two.retries, one.retries) == (2, 0) and one.tau == two.tau and one.rejected == []
    assert np.array_equal(one.vertices, two.vertices)
    # IPOPT's failed attempts are cheap and it took some far below tau_c at tau: it looks after its first failure
    flow = pb.make_flow(solver="ipopt", fallback_solver="")
    with pytest.warns(UserWarning, match="convex at the initial state only below"):
        ipopt = flow.step()
    assert ipopt.retries == 1 and ipopt.tau == two.tau
    assert [r.split(":")[0] for r in ipopt.rejected] == [f"tau={flow.tau:.6g}"]


def test_a_first_step_taken_at_tau_over_2_is_unchanged(tmp_path) -> None:
    """The smoothed box of docs/guide/mesh_quality_measurements.md's tables (trimesh box subdivided 3 times and
    Laplacian-smoothed 5 times, 386 v; IPOPT): its first attempt fails, the one at tau / 2 converges although tau_c =
    tau / 10,860 (the largest ratio measured where that happens, which ``CONVEX_FAR`` stays above): the first look finds
    tau_c, no jump follows, and the states with and without ``convex_start`` are equal bit for bit."""
    from willmore_nlp.flow import CONVEX_FAR, CONVEX_JUMP

    b = trimesh.creation.box().subdivide().subdivide().subdivide()
    trimesh.smoothing.filter_laplacian(b, iterations=5)
    b.export(tmp_path / "box.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "box.obj"), length=1.0)
    runs = [pb.make_flow(convex_start=flag) for flag in (True, False)]
    steps = [flow.step() for flow in runs]
    assert [r.retries for r in steps] == [1, 1] and steps[0].tau == runs[0].tau / 2
    tau_c = runs[0]._tau_c[0]
    assert runs[0].tau / CONVEX_FAR < tau_c < runs[0].tau / CONVEX_JUMP
    assert np.array_equal(runs[0].X, runs[1].X)


def test_a_first_step_with_volume_and_area_fixed_is_retried_below_tau_c(tmp_path) -> None:
    """trimesh's box subdivided 3 times (386 v, its edges sharp) with V and A fixed (IPOPT): the outer constraints'
    convexity limit is the unconstrained one (their multipliers 0; a lower bound on their tangent space), tau / 4,287
    (measured). With outer constraints only the last attempt goes below tau_c (here ``max_retries = 2``; the
    ``file`` problem's 8 fail from tau to tau / 128, IPOPT's iterates collapsing triangles, measured): the attempts at
    tau and tau / 2 fail, the last one is below tau_c and converges, V and A kept. Before, tau_c was not computed with
    outer constraints (inf) and the first step failed at every tau."""
    trimesh.creation.box().subdivide().subdivide().subdivide().export(tmp_path / "box.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "box.obj"))
    flow = pb.make_flow(volume="initial", area="initial", max_retries=2)
    free = pb.make_flow()
    z0 = flow.problem.pack_z(flow.X, flow.Y)
    assert flow.problem.nh == 2 and np.array_equal(z0, free.problem.pack_z(free.X, free.Y))
    tau_c = convexity_limit(flow.evaluator, z0, flow.params(flow.X, flow.tau))
    assert tau_c == pytest.approx(convexity_limit(free.evaluator, z0, free.params(free.X, free.tau)), rel=1e-9)
    assert tau_c < flow.tau / 1e3
    V0, A0 = geometry.enclosed_volume(flow.mesh), geometry.measure(flow.mesh)
    with pytest.warns(UserWarning, match="convex at the initial state only below"):
        first = flow.step()
    assert first.retries == 2 and first.tau <= tau_c
    state = flow.mesh.with_vertices(flow.X)
    assert geometry.enclosed_volume(state) == pytest.approx(V0, rel=1e-12)
    assert geometry.measure(state) == pytest.approx(A0, rel=1e-12)


def test_a_run_that_started_below_tau_c_resumes_bit_for_bit(tmp_path, straight_and_resumed) -> None:
    """The cylinder's run of 5 steps straight and cut after 2 then resumed: the same states (the step-size control
    replays the first step's retry from history.csv)."""
    full, part = straight_and_resumed([_cylinder(tmp_path), "--set", "length=1"], 5, 2, tmp_path)
    assert int(full.history[1]["retries"]) == 2 and float(full.history[1]["tau"]) < float(full.history[0]["tau"]) / 1e4
    assert [h["tau"] for h in full.history] == [h["tau"] for h in part.history]
    for ya, yb, sa, sb in zip(full.Y, part.Y, full.states, part.states, strict=True):
        assert np.array_equal(sa.vertices, sb.vertices) and np.array_equal(ya, yb)


def test_a_convexity_limit_under_the_floor_is_named_with_the_min_tau_that_reaches_it(tmp_path) -> None:
    """trimesh's raw cone (34 v, refined by the file problem to 192 v; its apex stays): tau_c = tau / 5.1e4 (measured),
    and the step sizes tau / 2^j below it are under the floor min_tau = 0.01 h^4, so the attempts go on halving and
    step 1 fails; a warning names tau_c, the smallest attempt (tau / 2^max_retries) and a min_tau below tau_c, with
    which the next attempt starts below tau_c / 2 and converges."""
    import re

    from willmore_nlp import FlowError

    trimesh.creation.cone(radius=0.5, height=1.0).export(tmp_path / "cone.obj")
    with pytest.warns(UserWarning, match="edges in size"):
        pb, _ = registry.build("file", path=str(tmp_path / "cone.obj"))
    flow = pb.make_flow()
    with pytest.warns(UserWarning, match="under the step-size floor") as record, pytest.raises(FlowError):
        flow.step()
    message = next(str(w.message) for w in record if "under the step-size floor" in str(w.message))
    tau_c = float(re.search(r"only below tau = ([0-9.e+-]+)", message).group(1))
    # (it says how far the halving goes: a user read "the attempts go on halving" as reaching tau_c)
    last = float(re.search(r"halving to tau / 2\^\d+ = ([0-9.e+-]+) \(max_retries\)", message).group(1))
    assert last == pytest.approx(flow.tau / 2**flow.settings.max_retries, rel=1e-2) and last > tau_c
    min_tau = float(re.search(r"--set min_tau=([0-9.e+-]+)", message).group(1))
    assert flow.tau / 2 ** np.ceil(np.log2(flow.tau / tau_c)) < flow.min_tau and min_tau < tau_c / 2
    flow = pb.make_flow(min_tau=min_tau)
    with pytest.warns(UserWarning, match="the next attempt is at tau"):
        first = flow.step()
    assert first.retries == 2 and first.tau <= tau_c / 2 * 1.01  # (tau_c as printed: 3 digits)


def test_newton_krylov_leaves_a_first_step_far_from_convex_under_the_floor_to_its_fallback(tmp_path) -> None:
    """When the first look finds tau_c far below tau (< tau / ``CONVEX_FAR``) and under the step-size floor, so that
    no attempt can start below it, newton-krylov's first-step attempts are left to the fallback (IPOPT): a trimesh
    icosphere(3) with normal noise 0.2 h (625 v after the input repair) at tau = 20 h with min_tau = tau / 10^4
    (tau / tau_c = 2.9e5, measured) is IPOPT's step at tau, bit for bit that of an IPOPT flow, with a warning naming
    tau_c and the floor (measured on a noisy 2,279-vertex icosphere at tau = h, where tau_c is under the default
    floor: nine failed newton-krylov attempts, then IPOPT at tau, 73.5 s -> 13.0 s, the same state)."""
    import re

    from willmore_nlp.flow import CONVEX_FAR, SKIP_REASON

    m = trimesh.creation.icosphere(3)
    m.vertices += 0.2 * m.edges_unique_length.mean() * np.random.default_rng(1).standard_normal(m.vertices.shape)
    m.export(tmp_path / "noisy.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "noisy.obj"))
    tau = 20 * pb.tau
    flow = pb.make_flow(tau=tau, min_tau=tau / 1e4)
    ref = pb.make_flow(tau=tau, min_tau=tau / 1e4, solver="ipopt", fallback_solver="")
    assert flow._step_solvers() == ("newton-krylov", "ipopt")
    ref.evaluator.cholesky = flow.evaluator.cholesky  # newton-krylov gives the flow's Y[X] solves its Cholesky
    ref.Y = ref._solve_y(ref.X, ref.tau)
    notes: list[str] = []
    flow.on_retry = notes.append
    with pytest.warns(UserWarning, match="under the step-size floor") as record:
        r = flow.step()
    message = next(str(w.message) for w in record if "under the step-size floor" in str(w.message))
    tau_c = float(re.search(r"only below tau = ([0-9.e+-]+)", message).group(1))
    assert tau_c < flow.tau / CONVEX_FAR and tau_c < flow.min_tau
    q = ref.step()
    assert r.stats["solver"] == "ipopt" and r.retries == q.retries == 0 and r.tau == q.tau == flow.tau
    assert r.rejected == [f"tau={flow.tau:.6g}: newton-krylov: {SKIP_REASON} = {flow.min_tau:.3g}"]
    assert len(notes) == 1 and notes[0].endswith(f"attempt 1: ipopt at tau={flow.tau:.3g}")  # no attempt before
    np.testing.assert_array_equal(r.vertices, q.vertices)


def test_a_first_look_that_finds_nothing_is_followed_by_the_full_one_after_a_failure(tmp_path, monkeypatch) -> None:
    """When the first look before newton-krylov's first attempt does not converge (nan: a 28,212-vertex dumbbell,
    whose full look finds tau / 1.65e5), the full look follows that attempt's failure instead of the second attempt at
    tau / 2 (200 s there). Made so on the cylinder: its first look answers nan, and with ``CONVEX_FAR`` at 1e4 its
    tau_c (tau / 5e4) is far: one failed attempt, then the step below tau_c, the state of the two-failure path."""
    import willmore_nlp.flow as flow_module
    from willmore_nlp.solvers import reduced

    pb, _ = registry.build("file", path=_cylinder(tmp_path), length=1.0)
    with pytest.warns(UserWarning, match="convex at the initial state only below"):
        two = pb.make_flow().step()  # (the full look after two failures: tau_c above tau / CONVEX_FAR)
    looks: list[int] = []
    full = reduced.convexity_limit

    def blind_first(evaluator, z0, p, restarts=reduced.CONVEXITY_RESTARTS, solver=None, dense=False):
        looks.append(restarts)
        return float("nan") if restarts == reduced.CONVEXITY_FIRST_RESTARTS else full(evaluator, z0, p, restarts,
                                                                                        solver, dense=dense)

    monkeypatch.setattr(reduced, "convexity_limit", blind_first)
    monkeypatch.setattr(flow_module, "CONVEX_FAR", 1e4)
    with pytest.warns(UserWarning, match="convex at the initial state only below"):
        one = pb.make_flow().step()
    assert looks == [reduced.CONVEXITY_FIRST_RESTARTS, reduced.CONVEXITY_RESTARTS]
    assert (two.retries, one.retries) == (2, 1) and one.tau == two.tau
    assert np.array_equal(one.vertices, two.vertices)


def test_a_refinement_lowers_the_floor_to_the_edge_of_its_finest_part(tmp_path) -> None:
    """trimesh's box subdivided 3 times (386 v) with V and A fixed, the ``file`` problem's defaults: the flow sharpens
    the corners into cones and refines near them after steps 1 and 9 (386 -> 646 -> 681 v, edge there / 1.41 each),
    and the refined state's step problem is convex only below tau_c = 1.42e-6 (measured), under the initial mesh's floor
    0.01 h^4 = 4.1e-6: step 10 failed with that floor. The floor follows the finest edge (/ 4 per refinement, as
    tau_tilde / 2), step 10 is taken below the initial floor, V and A are kept; a flow restarted from a history with
    those refinements has the same floor."""
    trimesh.creation.box().subdivide().subdivide().subdivide().export(tmp_path / "box.obj")
    pb, _ = registry.build("file", path=str(tmp_path / "box.obj"))
    flow = pb.make_flow(volume="initial", area="initial")
    floor0 = flow.min_tau
    assert floor0 == pytest.approx(1e-2 * flow.mesh.h**4, rel=1e-12)
    V0, A0 = geometry.enclosed_volume(flow.mesh), geometry.measure(flow.mesh)
    with pytest.warns(UserWarning, match="refined"):
        steps = flow.run(steps=10)
    refined = [r.step for r in steps if "refine" in r.remeshed.split("+")]
    assert refined  # (measured: after steps 1 and 9)
    assert flow.min_tau == pytest.approx(floor0 / 4 ** len(refined), rel=1e-12)
    assert steps[9].tau < floor0 and steps[9].tau >= flow.min_tau
    state = flow.mesh.with_vertices(flow.X)
    assert geometry.enclosed_volume(state) == pytest.approx(V0, rel=1e-10)
    assert geometry.measure(state) == pytest.approx(A0, rel=1e-10)
    again = pb.make_flow(volume="initial", area="initial")
    rows = [{"step": r.step, "remesh_action": r.remeshed} for r in steps]
    again.restart(flow.X, flow.Y, flow.t, flow.k, simplices=flow.mesh.simplices, history=rows,
                  last_tau=steps[-1].tau, tau_tilde=flow.tau_tilde)
    assert again.min_tau == flow.min_tau
    given = pb.make_flow(volume="initial", area="initial", min_tau=1e-5)
    given.restart(flow.X, flow.Y, flow.t, flow.k, simplices=flow.mesh.simplices, history=rows)
    assert given.min_tau == 1e-5  # (a given floor is kept as given)


def _wobbly_ellipse(tmp_path: Path, n: int = 400) -> str:
    """A curve file: x = 2 cos s + 0.3 cos 5s, y = 0.7 sin s at n equal steps of s (smooth, two tips of radius 0.05;
    a new user's input)."""
    s = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    path = tmp_path / f"wobble{n}.txt"
    np.savetxt(path, np.column_stack([2 * np.cos(s) + 0.3 * np.cos(5 * s), 0.7 * np.sin(s)]))
    return str(path)


def test_a_smooth_curve_whose_lanczos_look_found_nothing_gets_its_dense_tau_c_and_flows(tmp_path) -> None:
    """A smooth 400-vertex curve with two sharp tips failed its first step with the file problem's defaults (all 18
    attempts, IPOPT and newton-krylov down to tau / 256): its step problem is convex only below tau / 11,121 (the
    tips' time scale), and the Lanczos look did not converge (a wide spectrum whose lowest modes come in pairs), so
    convex_start saw nothing (a new user's check). A curve's tau_c now comes from the dense reduced Hessian: it is
    where a finite-difference reduced Hessian (not the second-order adjoint products) stops being positive definite,
    and the run starts below it and takes its steps, the curve's Willmore energy falling at each."""
    pb, _ = registry.build("file", path=_wobbly_ellipse(tmp_path))
    flow = pb.make_flow()
    z0, P = flow.problem.pack_z(flow.X, flow.Y), flow.problem
    red = ReducedSolver(flow.evaluator, ReducedSettings(), "newton")
    x0, Y0, tau = z0[: red.nxm], P.unpack_z(z0, flow.X)[1], flow.tau
    p = flow.params(flow.X, tau)
    H = _fd_reduced_hessian(red, x0, p, Y0)
    D = red._distance_hessian(red._at(x0, p, Y0).z, p).toarray()
    tau_c = convexity_limit(flow.evaluator, z0, p)
    assert tau_c < tau / 1e4
    for factor, definite in ((0.95, True), (1.05, False)):
        Hf = D + factor * tau_c / tau * (H - D)
        assert bool(sl.eigh(Hf, D, eigvals_only=True, subset_by_index=[0, 0])[0] > 0) is definite
    with pytest.warns(UserWarning, match=r"convex at the initial state only below tau = .*the next attempt is at tau"):
        first = flow.step()
    assert first.converged and first.tau <= tau_c
    w = [geometry.willmore_energy(flow.initial_mesh), first.willmore]
    for _ in range(4):
        w.append(flow.step().willmore)
    assert np.all(np.diff(w) < 0)


def test_a_fixed_step_flow_that_fails_names_the_convexity_limit_and_a_tau_below_it_steps() -> None:
    """The torus problem at tau = 5.9 with tangential_weight = 1 (a new user's compare at 20h) failed its first step at
    every attempt (IPOPT, 100-200 iterations each, to tau / 16) with no word on what to do: convex_start takes only
    adaptive or relax steps. The error now ends with the step problem's convexity limit at the state and the two ways
    on. Its tau_c is where a finite-difference reduced Hessian stops being positive definite (the dense eigenproblem:
    the Lanczos look's estimate, tau / 152, missed the torus's lowest mode; the finite differences give tau / 421); a
    fixed step at the tau it names (tau_c / 2) is taken at its first attempt, and the adaptive flow's first step (from
    the Lanczos estimate) starts below tau_c."""
    import re

    from willmore_nlp import registry
    from willmore_nlp.flow import FlowError

    pb, _ = registry.build("torus", tau=5.9, tangential_weight=1.0)
    with pytest.raises(FlowError) as err:
        pb.make_flow(max_retries=1, **{"ipopt.max_iter": 40}).step()
    assert err.value.hint and str(err.value).endswith(err.value.hint)
    tau_c = float(re.search(r"convex at this state only below tau = ([0-9.e+-]+) = ", err.value.hint).group(1))
    given = float(re.search(r"give tau = ([0-9.e+-]+) ", err.value.hint).group(1))
    assert given <= tau_c / 2 * 1.01 and "adaptive = true" in err.value.hint and "estimate" not in err.value.hint
    flow = pb.make_flow()
    z0 = flow.problem.pack_z(flow.X, flow.Y)
    red = ReducedSolver(flow.evaluator, ReducedSettings(), "newton")
    x0, Y0, p = z0[: red.nxm], flow.problem.unpack_z(z0, flow.X)[1], flow.params(flow.X, flow.tau)
    H = _fd_reduced_hessian(red, x0, p, Y0)
    D = red._distance_hessian(red._at(x0, p, Y0).z, p).toarray()
    for factor, definite in ((0.95, True), (1.05, False)):  # (D + t R = D + t (H - D) / tau, at t = factor tau_c)
        t = factor * tau_c
        smallest = sl.eigh(D + t / flow.tau * (H - D), D, eigvals_only=True, subset_by_index=[0, 0])[0]
        assert (smallest > 0) == definite, (factor, smallest)
    at_limit, _ = registry.build("torus", tau=given, tangential_weight=1.0)
    flow = at_limit.make_flow()
    w0 = flow.state().willmore
    r = flow.step()
    assert r.tau == given and r.retries == 0 and r.willmore < w0
    adaptive = pb.make_flow(adaptive=True, **{"ipopt.max_iter": 40}).step()
    assert adaptive.tau <= tau_c
