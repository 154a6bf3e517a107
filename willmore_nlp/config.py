"""Run configuration: a problem name or a TOML file, plus ``key=value`` overrides.

A TOML file is flat: ``problem = "NAME"`` (a registered problem) or ``mesh = "FILE"``
(shorthand for problem ``file`` with ``path = FILE``, relative to the TOML file), then
any parameter of that problem, flow options (:data:`FLOW_KEYS`), run length (``steps``,
``t_end``) and IPOPT options in an ``[ipopt]`` table or as ``ipopt.NAME`` keys.
A run target may also be a mesh file itself (:data:`MESH_SUFFIXES`).
Unknown keys are errors, so a typo is never silently ignored, and values are range-checked
(:func:`check_spec`) with messages naming the file or ``--set`` that gave them.
"""

from __future__ import annotations

import difflib
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the same parser as the package tomli
    import tomli as tomllib

from willmore_nlp import registry
from willmore_nlp.errors import UserInputError
from willmore_nlp.mesh.core import MeshError
from willmore_nlp.registry import Problem, ProblemError, coerce
from willmore_nlp.tangential import CONTROL_METHODS, DEFAULT_CONTROL_WEIGHT

FLOW_KEYS: dict[str, Any] = {
    "solver": "ipopt",
    "codegen": None,
    "max_retries": 4,
    "check_energy": True,
    "min_angle": 0.5,
    "max_edge_ratio": 1e3,
    "energy_rtol": 1e-8,
    "tol": 1e-9,
    "max_iter": 200,
    "warm_start": False,
    "allow_components": False,
    "anisotropy": None,
    "tangential_weight": 1.0,
    "c0": 0.0,
    "volume": None,
    "area": None,
    "tangential_control": "off",
    "tangential_control_weight": DEFAULT_CONTROL_WEIGHT,
    "tangential_control_time": 0.0,
    "redistribute": False,
    "adaptive": False,
    "min_tau": None,
    "iteration_budget": 2.0,
    "iteration_budget_min": 30,
    "stall_iterations": 15,
    "relax": False,
    "relax_tol": 1e-4,
    "relax_max_tau": None,
    "mesh_control": "auto",
    "remesh": "auto",
    "remesh_min_angle": 15.0,
    "remesh_max_edge_ratio": 10.0,
    "remesh_target": None,
    "remesh_relax": 2,
}
"""Flow and solver options accepted in configs, with their defaults."""

RUN_KEYS: dict[str, Any] = {"steps": None, "t_end": None}

MESH_SUFFIXES = (".obj", ".off", ".ply", ".stl", ".npz", ".txt", ".curve", ".xy", ".xyz")
"""A run target with one of these suffixes is a mesh file: problem ``file`` with ``path = TARGET``."""


MAX_TOML_BYTES = 1_000_000
"""Larger .toml files are refused before they are read (a config is a few lines)."""


class ConfigError(UserInputError):
    """A configuration file or override is invalid; the message names the file and key."""


@dataclass
class RunSpec:
    """Everything needed to start a run."""

    problem_name: str
    problem: Problem
    params: dict[str, Any]
    flow_options: dict[str, Any] = field(default_factory=dict)
    steps: int | None = None
    t_end: float | None = None

    def config(self) -> dict[str, Any]:
        """JSON-able resolved configuration."""
        import casadi
        import numpy

        from willmore_nlp import __version__

        return {
            "problem": self.problem_name,
            "params": self.params,
            "tau": self.problem.tau,
            "tau_tilde": self.problem.tau_tilde,
            "lam": self.problem.lam,
            "flow_options": self.flow_options,
            "effective_flow_options": {**self.problem.flow_options, **self.flow_options},
            "steps": self.steps,
            "t_end": self.t_end,
            "mesh": {"n_vertices": self.problem.mesh.n_vertices, "n_simplices": self.problem.mesh.n_simplices,
                     "d": self.problem.mesh.d, "m": self.problem.mesh.m, "h": self.problem.mesh.h},
            "versions": {"willmore_nlp": __version__, "casadi": casadi.__version__, "numpy": numpy.__version__},
        }


def parse_overrides(items: list[str]) -> dict[str, str]:
    """``["a=1", "b=x"]`` -> ``{"a": "1", "b": "x"}``; malformed items are errors."""
    out: dict[str, str] = {}
    for it in items:
        if "=" not in it:
            raise ConfigError(f"--set {it!r}: expected key=value")
        k, v = it.split("=", 1)
        k = k.strip()
        if not k:
            raise ConfigError(f"--set {it!r}: empty key")
        out[k] = v.strip()
    return out


def read_toml(path: Path) -> dict[str, Any]:
    """Read a TOML config and flatten ``[ipopt]`` into ``ipopt.KEY`` entries."""
    if path.is_file() and path.stat().st_size > MAX_TOML_BYTES:
        raise ConfigError(f"{path}: {path.stat().st_size / 1e6:.3g} MB is not a config file (the limit is "
                          f"{MAX_TOML_BYTES / 1e6:g} MB; meshes go in their own file: mesh = \"FILE\")")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # -sig: a BOM (Windows editors) is dropped
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: no such config file") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from exc
    flat: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, dict):
            if k != "ipopt":
                raise ConfigError(f"{path}: unknown table [{k}] (only [ipopt] is allowed)")
            flat.update({f"ipopt.{kk}": vv for kk, vv in v.items()})
        else:
            flat[k] = v
    if "mesh" in flat:
        if "problem" in flat:
            raise ConfigError(f"{path}: give either 'problem' or 'mesh', not both")
        mesh_path = Path(str(flat.pop("mesh")))
        flat["problem"] = "file"
        flat["path"] = str(mesh_path if mesh_path.is_absolute() else (path.parent / mesh_path))
    if "problem" not in flat:
        raise ConfigError(f"{path}: missing 'problem = NAME' or 'mesh = FILE'")
    return flat


def resolve(target: str, overrides: dict[str, Any] | None = None, *, source: str = "--set") -> RunSpec:
    """Resolve a problem name or TOML path plus overrides into a :class:`RunSpec`."""
    overrides = dict(overrides or {})
    if target.endswith(".toml"):
        path = Path(target)
        base = read_toml(path)
        where = str(path)
    elif Path(target).suffix.lower() in MESH_SUFFIXES:
        base = {"problem": "file", "path": target}
        where = target
    else:
        base = {"problem": target}
        where = source
    name = str(base.pop("problem"))
    merged: dict[str, tuple[Any, str]] = {k: (v, where) for k, v in base.items()}
    merged.update({k: (v, source) for k, v in overrides.items()})
    try:
        entry = registry.get(name)
    except ProblemError as exc:
        raise ConfigError(f"{where}: {exc}" if target.endswith(".toml") else str(exc)) from exc
    fparams = entry.defaults()
    factory_kw: dict[str, Any] = {}
    flow: dict[str, Any] = {}
    run: dict[str, Any] = {}
    for k, (v, src) in merged.items():
        if k in fparams:
            factory_kw[k] = v
        elif k in FLOW_KEYS:
            try:
                flow[k] = coerce_flow_option(k, v)
            except ProblemError as exc:
                raise ConfigError(f"{src}: {exc}") from exc
        elif k in RUN_KEYS:
            run[k] = _auto(v)
        elif k.startswith("ipopt."):
            flow[k] = _auto(v)
        else:
            known = sorted({*fparams, *FLOW_KEYS, *RUN_KEYS})
            close = difflib.get_close_matches(k, known, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ConfigError(f"{src}: unknown key {k!r} for problem {name!r}; {hint}known keys: {', '.join(known)}")
    for k in ("steps", "t_end"):
        if k in fparams and k in factory_kw:
            run.setdefault(k, _auto(factory_kw[k]))
    _check_types(merged, fparams, name)
    try:
        problem, resolved = registry.build(name, **factory_kw)
    except ProblemError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    except MeshError:
        raise
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}: problem {name!r}: {exc}") from exc
    steps = run.get("steps", problem.steps)
    t_end = run.get("t_end", problem.t_end)
    if steps is not None and t_end is not None and "steps" in run and "t_end" not in run:
        t_end = None
    if t_end is not None and steps is not None and "t_end" in run and "steps" not in run:
        steps = None
    spec = RunSpec(name, problem, resolved, flow, steps, t_end)
    check_spec(spec, {k: src for k, (_, src) in merged.items()})
    spec.steps = None if steps is None else int(steps)
    spec.t_end = None if t_end is None else float(t_end)
    return spec


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_types(merged: dict[str, tuple[Any, str]], fparams: dict[str, Any], name: str) -> None:
    """Problem parameters given as a number where the factory expects one (TOML values are not coerced)."""
    for k, (v, src) in merged.items():
        if k not in fparams:
            continue
        num = _auto(v) if isinstance(v, str) else v
        if k in ("tau", "tau_tilde", "lam", "steps", "t_end") and v is not None and not _is_number(num):
            raise ConfigError(f"{src}: {k} must be a number, got {v!r}")
        if isinstance(v, str):
            continue
        d = fparams[k]
        if isinstance(d, bool) and not isinstance(v, bool):
            raise ConfigError(f"{src}: {k} must be true or false, got {v!r}")
        if isinstance(d, int) and not isinstance(d, bool) and not (
                _is_number(v) and float(v).is_integer()):
            raise ConfigError(f"{src}: {k} must be an integer, got {v!r}")
        if isinstance(d, float) and not _is_number(v):
            raise ConfigError(f"{src}: {k} must be a number, got {v!r}")


RANGES: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "tau": ("a number > 0", lambda v: _is_number(v) and math.isfinite(v) and v > 0),
    "tau_tilde": ("a number > 0", lambda v: _is_number(v) and math.isfinite(v) and v > 0),
    "lam": ("a number >= 0", lambda v: _is_number(v) and math.isfinite(v) and v >= 0),
    "steps": ("an integer >= 1", lambda v: _is_number(v) and float(v).is_integer() and v >= 1),
    "t_end": ("a number > 0", lambda v: _is_number(v) and math.isfinite(v) and v > 0),
    "max_retries": ("an integer >= 0", lambda v: _is_number(v) and float(v).is_integer() and v >= 0),
    "check_energy": ("true or false", lambda v: isinstance(v, bool)),
    "warm_start": ("true or false", lambda v: isinstance(v, bool)),
    "allow_components": ("true or false", lambda v: isinstance(v, bool)),
    "codegen": ("true, false or unset", lambda v: v is None or isinstance(v, bool)),
    "min_angle": ("a number in [0, 60)", lambda v: _is_number(v) and 0 <= v < 60),
    "max_edge_ratio": ("a number >= 1", lambda v: _is_number(v) and v >= 1),
    "energy_rtol": ("a number >= 0", lambda v: _is_number(v) and math.isfinite(v) and v >= 0),
    "tol": ("a number > 0", lambda v: _is_number(v) and math.isfinite(v) and v > 0),
    "max_iter": ("an integer >= 0", lambda v: _is_number(v) and float(v).is_integer() and v >= 0),
    "min_tau": ("a number >= 0 or unset (0.01 h^4)", lambda v: v is None or (_is_number(v) and math.isfinite(v)
                                                                            and v >= 0)),
    "iteration_budget": ("a number >= 0 (0: no budget)", lambda v: _is_number(v) and math.isfinite(v) and v >= 0),
    "iteration_budget_min": ("an integer >= 1", lambda v: _is_number(v) and float(v).is_integer() and v >= 1),
    "stall_iterations": ("an integer >= 0 (0: off)", lambda v: _is_number(v) and float(v).is_integer() and v >= 0),
    "relax": ("true or false", lambda v: isinstance(v, bool)),
    "relax_tol": ("a number >= 0", lambda v: _is_number(v) and math.isfinite(v) and v >= 0),
    "relax_max_tau": ("a number > 0 or unset (100 tau)", lambda v: v is None or (_is_number(v) and math.isfinite(v)
                                                                                and v > 0)),
    "mesh_control": ("'auto' or 'off'", lambda v: v in ("auto", "off")),
    "remesh": ("'auto' or 'off'", lambda v: v in ("auto", "off")),
    "remesh_min_angle": ("a number in [0, 60)", lambda v: _is_number(v) and 0 <= v < 60),
    "remesh_max_edge_ratio": ("a number >= 1", lambda v: _is_number(v) and v >= 1),
    "remesh_target": ("a number > 0 or unset (the initial mean edge)",
                      lambda v: v is None or (_is_number(v) and math.isfinite(v) and v > 0)),
    "remesh_relax": ("an integer >= 0", lambda v: _is_number(v) and float(v).is_integer() and v >= 0),
    "tangential_control": (" or ".join(map(repr, CONTROL_METHODS)), lambda v: v in CONTROL_METHODS),
    "tangential_control_weight": ("a number > 0", lambda v: _is_number(v) and math.isfinite(v) and v > 0),
    "tangential_control_time": ("a number >= 0", lambda v: _is_number(v) and math.isfinite(v) and v >= 0),
    "c0": ("a number", lambda v: _is_number(v) and math.isfinite(v)),
    "volume": ("'initial', a number > 0 or unset", lambda v: v is None or v == "initial" or (
        _is_number(v) and math.isfinite(v) and v > 0)),
    "area": ("'initial', a number > 0 or unset", lambda v: v is None or v == "initial" or (
        _is_number(v) and math.isfinite(v) and v > 0)),
}
"""Allowed values of the numeric and boolean configuration keys: (description, test)."""


def check_spec(spec: RunSpec, sources: dict[str, str] | None = None) -> None:
    """Reject out-of-range step sizes, run lengths, flow options and IPOPT options.

    Parameters
    ----------
    spec : RunSpec
    sources : dict, optional
        Where each key was given (a file or ``--set``), named in the message; keys not
        given come from the problem's defaults.

    Raises
    ------
    ConfigError
        Naming the source, the key, the allowed range and the value.
    """
    sources = sources or {}
    pb = spec.problem
    values: dict[str, Any] = {"tau": pb.tau, "tau_tilde": pb.tau_tilde, "lam": pb.lam}
    if spec.steps is not None:
        values["steps"] = spec.steps
    if spec.t_end is not None:
        values["t_end"] = spec.t_end
    values.update({k: v for k, v in spec.flow_options.items() if not k.startswith("ipopt.")})
    for k, v in values.items():
        if k in RANGES:
            what, ok = RANGES[k]
            if not ok(v):
                src = sources.get(k, f"problem {spec.problem_name!r}")
                raise ConfigError(f"{src}: {k} must be {what}, got {v!r}")
    solver = spec.flow_options.get("solver", pb.flow_options.get("solver", "ipopt"))
    from willmore_nlp.solvers import solver_names

    if solver not in solver_names():
        raise ConfigError(f"{sources.get('solver', 'solver')}: unknown solver {solver!r}; "
                          f"available: {', '.join(solver_names())}")
    if solver == "ipopt":
        opts = {k: v for k, v in spec.flow_options.items() if k.startswith("ipopt.")}
        check_ipopt_options(opts, sources)


def check_ipopt_options(options: dict[str, Any], sources: dict[str, str] | None = None) -> None:
    """Let IPOPT itself check ``{"ipopt.NAME": value}`` options on a one-variable problem.

    Raises
    ------
    ConfigError
        Naming the source and option: unknown options, wrong types, values out of
        IPOPT's range or not among its valid settings, unavailable linear solvers.
    """
    if not options:
        return
    sources = sources or {}
    if _ipopt_problem(dict(options)) is None:
        return
    for key, val in options.items():
        err = _ipopt_problem({key: val})
        if err is not None:
            name = key.removeprefix("ipopt.")
            raise ConfigError(f"{sources.get(key, '--set')}: IPOPT option {name} = {val!r}: {err}")
    raise ConfigError(f"{', '.join(sorted(set(sources.get(k, '--set') for k in options)))}: "
                      f"the IPOPT options {sorted(options)} are rejected together")


def _ipopt_problem(options: dict[str, Any]) -> str | None:
    """None when IPOPT accepts ``options`` on a trivial problem, else what it complained about."""
    import contextlib
    import io
    import os
    import re
    import sys
    import tempfile

    import casadi as ca

    opts = {k.removeprefix("ipopt."): v for k, v in options.items()}
    opts.update({"print_level": 0, "sb": "yes", "max_iter": opts.get("max_iter", 3)})
    x = ca.MX.sym("x")
    py_out = io.StringIO()
    sys.stdout.flush()
    with tempfile.TemporaryFile(mode="w+b") as cap, contextlib.redirect_stdout(py_out):
        saved = os.dup(1)
        try:
            os.dup2(cap.fileno(), 1)  # IPOPT's diagnostics go to CasADi's stream (sys.stdout) or the C stdout
            try:
                s = ca.nlpsol("check_options", "ipopt", {"x": x, "f": x**2},
                              {"ipopt": opts, "print_time": False, "error_on_fail": False})
                s(x0=1.0)
                status = str(s.stats().get("return_status", ""))
                err = None if status != "Invalid_Option" else "not usable in this IPOPT build"
            except RuntimeError as exc:
                err = str(exc).strip().splitlines()[-1]
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        cap.seek(0)
        out = cap.read().decode("utf-8", "replace") + py_out.getvalue()
    if err is None:
        return None
    m = re.search(r"No such IPOPT option: (\S+)", err)
    if m:
        return "unknown option"
    if "type mismatch" in err:
        return "wrong type"
    detail = [ln.strip() for ln in out.splitlines() if "is not a valid setting" in ln]
    rng = [ln.strip() for ln in out.splitlines() if re.match(r"^\s*[-+0-9.e]+ <=? \(", ln)
           or re.match(r"^-inf <", ln.strip())]
    valid = [ln.strip().split(" ", 1)[0] for ln in out.splitlines() if ln.startswith("\t")]
    msg = "not a valid setting" if detail else err
    if rng:
        msg += f" (range: {re.sub(r'[(][^)]*[)]', 'value', rng[0])})"
    elif valid:
        msg += f" (valid: {', '.join(valid)})"
    return msg


def coerce_flow_option(key: str, value: Any) -> Any:
    """A flow option from a string override, typed like its default in :data:`FLOW_KEYS`.

    Raises
    ------
    ProblemError
        When the value cannot be read as the option's type.
    """
    default = FLOW_KEYS[key]
    return coerce(value, default, key) if default is not None else _auto(value)


def _auto(v: Any) -> Any:
    """Parse a string override as bool/int/float when it looks like one."""
    if not isinstance(v, str):
        return v
    low = v.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            continue
    return v
