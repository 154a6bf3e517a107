"""Registry of named problems (the paper's scenarios and more).

A problem factory is a function with keyword parameters (all with defaults) returning a
:class:`Problem`. Factories are registered with :func:`register` from the modules of the
repository's top-level ``problems/`` folder, which :func:`load_all` imports under the private name
:data:`PACKAGE` (``willmore_nlp._problems.closed`` ...), never as a top-level ``problems``: a user's
own ``problems`` package neither shadows ours nor is shadowed by it.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import math
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.settings import RUN_KINDS, auto, is_number, moebius_invariant, parse_bool

if TYPE_CHECKING:
    from willmore_nlp.flow import WillmoreFlow

LARGE_SURFACE = 10_000
"""Surfaces of at least this many vertices flow with ``solver = "newton-krylov"`` and ``fallback_solver = "ipopt"``
when the problem and the user name no solver (:meth:`Problem.effective_options`): above every size of the paper's
reproduction (at most 4,608 vertices, whose reference solver stays IPOPT), where IPOPT's step costs 8-9x
newton-krylov's on the benchmark spheres and a 10,242-vertex ellipsoid's 10 steps took 1,288 s against 166 s
(docs/guide/performance.md). The ``file`` problem chooses the same from 500 vertices (its own measurements)."""


class ProblemError(UserInputError):
    """Unknown problem or parameter, or a parameter of the wrong type."""


@dataclass
class Problem:
    """A fully specified flow: initial mesh, step sizes, run length and flow options.

    Attributes
    ----------
    mesh : initial Mesh
    tau, tau_tilde, lam : step sizes and length/area energy weight
    steps, t_end : default run length (either may be None)
    flow_options : further keyword arguments of :class:`~willmore_nlp.WillmoreFlow`
    description : one line shown by ``willmore-nlp problems``
    held : flow options the problem defines through its parameters, which overrides may not replace (option ->
        the parameter to set instead; the ``vesicle`` problem's ``volume`` and ``area``: ``reduced_volume``)
    """

    mesh: Mesh
    tau: float
    tau_tilde: float
    lam: float = 0.0
    steps: int | None = None
    t_end: float | None = None
    flow_options: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    held: dict[str, str] = field(default_factory=dict)

    def make_flow(self, **overrides: Any) -> WillmoreFlow:
        """The problem's :class:`~willmore_nlp.flow.WillmoreFlow`; ``overrides`` (``tau``, flow and solver
        options) replace the problem's values (:meth:`effective_options`)."""
        from willmore_nlp.flow import WillmoreFlow

        kw = {"tau": self.tau, "tau_tilde": self.tau_tilde, "lam": self.lam, **self.effective_options(overrides)}
        return WillmoreFlow(self.mesh, **kw)

    def effective_options(self, overrides: dict[str, Any]) -> dict[str, Any]:
        """The flow options of :meth:`make_flow`: the problem's, replaced by ``overrides``. A ``conformal_gauge`` of
        the problem's own (the ``torus`` problem's, the ``file`` problem's closed surfaces of genus >= 1) gives way
        to a volume or area constraint, an area term ``lam``, a spontaneous curvature ``c0`` or an anisotropy: the
        gauge undoes Moebius motions, which only the unconstrained isotropic Willmore energy leaves free (with the
        others they are the flow's own); only asking for the gauge and a constraint at once is an error. A surface
        of at least :data:`LARGE_SURFACE` vertices whose problem names no solver gets newton-krylov with the IPOPT
        fallback, a smaller one ``large_solver = "newton-krylov"`` from that size (a refinement's steps). A
        ``first_step_solver``, ``fallback_solver`` or ``large_solver`` of the problem's own (the ``file`` problem's
        surfaces) gives way to a ``solver`` among the overrides: ``--set solver=sqp`` runs every step with sqp. A
        ``remesh_target`` of the problem's own (the ``file`` problem's coarse inputs) gives way to ``input_repair =
        false`` among the overrides: ``--set input_repair=false`` flows the input as given, its later remeshings
        toward their default target. A ``relax_max_tau`` of the problem's own is a multiple of its tau (the
        ``vesicle`` problem's 8 tau): a ``tau`` among the overrides scales it (``compare vesicle --taus h`` was refused,
        "relax_max_tau must be a number >= tau", a new-user check)."""
        clash = sorted(set(overrides) & set(self.held))
        if clash:  # (vesicle --set volume=3 ran at v = 0.716 while its record said 0.65: a new-user check)
            raise ProblemError(f"{self.description or 'this problem'}: {', '.join(clash)} is set by the problem's "
                               f"parameters; set {', '.join(sorted({self.held[k] for k in clash}))} instead")
        options = dict(self.flow_options)
        if self.mesh.d == 2 and "solver" not in options and "large_solver" not in options:
            options.update(dict(solver="newton-krylov", fallback_solver="ipopt")
                           if self.mesh.n_vertices >= LARGE_SURFACE
                           else dict(large_solver="newton-krylov", large_vertices=LARGE_SURFACE))
        merged = {"lam": self.lam, **options, **overrides}
        self._refuse_unconstrained_solvers(merged)
        moebius = moebius_invariant(merged["lam"], merged.get("c0", 0.0), merged.get("anisotropy"),
                                    merged.get("volume"), merged.get("area"))
        if not moebius and "conformal_gauge" not in overrides:
            options.pop("conformal_gauge", None)
        for key in ("first_step_solver", "fallback_solver", "large_solver"):
            if "solver" in overrides and key not in overrides:
                options.pop(key, None)
        if overrides.get("input_repair") is False and "remesh_target" not in overrides:
            options.pop("remesh_target", None)
        if "tau" in overrides and "relax_max_tau" in options and "relax_max_tau" not in overrides:
            options["relax_max_tau"] *= float(overrides["tau"]) / self.tau
        return {**options, **overrides}

    def _refuse_unconstrained_solvers(self, merged: dict[str, Any]) -> None:
        """Refuse a solver (or first-step, fallback or large solver) without outer equality constraints when the
        problem holds ``volume`` or ``area`` through its parameters (:attr:`held`): the solver's own refusal ends
        "use volume=None", which the command line cannot give and the problem refuses (``vesicle --set solver=lbfgs``,
        a new-user check); this one names the solvers that can."""
        held = [k for k in ("volume", "area") if k in self.held and merged.get(k) is not None]
        if not held:
            return
        from willmore_nlp.solvers import solver_capabilities, solver_names

        for key in ("solver", "first_step_solver", "fallback_solver", "large_solver"):
            name = merged.get(key, "ipopt" if key == "solver" else "")
            if name and "constraints" not in solver_capabilities(name):
                able = [n for n in solver_names() if "constraints" in solver_capabilities(n)]
                raise ProblemError(f"{self.description or 'this problem'}: {key} {name} cannot handle the problem's "
                                   f"{' and '.join(held)} constraints (set by "
                                   f"{', '.join(sorted({self.held[k] for k in held}))}; it has no outer equality "
                                   f"constraints): use one of {', '.join(able)}")


@dataclass(frozen=True)
class Entry:
    """A registered factory with its name, module and one-line description; ``before``: the values of parameters
    added since, with which a configuration written before them (whose ``params`` list every parameter of its
    time, :func:`build`) ran (:func:`~willmore_nlp.runner.spec_from_config`)."""

    name: str
    factory: Callable[..., Problem]
    module: str
    description: str
    before: dict[str, Any] = field(default_factory=dict)

    def defaults(self) -> dict[str, Any]:
        """The factory's keyword parameters and their defaults."""
        return {
            k: p.default
            for k, p in inspect.signature(self.factory).parameters.items()
            if p.default is not inspect.Parameter.empty
        }


_REGISTRY: dict[str, Entry] = {}


def register(name: str, before: dict[str, Any] | None = None) -> Callable[[Callable[..., Problem]],
                                                                          Callable[..., Problem]]:
    """Decorator registering a problem factory under ``name`` (the docstring's summary, its first paragraph on one
    line, = description; ``before``: :attr:`Entry.before`)."""

    def deco(factory: Callable[..., Problem]) -> Callable[..., Problem]:
        if name in _REGISTRY and _REGISTRY[name].factory is not factory:
            raise ProblemError(f"problem {name!r} is registered twice ({_REGISTRY[name].module}, {factory.__module__})")
        summary = " ".join((inspect.getdoc(factory) or "").strip().split("\n\n")[0].split())
        _REGISTRY[name] = Entry(name, factory, factory.__module__, summary, dict(before or {}))
        return factory

    return deco


PACKAGE = "willmore_nlp._problems"
"""Import name of the ``problems/`` folder (an installed package maps it there: pyproject.toml)."""


def problems_package() -> ModuleType:
    """The ``problems/`` folder as the package :data:`PACKAGE`: installed, or beside ``willmore_nlp/``."""
    try:
        return importlib.import_module(PACKAGE)
    except ModuleNotFoundError as exc:
        if exc.name != PACKAGE:
            raise
    folder = Path(__file__).resolve().parent.parent / "problems"  # a source checkout
    spec = importlib.util.spec_from_file_location(PACKAGE, folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    if spec is None or spec.loader is None:
        raise ImportError(f"{folder}: the problems folder is missing")
    module = sys.modules[PACKAGE] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def problem_module(name: str) -> ModuleType:
    """The module ``problems/NAME.py`` (for its helpers; :func:`get` for the factories)."""
    problems_package()
    return importlib.import_module(f"{PACKAGE}.{name}")


def load_all() -> dict[str, Entry]:
    """Import every module of the ``problems/`` folder and return the registry."""
    for mod in pkgutil.iter_modules(problems_package().__path__):
        problem_module(mod.name)
    return dict(_REGISTRY)


def get(name: str) -> Entry:
    """The registry entry of ``name`` (loading the problems package first)."""
    reg = load_all()
    if name not in reg:
        raise ProblemError(f"unknown problem {name!r}; known: {', '.join(sorted(reg))}")
    return reg[name]


def coerce(value: Any, default: Any, key: str) -> Any:
    """Parameter ``key`` typed like ``default`` (any type when None, except the step sizes and run length,
    :data:`~willmore_nlp.settings.RUN_KINDS`); a string is read.

    Raises
    ------
    ProblemError
        ``KEY must be true or false / an integer / a number, got VALUE``.
    """
    want = type(default) if default is not None else (int if key == "steps" else float) if key in RUN_KINDS else None
    out = value if not isinstance(value, str) or want is str else parse_bool(value) if want is bool else auto(value)
    if want in (None, str) or (want is bool and isinstance(out, bool)) or (value is None and default is None):
        return out
    if want in (int, float) and is_number(out) and math.isfinite(out) and (want is float or float(out).is_integer()):
        return want(out)
    what = {bool: "true or false", int: "an integer", float: "a finite number"}.get(want, f"a {want.__name__}")
    raise ProblemError(f"{key} must be {what}, got {value!r}")


def build(name: str, **params: Any) -> tuple[Problem, dict[str, Any]]:
    """Call the factory of ``name`` with ``params`` (unknown keys are an error).

    Returns
    -------
    problem : Problem
    resolved : dict
        Every factory parameter with the value used.
    """
    entry = get(name)
    resolved = {**entry.defaults(), **check_params(name, params)}
    return entry.factory(**resolved), resolved


def check_params(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """``params`` of problem ``name`` typed like the factory's defaults (unknown keys are an error).

    Raises
    ------
    ProblemError
        Naming the unknown parameter, or the value that cannot be read as its type.
    """
    entry = get(name)
    defaults = entry.defaults()
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise ProblemError(
            f"problem {name!r} has no parameter {unknown[0]!r}; its parameters: {', '.join(sorted(defaults))}"
        )
    return {k: v if v is None and defaults[k] is None else coerce(v, _typed(entry, k, defaults[k]), k)
            for k, v in params.items()}


def _typed(entry: Entry, key: str, default: Any) -> Any:
    """The default of parameter ``key``, or for a default of None a value of the annotated type ("float | None":
    0.0), so that :func:`coerce` reads and checks it (``tangential_weight=zzz`` reached ``float()`` in the factory:
    a new-user check)."""
    if default is not None:
        return default
    ann = inspect.signature(entry.factory).parameters[key].annotation
    first = (ann if isinstance(ann, str) else getattr(ann, "__name__", "")).split("|")[0].strip()
    return {"float": 0.0, "int": 0}.get(first)
