"""Shared test helpers (fixtures)."""

from collections.abc import Callable

import numpy as np
import pytest


def _check_step_derivatives(ev, z: np.ndarray, p: np.ndarray, rng: np.random.Generator) -> None:
    """Gradient of W and Lagrangian Hessian of a step evaluator against central differences (random direction)."""
    eps = 1e-6
    d = rng.normal(size=z.size)
    fd = (ev.f(z + eps * d, p) - ev.f(z - eps * d, p)) / (2 * eps)
    assert ev.grad_f(z, p) @ d == pytest.approx(fd, rel=1e-6)
    lam_g = rng.normal(size=ev.problem.ng)

    def lag_grad(zz: np.ndarray) -> np.ndarray:
        return 0.7 * ev.grad_f(zz, p) + ev.jac_g(zz, p).T @ lam_g

    fdh = (lag_grad(z + eps * d) - lag_grad(z - eps * d)) / (2 * eps)
    assert np.max(np.abs(ev.hess_lag(z, p, 0.7, lam_g) @ d - fdh)) <= 1e-5 * np.max(np.abs(fdh))


@pytest.fixture
def check_step_derivatives() -> Callable[..., None]:
    """:func:`_check_step_derivatives` (assert-style finite-difference check of a StepEvaluator)."""
    return _check_step_derivatives
