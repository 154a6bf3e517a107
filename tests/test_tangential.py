"""Tangential weight beta of the distance term: exact form, derivatives, and the unchanged geometric flow."""

import subprocess
import sys

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow, registry
from willmore_nlp.analysis import axis_widths, wulff_widths
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.model.build import build_step
from willmore_nlp.model.evaluator import StepEvaluator


def _perturbed(mesh: Mesh, seed: int) -> Mesh:
    rng = np.random.default_rng(seed)
    return mesh.with_vertices(mesh.vertices + 0.05 * mesh.h * rng.normal(size=mesh.vertices.shape))


def _tangential_distance(Xk: np.ndarray, X: np.ndarray, S: np.ndarray) -> float:
    """sum_T int_T |P_T (X - Xk)|^2 with P1 interpolation, P_T the tangent projector of T in Xk (numpy)."""
    D = X - Xk
    total = 0.0
    for s in S:
        E = Xk[s[1:]] - Xk[s[0]]
        if len(s) == 2:
            t = E[0] / np.linalg.norm(E[0])
            P = np.outer(t, t)
            size = np.linalg.norm(E[0])
        else:
            n = np.cross(E[0], E[1])
            size = 0.5 * np.linalg.norm(n)
            n /= np.linalg.norm(n)
            P = np.eye(3) - np.outer(n, n)
        k = len(s)
        Mloc = size * (np.ones((k, k)) + np.eye(k)) / (k * (k + 1))
        U = D[s] @ P
        total += float(np.sum(Mloc * (U @ U.T)))
    return total


@pytest.mark.parametrize("case", ["curve", "surface", "anisotropic curve"])
def test_weighted_distance_matches_numpy_and_derivatives_fd(case: str, check_step_derivatives) -> None:
    """W(beta) - W(1) = (beta - 1) sum_T int_T |P_T (X - Xk)|^2 (independent numpy assembly); the
    gradient of W and the Lagrangian Hessian against central differences."""
    base = shapes.ellipse(14, 1.0, 0.7) if case != "surface" else shapes.icosphere(1)
    mesh = _perturbed(base, 0)
    aniso = "gamma1" if case == "anisotropic curve" else None
    beta = 50.0
    evs = []
    for b in (1.0, beta):
        setup = build_step(mesh, anisotropy=aniso, tangential_weight=b)
        evs.append((setup, StepEvaluator(setup.problem, setup.problem.functions())))
    (_, ev1), (sb, evb) = evs
    rng = np.random.default_rng(3)
    V = mesh.vertices
    X = V + 0.2 * mesh.h * rng.normal(size=V.shape)
    Y = X + 0.1 * mesh.h * rng.normal(size=V.shape)
    P = sb.problem
    z, p = P.pack_z(X, Y), sb.params(V, 0.3, 0.1 * mesh.h**2, 0.5)
    expected = (beta - 1) * _tangential_distance(V, X, mesh.simplices)
    assert expected > 1e-3 * evb.f(z, p)
    assert evb.f(z, p) - ev1.f(z, p) == pytest.approx(expected, rel=1e-10)

    check_step_derivatives(evb, z, p, rng)


def _tangential_motion(Xk: np.ndarray, X: np.ndarray) -> float:
    """Largest component of X - Xk along the nodal tangents (central differences) of the closed polygon Xk."""
    T = np.roll(Xk, -1, axis=0) - np.roll(Xk, 1, axis=0)
    T /= np.linalg.norm(T, axis=1)[:, None]
    return float(np.max(np.abs(np.sum((X - Xk) * T, axis=1))))


def test_tangential_weight_changes_the_nodes_not_the_curve(curves_agree_before_nodes) -> None:
    """Willmore flow of an ellipse (nodes equally spaced in angle, so the paper's scheme moves them
    along the curve) with beta = 1 and beta = 100 up to t = 0.04 (tau = h/8): the curves converge to
    each other under refinement, faster than the nodes do. Measured (n = 32, 64, 128): curve distance
    2.16e-2, 6.0e-3, 1.6e-3 (order 1.9), node distance 2.2e-2, 6.7e-3, 3.8e-3 (order 1.3), while the
    curve moves 0.16; one step's tangential motion (tau = h, n = 64) shrinks by a factor 95."""
    curves_agree_before_nodes({"tangential_weight": 1.0}, {"tangential_weight": 100.0})

    mesh = shapes.ellipse(64, 1.0, 0.5)
    moved = {b: WillmoreFlow(mesh, tau=mesh.h, tau_tilde=0.1 * mesh.h**2, tangential_weight=b).step().vertices
             for b in (1.0, 100.0)}
    assert _tangential_motion(mesh.vertices, moved[100.0]) < 0.1 * _tangential_motion(mesh.vertices, moved[1.0])


def test_bunny_gamma2_runs_to_its_rounded_square_wulff_shape() -> None:
    """Fig. 11, third row, with the tangential weight alone: the bunny under gamma2 with eps = 0.1,
    tangential weight 1000 and no redistribution (README, "Anisotropic flow": eps = 1e-7 fails).
    Its diagonal / axial width ratio moves from the bunny's towards that of the Wulff shape,
    gamma(diag) / gamma(axis) = 1.135 (circle 1, square sqrt 2): 0.99 at t = 0.025, 1.135 at t = 5
    (100 steps), 1.137 at t = 30. Every step is taken at tau = h after the first few."""
    bunny = registry.problem_module("anisotropic").bunny

    prob = bunny(gamma="gamma2:0.1", redistribute=False)
    assert prob.flow_options["tangential_weight"] == 1000.0
    # full IPOPT solves, as in the reproduction (PAPER_SCHEME): the claim "every step at tau = h after the
    # first few" is one of the scheme; the iteration budget cuts step 34's slow solve and retries it at tau/2
    flow = WillmoreFlow(prob.mesh, prob.tau, prob.tau_tilde, lam=prob.lam, **prob.flow_options,
                        iteration_budget=0, stall_iterations=0)
    ww = wulff_widths("gamma2:0.1")
    wulff = ww[2:].mean() / ww[:2].mean()
    assert wulff == pytest.approx(2 * np.sqrt(0.6) / (np.sqrt(1.1) + np.sqrt(0.1)), rel=1e-12)  # 1.1349
    out = flow.run(t_end=5.0)
    energies = [r.energy for r in out]
    assert np.all(np.diff(energies) <= 1e-8 * np.abs(energies[:-1]))
    assert all(r.retries == 0 for r in out[10:])
    w = axis_widths(flow.X)
    ratio = w[2:].mean() / w[:2].mean()
    w0 = axis_widths(prob.mesh.vertices)
    assert w0[2:].mean() / w0[:2].mean() < 1.06
    assert ratio == pytest.approx(wulff, abs=0.03)


def test_bad_tangential_weights_are_refused(tmp_path) -> None:
    mesh = shapes.ellipse(16, 1.0, 0.7)
    for bad in (0.5, float("nan"), -1.0, 1e10):
        with pytest.raises(ValueError, match=r"tangential_weight must be a number in \[1, 1e\+08\]"):
            WillmoreFlow(mesh, mesh.h, 0.1 * mesh.h**2, tangential_weight=bad)
    with pytest.raises(ValueError, match="semi-implicit: the baseline has no tangential weight"):
        WillmoreFlow(mesh, mesh.h, 0.1 * mesh.h**2, tangential_weight=10.0, solver="semi-implicit")
    r = subprocess.run([sys.executable, "-m", "willmore_nlp.cli", "run", "circle", "--set", "tangential_weight=0.1",
                        "--steps", "1", "--out", str(tmp_path / "bad")], capture_output=True, text=True, timeout=600)
    assert r.returncode != 0 and "tangential_weight must be a number in [1, 1e+08]" in r.stderr
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("beta", [1.5, 1e6 + 0.25, 1e8])
def test_any_tangential_weight_in_range_builds_its_kernels(beta: float) -> None:
    """The weight is part of the compiled kernels' names, which must be identifiers: any weight that is not an integer
    (found by a new-user check: 1.5, 2.5, 12.5) or from 1e6 on ("tw1e+06") crashed with exit 70. Each takes the first
    step without a retry, to a Willmore energy within 2 % of the paper's weight 1 (the weight charges only the
    tangential motion)."""
    sphere = shapes.icosphere(1)
    V = sphere.vertices * [1.0, 1.0, 1.3]
    steps = {b: WillmoreFlow(sphere.with_vertices(V), 0.01, 1e-4, tangential_weight=b).step() for b in (1.0, beta)}
    assert steps[beta].retries == 0 and steps[beta].willmore == pytest.approx(steps[1.0].willmore, rel=2e-2)
