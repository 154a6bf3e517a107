"""Run configuration: a problem name or a TOML file, plus ``key=value`` overrides.

A TOML file is flat: ``problem = "NAME"`` (a registered problem) or ``mesh = "FILE"``
(shorthand for problem ``file`` with ``path = FILE``, relative to the TOML file), then
any parameter of that problem, flow options (:class:`~willmore_nlp.settings.FlowSettings`), solver
options (:func:`solver_keys`), run length (``steps``, ``t_end``) and IPOPT options in an ``[ipopt]``
table or as ``ipopt.NAME`` keys: IPOPT's, whether it is the ``solver``, ``first_step_solver``, ``fallback_solver``
or ``large_solver`` (:func:`~willmore_nlp.settings.solver_of`).
A run target may also be a mesh file itself (:data:`MESH_SUFFIXES`).
Unknown keys are errors, so a typo is never silently ignored, and values are checked by the
settings (:func:`check_spec`) with messages naming the file or ``--set`` that gave them.
"""

from __future__ import annotations

import difflib
import sys
from collections.abc import Mapping
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
from willmore_nlp.settings import FlowSettings, auto, check_run_value, flow_solvers, solver_of
from willmore_nlp.solvers import solver_names, solver_settings

FLOW_KEYS: dict[str, Any] = FlowSettings.defaults()
"""Flow options accepted in configs, with their defaults (the fields of :class:`FlowSettings`)."""


def solver_keys() -> set[str]:
    """The solver options that configs take (``ipopt.NAME`` aside): those of every registered solver."""
    return {k for name in solver_names() for k in solver_settings(name).config_keys()}


RUN_KEYS: dict[str, Any] = {"steps": None, "t_end": None}

MESH_SUFFIXES = (".obj", ".off", ".ply", ".stl", ".npz", ".txt", ".curve", ".xy", ".xyz")
"""A run target with one of these suffixes is a mesh file: problem ``file`` with ``path = TARGET``."""


MAX_TOML_BYTES = 1_000_000
"""Larger .toml files are refused before they are read (a config is a few lines)."""

RELAX_RUN_STEPS = 300
"""Length of a run given ``relax = true`` but neither ``steps`` nor ``t_end``, for a problem that is not itself a
relaxation (the vesicle problem's 300): the relaxation ends the run when it is relaxed, and the problem's trajectory
length would end it on the way (the file problem's 10 steps: a new user's trimesh torus of R 1, r 0.3 stopped at step
10 "completed", where its relaxation by time steps takes 64 steps)."""


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
            "effective_flow_options": self.problem.effective_options(self.flow_options),
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
        if "path" in flat:
            raise ConfigError(f"{path}: give either 'mesh' or 'path', not both")
        mesh_path = Path(str(flat.pop("mesh")))
        flat["problem"] = "file"
        flat["path"] = str(mesh_path if mesh_path.is_absolute() else (path.parent / mesh_path))
    if "problem" not in flat:
        raise ConfigError(f"{path}: missing 'problem = NAME' or 'mesh = FILE'")
    return flat


def mesh_file_settings(target: str, overrides: Mapping[str, Any], source: str = "--set") -> dict[str, Any]:
    """The file problem's ``path`` for a mesh file named as the target of ``run`` or ``compare``; refused when the
    ``overrides`` (from ``source``) give a path too."""
    if "path" in overrides:
        raise ConfigError(f"{target}: the mesh is given twice, as the target and as {source} path="
                          f"{overrides['path']}: give one")
    return {"path": target}


def resolve(target: str, overrides: dict[str, Any] | None = None, *, source: str = "--set") -> RunSpec:
    """Resolve a problem name or TOML path plus overrides into a :class:`RunSpec`."""
    overrides = dict(overrides or {})
    if target.endswith(".toml"):
        path = Path(target)
        base = read_toml(path)
        where = str(path)
    elif Path(target).suffix.lower() in MESH_SUFFIXES:
        base = {"problem": "file", **mesh_file_settings(target, overrides, source)}
        where = target
    else:
        base = {"problem": target}
        where = source
    name = str(base.pop("problem"))
    old = FlowSettings.renamed
    merged: dict[str, tuple[Any, str]] = {old.get(k, k): (v, where) for k, v in base.items()}
    merged.update({old.get(k, k): (v, source) for k, v in overrides.items()})
    try:
        entry = registry.get(name)
    except ProblemError as exc:
        if not target.endswith(".toml") and ("/" in target or Path(target).suffix):  # a path, not a name
            kind = "no such file" if not Path(target).exists() else "not a supported mesh or config format"
            raise ConfigError(f"{target}: {kind} (meshes: {', '.join(sorted(MESH_SUFFIXES))}; configs: .toml; "
                              f"or a problem name, see 'willmore-nlp problems')") from exc
        raise ConfigError(f"{where}: {exc}" if target.endswith(".toml") else str(exc)) from exc
    fparams = entry.defaults()
    factory_kw: dict[str, Any] = {}
    flow: dict[str, Any] = {}
    run: dict[str, Any] = {}
    solver_opts = solver_keys()
    for k, (v, src) in merged.items():
        if k in fparams:
            try:
                factory_kw[k] = coerce(v, fparams[k], k)
            except ProblemError as exc:
                raise ConfigError(f"{src}: {exc}") from exc
        elif k in FLOW_KEYS:
            try:
                flow[k] = FlowSettings.parse(k, v)
            except UserInputError as exc:
                raise ConfigError(f"{src}: {exc}") from exc
        elif k in RUN_KEYS:
            run[k] = auto(v)
        elif k.startswith("ipopt.") or k in solver_opts:
            flow[k] = auto(v)
        else:
            known = sorted({*fparams, *FLOW_KEYS, *RUN_KEYS, *solver_opts})
            close = difflib.get_close_matches(k, known, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ConfigError(f"{src}: unknown key {k!r} for problem {name!r}; {hint}known keys: {', '.join(known)}")
    for k in ("steps", "t_end"):
        if k in fparams and k in factory_kw:
            run.setdefault(k, factory_kw[k])
    try:
        problem, resolved = registry.build(name, **factory_kw)
    except ProblemError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    except MeshError:
        raise
    except UserInputError as exc:  # (not any ValueError: a bug in a problem is a bug, with its traceback)
        raise ConfigError(f"{where}: problem {name!r}: {exc}") from exc
    steps = run.get("steps", problem.steps)
    t_end = run.get("t_end", problem.t_end)
    if steps is not None and t_end is not None and "steps" in run and "t_end" not in run:
        t_end = None
    if t_end is not None and steps is not None and "t_end" in run and "steps" not in run:
        steps = None
    if flow.get("relax") is True and not problem.flow_options.get("relax") and not {"steps", "t_end"} & run.keys():
        steps, t_end = max(int(steps or 0), RELAX_RUN_STEPS), None
    spec = RunSpec(name, problem, resolved, flow, steps, t_end)
    check_spec(spec, {k: src for k, (_, src) in merged.items()})
    spec.steps = None if steps is None else int(steps)
    spec.t_end = None if t_end is None else float(t_end)
    return spec


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

    def fail(key: str, exc: UserInputError) -> ConfigError:
        return ConfigError(f"{sources.get(key, f'problem {spec.problem_name!r}')}: {exc}")

    run = {"tau": pb.tau, "tau_tilde": pb.tau_tilde, "lam": pb.lam, "steps": spec.steps, "t_end": spec.t_end}
    flow, solver_opts = FlowSettings.split(spec.flow_options)
    for k, v in [*((k, v) for k, v in run.items() if v is not None), *flow.items()]:
        try:
            FlowSettings.check(k, v) if k in flow else check_run_value(k, v)
        except UserInputError as exc:
            raise fail(k, exc) from exc
    roles = pb.effective_options(spec.flow_options)  # (the problem's solvers, e.g. the file problem's fallback)
    for role, name in flow_solvers(roles).items():
        if name:
            try:
                solver_settings(name)
            except UserInputError as exc:
                raise ConfigError(f"{sources.get(role, role)}: {exc}") from exc
    for k, v in solver_opts.items():
        try:
            solver_settings(solver_of(k, roles)[0]).from_options({k: v})
        except UserInputError as exc:
            raise ConfigError(f"{sources.get(k, '--set')}: {exc}") from exc


def parse_option(key: str, value: Any) -> Any:
    """A flow or solver option from a string override (flow options validated)."""
    return FlowSettings.parse(key, value) if key in FLOW_KEYS else auto(value)
