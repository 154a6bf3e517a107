"""Circles: the time-discrete radius equation of Sec. 2.1 and convergence orders O(h^2 + tau + tt)."""

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow
from willmore_nlp.analysis import circle_step_radius, fit_order
from willmore_nlp.fem.assembly import lumped_mass
from willmore_nlp.mesh import shapes

R0 = 1.0


def exact_radius(t: float) -> float:
    return (R0**4 + 2 * t) ** 0.25


def l2_radius_error(X: np.ndarray, S: np.ndarray, R: float) -> float:
    """L2 error of |X| - R on the polygon (lumped mass), as in Table 1."""
    return float(np.sqrt(np.sum(lumped_mass(X, S) * (np.linalg.norm(X, axis=1) - R) ** 2)))


@pytest.mark.parametrize("control", ["off", "meanratio"])
def test_one_step_follows_time_discrete_equation_as_h_to_0(control: str) -> None:
    tau, tt = 0.01, 1e-4
    R_star = circle_step_radius(R0, tau, tt)
    hs, errs = [], []
    for n in (32, 64, 128, 256):
        mesh = shapes.regular_polygon(n, R0)
        r = WillmoreFlow(mesh, tau, tt, tangential_control=control).step()
        R = np.linalg.norm(r.vertices, axis=1)
        assert R.std() < 1e-12  # the regular polygon stays regular
        hs.append(mesh.h)
        errs.append(abs(R.mean() - R_star))
    assert np.all(np.diff(errs) < 0)
    assert fit_order(hs, errs) == pytest.approx(2.0, abs=0.1)


def test_convergence_tau_tt_h2() -> None:
    """Table 1, left column: tau = tt = h^2, error at t = 0.05 is O(h^2)."""
    t_end = 0.05
    hs, errs = [], []
    for n in (64, 128, 256):
        mesh = shapes.regular_polygon(n, R0)
        k = int(np.ceil(t_end / mesh.h**2))
        flow = WillmoreFlow(mesh, t_end / k, t_end / k)
        flow.run(steps=k)
        hs.append(mesh.h)
        errs.append(l2_radius_error(flow.X, mesh.simplices, exact_radius(t_end)))
    assert fit_order(hs, errs) > 1.8


@pytest.mark.parametrize("which", ["tau", "tau_tilde"])
@pytest.mark.filterwarnings("ignore::willmore_nlp.flow.StepSizeWarning")
def test_first_order_in_tau_and_tau_tilde(which: str) -> None:
    """With h small, the radius error is first order in tau (tt tiny) and in tt (tau tiny).

    The tt sweep goes up to 6.6 h^2 on purpose (to isolate the tt error); the regular polygon is
    symmetric, so the tangential degeneracy the StepSizeWarning is about cannot occur here.
    """
    mesh = shapes.regular_polygon(256, R0)
    steps, errs = [], []
    for s in (0.2, 0.1, 0.05, 0.025) if which == "tau" else (4e-3, 2e-3, 1e-3, 5e-4):
        tau, tt, t_end = (s, 1e-5, 0.4) if which == "tau" else (1e-3, s, 0.02)
        flow = WillmoreFlow(mesh, tau, tt)
        flow.run(t_end=t_end)
        steps.append(s)
        errs.append(abs(np.linalg.norm(flow.X, axis=1).mean() - exact_radius(t_end)))
    assert fit_order(steps, errs) == pytest.approx(1.0, abs=0.1)
