"""Run configuration: a problem name or a TOML file, plus ``key=value`` overrides.

A TOML file is flat: ``problem = "NAME"`` (a registered problem) or ``mesh = "FILE"``
(shorthand for problem ``file`` with ``path = FILE``, relative to the TOML file), then
any parameter of that problem, flow options (:data:`FLOW_KEYS`), run length (``steps``,
``t_end``) and IPOPT options in an ``[ipopt]`` table or as ``ipopt.NAME`` keys.
Unknown keys are errors, so a typo is never silently ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from willmore_nlp import registry
from willmore_nlp.registry import Problem, ProblemError, coerce

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
}
"""Flow and solver options accepted in configs, with their defaults."""

RUN_KEYS: dict[str, Any] = {"steps": None, "t_end": None}


class ConfigError(ValueError):
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
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: no such config file") from exc
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
    else:
        base = {"problem": target}
        where = source
    name = str(base.pop("problem"))
    merged: dict[str, tuple[Any, str]] = {k: (v, where) for k, v in base.items()}
    merged.update({k: (v, source) for k, v in overrides.items()})
    try:
        entry = registry.get(name)
    except ProblemError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    fparams = entry.defaults()
    factory_kw: dict[str, Any] = {}
    flow: dict[str, Any] = {}
    run: dict[str, Any] = {}
    for k, (v, src) in merged.items():
        if k in fparams:
            factory_kw[k] = v
        elif k in FLOW_KEYS:
            flow[k] = coerce(v, FLOW_KEYS[k], k) if FLOW_KEYS[k] is not None else _auto(v)
        elif k in RUN_KEYS:
            run[k] = _auto(v)
        elif k.startswith("ipopt."):
            flow[k] = _auto(v)
        else:
            known = sorted({*fparams, *FLOW_KEYS, *RUN_KEYS})
            raise ConfigError(f"{src}: unknown key {k!r} for problem {name!r}; known keys: {', '.join(known)}")
    for k in ("steps", "t_end"):
        if k in fparams and k in factory_kw:
            run.setdefault(k, _auto(factory_kw[k]))
    try:
        problem, resolved = registry.build(name, **factory_kw)
    except ProblemError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    steps = run.get("steps", problem.steps)
    t_end = run.get("t_end", problem.t_end)
    if steps is not None and t_end is not None and "steps" in run and "t_end" not in run:
        t_end = None
    if t_end is not None and steps is not None and "t_end" in run and "steps" not in run:
        steps = None
    return RunSpec(name, problem, resolved, flow, None if steps is None else int(steps),
                   None if t_end is None else float(t_end))


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
