"""Finite-difference checks of a step problem's derivatives, for the author of a term (docs/guide/terms.md).

CasADi differentiates every term, so a wrong derivative is a wrong term (a value read from the wrong place, a
non-smooth expression), not a wrong formula: :func:`derivative_errors` compares what the solvers are given with central
differences of the values themselves.
"""

from __future__ import annotations

import numpy as np

from willmore_nlp.model.evaluator import StepEvaluator


def derivative_errors(evaluator: StepEvaluator, z: np.ndarray, p: np.ndarray,
                      rng: np.random.Generator | None = None, eps: float = 1e-6) -> dict[str, float]:
    """Relative errors of the assembled derivatives against central differences along a random direction d.

    Parameters
    ----------
    evaluator : StepEvaluator
        A flow's ``flow.evaluator``.
    z : (nx,) point (X, Y) of the step's unknowns, e.g. ``flow.problem.pack_z(X, Y)``
    p : (np,) the step's parameters, e.g. ``flow.params(X, tau)``
    rng : random generator of the direction (and of the multipliers of the Hessian check)
    eps : difference step

    Returns
    -------
    dict
        ``gradient``: |grad W . d - fd| / |fd|; ``jacobian``: max |J_c d - fd| / max |fd| over the constraints c = [g;
        h]; ``hessian``: the same for the Lagrangian 0.7 W + lambda . c with random multipliers lambda. At a smooth
        point about 1e-9 (1e-6 and 1e-5 are the tests' bounds).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    ev = evaluator
    d = rng.normal(size=z.size)
    fd = (ev.f(z + eps * d, p) - ev.f(z - eps * d, p)) / (2 * eps)
    fdc = (ev.c_jac(z + eps * d, p)[0] - ev.c_jac(z - eps * d, p)[0]) / (2 * eps)
    lam_c = rng.normal(size=ev.problem.nc)

    def lag_grad(zz: np.ndarray) -> np.ndarray:
        return 0.7 * ev.grad_f(zz, p) + ev.c_jac(zz, p)[1].T @ lam_c

    fdh = (lag_grad(z + eps * d) - lag_grad(z - eps * d)) / (2 * eps)
    return {"gradient": float(abs(ev.grad_f(z, p) @ d - fd) / max(abs(fd), 1e-300)),
            "jacobian": float(np.max(np.abs(ev.c_jac(z, p)[1] @ d - fdc)) / max(np.max(np.abs(fdc)), 1e-300)),
            "hessian": float(np.max(np.abs(ev.hess_lag(z, p, 0.7, lam_c) @ d - fdh)) / max(np.max(np.abs(fdh)),
                                                                                         1e-300))}
