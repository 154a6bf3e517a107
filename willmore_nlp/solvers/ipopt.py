"""IPOPT with exact element-assembled Hessians (the default; the paper's Newton/SQP analogue)."""

from __future__ import annotations

import difflib
import json
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.io import signals_deferred
from willmore_nlp.model.evaluator import StepEvaluator
from willmore_nlp.settings import BOOL, FlowSettings, Kind, SolverSettings, one_of, option, real
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

UNIT_WIDTHS = (0.1, 1e3)
"""Widths of a mesh (its bounding box's largest extent) whose steps IPOPT solves as given (:func:`length_unit`):
the range in which its absolute tolerances were found to work (a 162-vertex ellipsoid 280 wide repeats the unit
steps, W to 1e-9; 2,800 wide it needed a retry and ended 1.5e-5 off; an ellipsoid scaled by 1e-2, 0.04 wide,
repeated them only to 2e-3)."""


def length_unit(V: np.ndarray) -> float:
    """The unit of length in which IPOPT solves the steps of a flow whose initial mesh has the vertices ``V`` (N, m):
    1 for widths in :data:`UNIT_WIDTHS`, else width / 2, the unit in which the mesh is 2 wide (the flow sets it once,
    :attr:`IpoptSolver.length`). IPOPT's tolerances and safeguards are absolute (tol 1e-9 on the KKT residual, the
    Hessian regularisation, the line search's thresholds) while the step's terms are homogeneous in the length: a
    162-vertex ellipsoid 4e-5 wide took 0 iterations and did not move, one 28,000 wide needed 6 retries and ended 2 %
    off (measured 2026-11-29). In this unit a mesh 2 wide scaled beyond :data:`UNIT_WIDTHS` takes its unit-size IPOPT
    iterates, scaled, up to rounding. Inside them the unit stays 1: IPOPT's path depends on the width there too (a
    0.45-wide ellipsoid needs 2 retries for a first step the 3-wide one takes at once), but no width is best for
    every problem (the 7-wide bunny curve of the paper's Fig. 11 with gamma1 fails its first step when solved 2
    wide), and unit-size runs stay as they were."""
    width = float(np.ptp(V, axis=0).max()) if len(V) else 0.0
    if not np.isfinite(width) or width <= 0 or UNIT_WIDTHS[0] <= width <= UNIT_WIDTHS[1]:
        return 1.0
    return width / 2

OPTIONS_FILE = Path(__file__).with_name("ipopt_options.json")
"""IPOPT's options with their types and ranges, as IPOPT documents them (``print_options_mode=doxygen``;
tests/test_settings.py checks it against the installed IPOPT): ``[type, lo, lo_open, hi, hi_open]`` for
"real" and "integer" options, ``["string", [settings] or null (free text)]`` for string options."""


@cache
def ipopt_kinds() -> dict[str, Kind]:
    """Every IPOPT option's allowed values (from :data:`OPTIONS_FILE`; ``sb``, undocumented, added)."""
    kinds = {"sb": one_of("yes", "no")}
    for name, (typ, *rng) in json.loads(OPTIONS_FILE.read_text(encoding="utf-8")).items():
        if typ == "string":
            kinds[name] = Kind("text", lambda v: isinstance(v, str)) if rng[0] is None else one_of(*rng[0])
            continue
        lo, lo_open, hi, hi_open = rng
        lo, hi = -np.inf if lo is None else lo, np.inf if hi is None else hi
        kinds[name] = real(lo, hi, lo_open=lo_open, hi_open=hi_open or hi == np.inf)
        if typ == "integer":
            num = kinds[name]
            kinds[name] = Kind(num.what.replace("a number", "an integer"),
                               lambda v, ok=num.ok: ok(v) and float(v).is_integer(), int)
    return kinds


def check_ipopt_option(name: str, value: Any) -> Any:
    """``value`` of the IPOPT option ``name`` typed for IPOPT, or UserInputError naming both."""
    kind = ipopt_kinds().get(name)
    if kind is None:
        raise UserInputError(f"IPOPT option {name} = {value!r}: unknown option")
    if not kind.ok(value):
        valid = f"not a valid setting (valid: {', '.join(kind.choices)})" if kind.choices else f"must be {kind.what}"
        raise UserInputError(f"IPOPT option {name} = {value!r}: {valid}")
    return kind.convert(value)


@dataclass(frozen=True)
class IpoptSettings(SolverSettings):
    """Options of ``ipopt``: ``warm_start`` and any IPOPT option (checked against :func:`ipopt_kinds`).

    Attributes
    ----------
    warm_start : bool
        Start each step from the previous step's multipliers (``warm_start_init_point``).
    ipopt : tuple
        ``(name, value)`` of the IPOPT options given (over :data:`IPOPT_DEFAULTS`).
    """

    solver = "ipopt"
    warm_start: bool = option(False, BOOL)
    ipopt: tuple[tuple[str, Any], ...] = option((), Kind("IPOPT options", lambda v: isinstance(v, tuple)))

    @classmethod
    def config_keys(cls) -> tuple[str, ...]:
        """``warm_start`` and the IPOPT options that configs take without the ``ipopt.`` prefix."""
        return ("warm_start", "tol", "max_iter", "print_level")

    @classmethod
    def owns(cls, key: str) -> bool:
        """``warm_start`` and IPOPT's options, with or without the ``ipopt.`` prefix."""
        return key in cls.kinds() or key.removeprefix("ipopt.") in ipopt_kinds()

    @classmethod
    def from_options(cls, options: dict[str, Any]) -> IpoptSettings:
        """``warm_start`` and IPOPT options (with or without the ``ipopt.`` prefix)."""
        mine, other = cls.split(options)
        unknown = [k for k in other if not k.startswith("ipopt.") and k not in ipopt_kinds()]
        cls.refuse_others(unknown)
        if unknown:  # (a typo of a flow option lands here)
            k = unknown[0]
            close = difflib.get_close_matches(k, [*FlowSettings.kinds(), *ipopt_kinds()], n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise UserInputError(f"unknown option {k} = {other[k]!r}: neither a flow option nor an IPOPT option{hint}")
        return cls(**mine, ipopt=tuple((k.removeprefix("ipopt."), check_ipopt_option(k.removeprefix("ipopt."), v))
                                       for k, v in other.items()))


def _never() -> bool:
    return False


@cache
def _refused(options: tuple[tuple[str, Any], ...]) -> bool:
    """Whether this IPOPT build refuses ``options`` when it solves (a linear solver it was built without, such as
    ``ma27``, passes the option table and is refused only then): one solve of a one-variable NLP, milliseconds."""
    x = ca.MX.sym("x")
    probe = ca.nlpsol("willmore_probe", "ipopt", {"x": x, "f": x * x},
                      {"print_time": False, "error_on_fail": False,
                       "ipopt": {**dict(options), "print_level": 0, "sb": "yes"}})
    probe(x0=1.0)
    return probe.stats().get("return_status") == "Invalid_Option"


class _StopHook(ca.Callback):
    """IPOPT iteration callback: asks ``check(f, g, x, lam_g)`` once per iteration; True stops the solve.

    ``f`` is the objective, ``g`` the (ng,) constraint values, ``x`` the (nx,) iterate and ``lam_g``
    the (ng,) constraint multipliers of the current iterate. IPOPT then
    returns ``User_Requested_Stop`` (not converged). An exception raised in ``check`` (a
    KeyboardInterrupt from a signal handler) is caught by CasADi and stops the solve the same way.
    """

    def __init__(self, nx: int, ng: int, check: Callable[[float, np.ndarray, np.ndarray, np.ndarray], bool]) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng, self.check = nx, ng, check
        names = [str(ca.nlpsol_out(i)) for i in range(int(ca.nlpsol_n_out()))]
        self._i = {k: names.index(k) for k in ("f", "g", "x", "lam_g")}
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
        i = self._i
        x, g, lam = (np.asarray(arg[i[k]]).ravel() for k in ("x", "g", "lam_g"))
        return [1 if self.check(float(arg[i["f"]]), g, x, lam) else 0]


def _changed(a: float, b: float, factor: float) -> bool:
    """``a`` and ``b`` (both >= 0) differ by more than ``factor`` times, either way."""
    return a > factor * b or b > factor * a


class SolveMonitor:
    """Per-solve iteration budget and stall test, polled by :class:`_StopHook` once per iteration.

    Parameters
    ----------
    iteration_limit : int or None
        Stop (status ``"Iteration_Budget"``) when this many iterations are done without
        convergence; None: no limit beyond IPOPT's ``max_iter``.
    stall_iterations : int
        Stop (status ``"Stalled"``) when the iterates are stuck: for ``stall_iterations``
        iterations the objective stayed within ``stall_rtol`` (relative), the largest constraint
        violation within a factor 10 and the dual residual (``dual_residual``, evaluated only when
        the first two stayed) within a factor 2 of their values at the last iterate that moved. A
        solve that wanders (the objective going up and down) is not stalled: the iteration budget
        is the limit for those. 0 turns the test off.
    stall_rtol : float
        Relative change of the objective that counts as movement.
    dual_residual : callable (x, lam_g) -> float, optional
        Largest entry of the gradient of the Lagrangian at the iterate; None: not used.

    Attributes
    ----------
    cut : str
        ``""`` while the solve runs or after a normal end; ``"Iteration_Budget"`` or ``"Stalled"``
        after the monitor stopped it.
    """

    def __init__(self, iteration_limit: int | None = None, stall_iterations: int = 0, stall_rtol: float = 1e-8,
                 dual_residual: Callable[[np.ndarray, np.ndarray], float] | None = None) -> None:
        self.iteration_limit = iteration_limit
        self.stall_iterations = int(stall_iterations)
        self.stall_rtol = float(stall_rtol)
        self.dual_residual = dual_residual
        self.cut = ""
        self._n = 0
        self._f = float("nan")
        self._viol = float("nan")
        self._du = float("nan")
        self._last_move = 0

    def __call__(self, f: float, g: np.ndarray, x: np.ndarray | None = None, lam_g: np.ndarray | None = None) -> bool:
        """Record iterate number ``self._n`` (0 = the starting point); True: stop the solve."""
        k = self._n
        self._n += 1
        viol = float(np.max(np.abs(g))) if g.size else 0.0
        moved = k == 0 or abs(f - self._f) > self.stall_rtol * abs(self._f) or _changed(viol, self._viol, 10.0)
        if not moved and self.stall_iterations and self.dual_residual is not None and x is not None:
            du = self.dual_residual(x, lam_g if lam_g is not None else np.zeros(g.size))
            if not np.isfinite(self._du) or _changed(du, self._du, 2.0):
                self._du, moved = du, True
        if moved:  # the reference values: the iterate of the last movement
            self._last_move, self._f, self._viol = k, f, viol
        if self.iteration_limit is not None and k >= self.iteration_limit:
            self.cut = "Iteration_Budget"
        elif self.stall_iterations and k - self._last_move >= self.stall_iterations:
            self.cut = "Stalled"
        return bool(self.cut)


@register_solver("ipopt", IpoptSettings)
class IpoptSolver:
    """One ``nlpsol('ipopt')`` object serving every step of a run.

    Parameters
    ----------
    evaluator : StepEvaluator
        Supplies ``f``/``g`` expressions and the assembled ``grad_f``, ``jac_c`` and
        ``hess_lag`` functions, passed to IPOPT directly (no global AD); IPOPT's constraints are
        ``c = [g; h]``, the inner constraint and the outer ones.
    settings : IpoptSettings
        IPOPT options (``tol``, ``max_iter``, ``mu_strategy`` ...), merged over
        :data:`IPOPT_DEFAULTS`. ``warm_start=True`` passes the previous multipliers and sets
        ``warm_start_init_point``.

    Attributes
    ----------
    should_stop : callable () -> bool
        Polled once per IPOPT iteration; True ends the solve at once (``User_Requested_Stop``).
        The flow sets it (:attr:`willmore_nlp.flow.WillmoreFlow.stop_requested`).
    iteration_limit : int or None
        Iteration budget of the next solve (:class:`SolveMonitor`); the flow sets it per attempt.
        A solve cut by it ends with status ``"Iteration_Budget"`` (not converged).
    stall_iterations : int
        Stall test of every solve (:class:`SolveMonitor`); a solve cut by it ends with status
        ``"Stalled"``. 0 (the solver's default) turns it off; the flow sets its own option
        (default 15).
    length : float
        The unit of length of the solves (default 1): the NLP is solved in z / length, with its objective and
        constraints divided by the powers of ``length`` they scale with (:meth:`_scaled_solver`); the flow sets
        :func:`length_unit` of its initial mesh.
    """

    name = "ipopt"

    def __init__(self, evaluator: StepEvaluator, settings: IpoptSettings) -> None:
        opts = {**IPOPT_DEFAULTS, **dict(settings.ipopt)}
        if settings.ipopt and _refused(tuple(sorted(opts.items()))):  # (before a run directory is written)
            raise UserInputError(f"IPOPT refused the options {dict(settings.ipopt)} (linear_solver = "
                                 f"{opts['linear_solver']!r} not in this build?)")
        self.warm_start = settings.warm_start
        if self.warm_start:
            opts["warm_start_init_point"] = "yes"
        self.options = opts
        self.should_stop: Callable[[], bool] = _never
        self.iteration_limit: int | None = None
        self.stall_iterations = 0
        self._monitor = SolveMonitor()
        self._interrupted: list[int] = []  # Ctrl-C signals during the solve under way (:meth:`_ctrl_c`)
        self._evaluator = evaluator
        self._p = np.zeros(0)
        self._hook: _StopHook | None = None
        self._solver: ca.Function | None = None  # the step's NLP (built on first need: :meth:`_plain_solver`)
        self._scaled: ca.Function | None = None  # the same NLP in a unit of length (built on first need)
        self._unit = (1.0, 1.0, 1.0)  # (L, a, b) of the solve under way: z = L z', f' = a f, c' = b c
        self.length = 1.0
        self.ng = evaluator.problem.nc

    def build(self) -> None:
        """Build the step's NLP now rather than at the first solve (a benchmark counts it in the build time)."""
        self._plain_solver()

    def _plain_solver(self) -> ca.Function:
        """The step's NLP, built at the first solve: the step problem's CasADi functions that it needs cost 0.5 s at
        2,562 vertices, and a relaxation by Newton steps on normal motions (``relax_newton``) rebuilds the problem
        after every change of the mesh without solving it."""
        if self._solver is None:
            fn = self._evaluator.fn
            nlp = {"x": fn["z"], "p": fn["p"], "f": fn["f_expr"], "g": fn["g_expr"]}
            self._solver = ca.nlpsol("willmore_step", "ipopt", nlp, self._nlpsol_options(
                fn["grad_f"], fn["jac_c"], fn["hess_lag"]))
        return self._solver

    def _nlpsol_options(self, grad_f: ca.Function, jac_g: ca.Function, hess_lag: ca.Function) -> dict[str, Any]:
        if self._hook is None:
            fn = self._evaluator.fn
            self._hook = _StopHook(fn["z"].numel(), fn["g_expr"].numel(), self._poll)
        return {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag, "print_time": False, "record_time": True,
                "error_on_fail": False, "iteration_callback": self._hook, "ipopt": self.options}

    def _scaled_solver(self) -> ca.Function:
        """The step's NLP in the unit of length L = :attr:`length`: unknowns z' = z / L, objective a f and
        constraints b c with a = L^-(d+2) and b = L^-(d+1), the degrees of the step's objective (tau / tt^2 |Y - X|^2_M,
        |X - X^k|^2_M, 2 tau W, with tau ~ L^4 and tt ~ L^2) and of its inner constraint dE/dY in the length (outer
        constraints take b too: exact for a volume, one power of L apart for an area). The parameters carry (L, a, b)
        after the step's own. Its multipliers are lam' = a lam / b."""
        if self._scaled is None:
            fn = self._evaluator.fn
            z, p = fn["z"], fn["p"]
            zs, lam_f, lam_c = ca.MX.sym("zs", z.numel()), ca.MX.sym("lam_f"), ca.MX.sym("lam_c", self.ng)
            L, a, b = ca.MX.sym("L"), ca.MX.sym("a"), ca.MX.sym("b")
            ps = ca.vertcat(p, L, a, b)
            f, grad = fn["grad_f"](L * zs, p)
            c, J = fn["jac_c"](L * zs, p)
            H = fn["hess_lag"](L * zs, p, a * lam_f, b * lam_c)
            io = ["x", "p"]
            grad_f = ca.Function("nlp_grad_f", [zs, ps], [a * f, (a * L) * grad], io, ["f", "grad"])
            jac_g = ca.Function("nlp_jac_c", [zs, ps], [b * c, (b * L) * J], io, ["g", "jac"])
            hess = ca.Function("nlp_hess_l", [zs, ps, lam_f, lam_c], [(L * L) * H],
                               ["x", "p", "lam_f", "lam_g"], ["hess"])
            fc = ca.Function("nlp_fc", [z, p], [fn["f_expr"], fn["g_expr"]])(L * zs, p)
            nlp = {"x": zs, "p": ps, "f": a * fc[0], "g": b * fc[1]}
            self._scaled = ca.nlpsol("willmore_step_scaled", "ipopt", nlp, self._nlpsol_options(grad_f, jac_g, hess))
        return self._scaled

    def _poll(self, f: float, g: np.ndarray, x: np.ndarray, lam_g: np.ndarray) -> bool:
        """The hook's test: a requested stop (signal) first, then the budget and stall test (on the step's own
        unknowns and multipliers: the scaled solve's are z / L and a lam / b)."""
        L, a, b = self._unit
        return bool(self._interrupted) or bool(self.should_stop()) or self._monitor(f, g, L * x, b / a * lam_g)

    def _dual_residual(self, x: np.ndarray, lam_g: np.ndarray) -> float:
        """max |grad f + J_g^T lam_g| at ``x`` with the parameters of the solve under way."""
        ev = self._evaluator
        return float(np.max(np.abs(ev.grad_f(x, self._p) + ev.c_jac(x, self._p)[1].T @ lam_g)))

    @contextmanager
    def _ctrl_c(self) -> Iterator[None]:
        """Ctrl-C during a solve in a Python session raises KeyboardInterrupt when the solve has stopped.

        Python's own SIGINT handler raises KeyboardInterrupt inside IPOPT's callbacks, which CasADi catches: the
        solve ended "NonIpopt_Exception_Thrown", the flow retried the step at tau / 2 and the run went on, changed
        (a user's 642-vertex run: t = 1.424 instead of 1.519 at step 8, positions 0.38 h apart). While the default
        handler is installed (not under the command line's runner, whose handler asks :attr:`should_stop`), a
        signal is recorded, stops the solve at its next iteration and is raised as KeyboardInterrupt after it; the
        step is abandoned, the flow stays at its last accepted state and continues from it as if uninterrupted.
        """
        if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            yield
            return
        with signals_deferred((signal.SIGINT,)) as noted:  # (raised again after the block: KeyboardInterrupt)
            self._interrupted = noted
            try:
                yield
            finally:
                self._interrupted = []

    def solve(self, z0: np.ndarray, p: np.ndarray, lam_g0: np.ndarray | None = None) -> SolveResult:
        """Solve from ``z0``; ``lam_g0`` is used when warm starting.

        The status is IPOPT's, except ``"Iteration_Budget"`` or ``"Stalled"`` when the
        :class:`SolveMonitor` cut the solve (a stop by :attr:`should_stop` keeps IPOPT's
        ``User_Requested_Stop``).
        """
        self._p = p
        self._monitor = SolveMonitor(self.iteration_limit, self.stall_iterations, dual_residual=self._dual_residual)
        P = self._evaluator.problem
        L = self.length
        a, b = L ** -(P.d + 2), L ** -(P.d + 1)
        self._unit = (L, a, b)
        solver = self._plain_solver() if L == 1 else self._scaled_solver()
        args: dict[str, Any] = {"x0": z0 / L, "p": p if L == 1 else np.concatenate([p, [L, a, b]]),
                                "lbg": 0.0, "ubg": 0.0}
        if self.warm_start and lam_g0 is not None:
            args["lam_g0"] = a / b * lam_g0
        with self._ctrl_c():
            r = solver(**args)
        st = solver.stats()
        status = self._monitor.cut or str(st.get("return_status", "unknown"))
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
        z = L * np.asarray(r["x"]).ravel()
        f = float(r["f"]) / a
        converged = bool(st.get("success", False)) and status == "Solve_Succeeded" and np.all(np.isfinite(z))
        return SolveResult(
            z=z,
            f=f,
            lam_g=b / a * np.asarray(r["lam_g"]).ravel(),
            converged=converged,
            status=status,
            iterations=int(st.get("iter_count", 0)),
            stats=stats,
        )

