"""IPOPT with exact element-assembled Hessians (the default; the paper's Newton/SQP analogue)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import casadi as ca
import numpy as np

from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.solvers.base import SolveResult, register_solver

IPOPT_DEFAULTS: dict[str, Any] = {
    "tol": 1e-9,
    "acceptable_tol": 1e-6,
    "max_iter": 200,
    "print_level": 0,
    "mu_strategy": "monotone",  # no inequalities or bounds: the barrier plays no role, adaptive costs time
    "constr_mult_init_max": 0.0,  # start multipliers at 0: saves the least-squares factorisation (~25% per step)
    "linear_solver": "mumps",
    "mumps_pivot_order": 5,  # METIS: decisive at scale (docs/theory/pitfalls.md, 'Sparse factorisation ordering')
    "sb": "yes",
}
"""IPOPT options used unless overridden (keys without the ``ipopt.`` prefix)."""


def _never() -> bool:
    return False


class _StopHook(ca.Callback):
    """IPOPT iteration callback: asks ``check()`` once per iteration; True stops the solve.

    IPOPT then returns ``User_Requested_Stop`` (not converged). An exception raised in ``check``
    (a KeyboardInterrupt from a signal handler) is caught by CasADi and stops the solve the same way.
    """

    def __init__(self, nx: int, ng: int, check: Callable[[], bool]) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.check = nx, ng, check
        self.construct("willmore_stop_hook", {})

    def get_n_in(self) -> int:
        return int(ca.nlpsol_n_out())

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return str(ca.nlpsol_out(i))

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        n = ca.nlpsol_out(i)
        if n == "f":
            return ca.Sparsity.scalar()
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[Any]:
        return [1 if self.check() else 0]


class IpoptSolver:
    """One ``nlpsol('ipopt')`` object serving every step of a run.

    Parameters
    ----------
    evaluator : StepEvaluator
        Supplies ``f``/``g`` expressions and the assembled ``grad_f``, ``jac_g`` and
        ``hess_lag`` functions, passed to IPOPT directly (no global AD).
    options : dict
        IPOPT options (``tol``, ``max_iter``, ``mu_strategy``, ``warm_start`` ...), merged over
        :data:`IPOPT_DEFAULTS`. ``warm_start=True`` passes the previous multipliers and sets
        ``warm_start_init_point``.

    Attributes
    ----------
    should_stop : callable () -> bool
        Polled once per IPOPT iteration; True ends the solve at once (``User_Requested_Stop``).
        The flow sets it (:attr:`willmore_nlp.flow.WillmoreFlow.stop_requested`).
    """

    name = "ipopt"

    def __init__(self, evaluator: StepEvaluator, options: dict[str, Any]) -> None:
        fn = evaluator.fn
        opts = dict(IPOPT_DEFAULTS)
        self.warm_start = bool(options.pop("warm_start", False))
        opts.update(options)
        if self.warm_start:
            opts["warm_start_init_point"] = "yes"
        nlp = {"x": fn["z"], "p": fn["p"], "f": fn["f_expr"], "g": fn["g_expr"]}
        self.options = opts
        self.should_stop: Callable[[], bool] = _never
        self._hook = _StopHook(fn["z"].numel(), fn["g_expr"].numel(), lambda: self.should_stop())
        self._solver = ca.nlpsol(
            "willmore_step",
            "ipopt",
            nlp,
            {
                "grad_f": fn["grad_f"],
                "jac_g": fn["jac_g"],
                "hess_lag": fn["hess_lag"],
                "print_time": False,
                "record_time": True,
                "error_on_fail": False,
                "iteration_callback": self._hook,
                "ipopt": opts,
            },
        )
        self.ng = evaluator.problem.ng

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """Solve from ``z0``; ``lam_g0`` is used when warm starting."""
        args: dict[str, Any] = {"x0": z0, "p": p, "lbg": 0.0, "ubg": 0.0}
        if self.warm_start and lam_g0 is not None:
            args["lam_g0"] = lam_g0
        r = self._solver(**args)
        st = self._solver.stats()
        status = str(st.get("return_status", "unknown"))
        it = st.get("iterations", {})
        stats = {
            "n_eval_f": st.get("n_call_nlp_f", 0),
            "n_eval_grad_f": st.get("n_call_nlp_grad_f", 0),
            "n_eval_g": st.get("n_call_nlp_g", 0),
            "n_eval_jac_g": st.get("n_call_nlp_jac_g", 0),
            "n_eval_hess": st.get("n_call_nlp_hess_l", 0),
            "t_wall_total": st.get("t_wall_total", float("nan")),
            "t_wall_eval": sum(
                st.get(f"t_wall_nlp_{k}", 0.0) for k in ("f", "g", "grad_f", "jac_g", "hess_l")
            ),
            "inf_pr": float(it["inf_pr"][-1]) if it.get("inf_pr") else float("nan"),
            "inf_du": float(it["inf_du"][-1]) if it.get("inf_du") else float("nan"),
        }
        stats["t_wall_solver"] = stats["t_wall_total"] - stats["t_wall_eval"]
        stats["kkt_residual"] = max(stats["inf_pr"], stats["inf_du"])
        z = np.asarray(r["x"]).ravel()
        f = float(r["f"])
        converged = bool(st.get("success", False)) and status == "Solve_Succeeded" and np.all(np.isfinite(z))
        return SolveResult(
            z=z,
            f=f,
            lam_g=np.asarray(r["lam_g"]).ravel(),
            converged=converged,
            status=status,
            iterations=int(st.get("iter_count", 0)),
            stats=stats,
        )


@register_solver("ipopt")
def make_ipopt(evaluator: StepEvaluator, options: dict[str, Any]) -> IpoptSolver:
    """Factory for :class:`IpoptSolver`."""
    return IpoptSolver(evaluator, options)
