"""What every step solver returns, and the registry of solver factories."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.model.terms import CAPABILITIES
from willmore_nlp.settings import SolverSettings


@dataclass
class SolveResult:
    """Outcome of one step solve.

    Attributes
    ----------
    z : (nx,) unknowns at the end of the solve
    f : objective W at ``z``
    lam_g : (ng,) constraint multipliers (the adjoint P up to sign and scale)
    converged : True when the solver reports success to its tolerance
    status : solver's own status string
    iterations : outer iterations
    stats : counts and timings (evaluations, linear solves, wall times, residuals)
    """

    z: np.ndarray
    f: float
    lam_g: np.ndarray
    converged: bool
    status: str
    iterations: int
    stats: dict[str, Any] = field(default_factory=dict)


class StepSolver(Protocol):
    """A solver built once per step problem; ``solve`` is called once per time step.

    The flow sets ``should_stop`` on every solver; a solver that can stop early polls it once per
    iteration and returns unconverged when it turns True (IPOPT does; the others finish the solve).
    """

    name: str
    should_stop: Callable[[], bool]

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """Solve the step NLP from ``z0`` with parameters ``p``."""
        ...


SolverFactory = Callable[[StepEvaluator, Any], StepSolver]
_SOLVERS: dict[str, tuple[SolverFactory, type[SolverSettings]]] = {}
_CAPABILITIES: dict[str, tuple[frozenset[str], str]] = {}
_WHY = {"variational": "it does not minimise W", "nonlinear_inner": "its inner equation is linear",
        "constraints": "it has no outer equality constraints"}


def register_solver(name: str, settings: type[SolverSettings], capabilities: frozenset[str] = CAPABILITIES,
                    noun: str = "the solver") -> Callable[[SolverFactory], SolverFactory]:
    """Decorator: register a solver factory under ``name``.

    The factory is called with the evaluator and an instance of ``settings``, which declares and validates the
    solver's options. ``capabilities`` says what it can do (:data:`CAPABILITIES`): :func:`make_solver` refuses a
    step problem with a term that needs one the solver lacks; ``noun`` names the solver in refusals ("the baseline").
    """

    def deco(factory: SolverFactory) -> SolverFactory:
        _SOLVERS[name] = (factory, settings)
        _CAPABILITIES[name] = (frozenset(capabilities), noun)
        return factory

    return deco


def solver_names() -> list[str]:
    """Registered solver names."""
    return sorted(_SOLVERS)


def solver_settings(name: str) -> type[SolverSettings]:
    """The options class of solver ``name`` (UserInputError naming the known solvers if there is none)."""
    if name not in _SOLVERS:
        raise UserInputError(f"unknown solver {name!r}; available: {', '.join(solver_names())}")
    return _SOLVERS[name][1]


def solver_capabilities(name: str) -> frozenset[str]:
    """What solver ``name`` can do (:data:`CAPABILITIES`; UserInputError naming the known solvers if there is none)."""
    solver_settings(name)
    return _CAPABILITIES[name][0]


def check_solver(name: str, problem: Any, options: dict[str, Any] | None = None) -> SolverSettings:
    """The settings of solver ``name`` from ``options``, checked against what the step problem needs.

    Raises
    ------
    UserInputError
        An unknown solver or option, or a problem term the solver cannot handle (``solver NAME: ... has no ...``,
        how to leave the term out and the solvers that can handle it).
    """
    settings = solver_settings(name).from_options(dict(options or {}))
    capabilities, noun = _CAPABILITIES[name]
    check_problem = getattr(_SOLVERS[name][0], "check_problem", None)  # (what the solver cannot take at all, first)
    if check_problem is not None:
        check_problem(problem)
    for cap, term in problem.requires().items():
        if cap not in capabilities:
            able = ", ".join(n for n in solver_names() if cap in _CAPABILITIES[n][0])
            parts = [f"solver {name}: {noun} has no {term.label} ({_WHY[cap]})", term.hint, f"solvers that can: {able}"]
            raise UserInputError("; ".join(p for p in parts if p))  # (a user's term has no hint)
    return settings


def make_solver(name: str, evaluator: StepEvaluator, options: dict[str, Any] | None = None) -> StepSolver:
    """Build the solver ``name`` for a step problem; ``options`` are validated by its settings class."""
    settings = check_solver(name, evaluator.problem, options)
    return _SOLVERS[name][0](evaluator, settings)
