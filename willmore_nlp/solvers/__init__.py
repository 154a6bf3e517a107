"""Step solvers behind one factory signature: ``make_solver(name, evaluator, options)``."""

from willmore_nlp.solvers import ipopt as _ipopt  # noqa: F401  (registers "ipopt")
from willmore_nlp.solvers import newton_krylov as _nk  # noqa: F401  (registers "newton-krylov")
from willmore_nlp.solvers import reduced as _reduced  # noqa: F401  (registers "gd", "lbfgs", "newton")
from willmore_nlp.solvers import semi_implicit as _semi  # noqa: F401  (registers "semi-implicit")
from willmore_nlp.solvers import sqp as _sqp  # noqa: F401  (registers "sqp")
from willmore_nlp.solvers.base import (
    SolveResult,
    check_solver,
    make_solver,
    register_solver,
    solver_capabilities,
    solver_names,
    solver_settings,
)

__all__ = ["SolveResult", "check_solver", "make_solver", "register_solver", "solver_capabilities", "solver_names",
           "solver_settings"]
