"""Shared test helpers (fixtures)."""

from collections.abc import Callable

import numpy as np
import pytest


def _check_step_derivatives(ev, z: np.ndarray, p: np.ndarray, rng: np.random.Generator) -> None:
    """Gradient of W, Jacobian of all constraints c = [g; h] and Lagrangian Hessian of a step evaluator
    against central differences (random direction)."""
    eps = 1e-6
    d = rng.normal(size=z.size)
    fd = (ev.f(z + eps * d, p) - ev.f(z - eps * d, p)) / (2 * eps)
    assert ev.grad_f(z, p) @ d == pytest.approx(fd, rel=1e-6)
    fdc = (ev.c_jac(z + eps * d, p)[0] - ev.c_jac(z - eps * d, p)[0]) / (2 * eps)
    assert np.max(np.abs(ev.c_jac(z, p)[1] @ d - fdc)) <= 1e-6 * np.max(np.abs(fdc))
    lam_c = rng.normal(size=ev.problem.nc)

    def lag_grad(zz: np.ndarray) -> np.ndarray:
        return 0.7 * ev.grad_f(zz, p) + ev.c_jac(zz, p)[1].T @ lam_c

    fdh = (lag_grad(z + eps * d) - lag_grad(z - eps * d)) / (2 * eps)
    assert np.max(np.abs(ev.hess_lag(z, p, 0.7, lam_c) @ d - fdh)) <= 1e-5 * np.max(np.abs(fdh))


@pytest.fixture
def check_step_derivatives() -> Callable[..., None]:
    """:func:`_check_step_derivatives` (assert-style finite-difference check of a StepEvaluator)."""
    return _check_step_derivatives
