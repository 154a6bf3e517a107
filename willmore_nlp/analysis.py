"""Small analysis helpers shared by tests, studies and reports."""

from __future__ import annotations

import numpy as np


def fit_order(h: np.ndarray | list[float], err: np.ndarray | list[float]) -> float:
    """Least-squares slope of log(err) against log(h): the observed convergence order.

    Parameters
    ----------
    h : (n,) mesh sizes or step sizes, n >= 2
    err : (n,) positive errors
    """
    h_, e_ = np.asarray(h, float), np.asarray(err, float)
    if h_.size < 2 or h_.size != e_.size or np.any(h_ <= 0) or np.any(e_ <= 0):
        raise ValueError("fit_order needs at least two positive (h, err) pairs")
    return float(np.polyfit(np.log(h_), np.log(e_), 1)[0])


def winding_number(V: np.ndarray, center: np.ndarray | None = None) -> float:
    """Winding number of a closed polygon (vertices in order, (n, 2+) array) around ``center``.

    Uses the x1-x2 projection; ``center`` defaults to the vertex mean.
    """
    c = V[:, :2] - (V[:, :2].mean(axis=0) if center is None else np.asarray(center)[:2])
    z = c[:, 0] + 1j * c[:, 1]
    dphi = np.angle(np.roll(z, -1) / z)
    return float(dphi.sum() / (2 * np.pi))


def circle_step_radius(Rk: float, tau: float, tt: float) -> float:
    """Radius after one step of the time-discrete, space-continuous scheme for a circle (Sec. 2.1).

    Solves (R - Rk)/tau = 1/2 (R^4 - 3 R^2 tt) / ((R^2 + tt)^3 Rk) for the root near Rk.
    """
    from scipy.optimize import brentq

    def F(R: float) -> float:
        return (R - Rk) / tau - 0.5 * (R**4 - 3 * R**2 * tt) / ((R**2 + tt) ** 3 * Rk)

    return float(brentq(F, 0.5 * Rk, 2.0 * Rk + 10 * tau / Rk**3))


def sphere_step_radius(Rk: float, tau: float, tt: float, lam: float = 0.0) -> float:
    """Radius after one step of the time-discrete, space-continuous scheme for a round sphere.

    With Y = X / (1 + 2 tt/R^2) the inner step, e(R) = 8 pi / (1 + 2 tt/R^2)^2 + lam 4 pi R^2,
    and stationarity of 4 pi Rk^2 (R - Rk)^2 + 2 tau e(R) gives
    R - Rk = -(tau / Rk^2) (16 tt / (R^3 (1 + 2 tt/R^2)^3) + 2 lam R).
    (The scheme shrinks spheres at the rate 16 tt / R^5 for lam = 0: an O(tt) consistency error.)
    """
    from scipy.optimize import brentq

    def F(R: float) -> float:
        return R - Rk + tau / Rk**2 * (16 * tt / (R**3 * (1 + 2 * tt / R**2) ** 3) + 2 * lam * R)

    return float(brentq(F, 1e-3 * Rk, Rk))
