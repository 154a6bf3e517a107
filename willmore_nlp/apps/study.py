"""Solver-comparison studies: a grid of (solver, tau, problem parameters) run on Dask.

``run_study`` submits every case of the grid to a ``dask.distributed`` cluster (a LocalCluster on
this machine by default, or an existing scheduler), each case writing ``cases/<key>.json`` when
it ends (atomically: a crashed worker never leaves a partial file). A failed case is recorded with
its error and does not stop the others; a rerun skips finished cases (same problem, solver, tau, parameters,
options and length: a rerun with another ``--steps`` or ``--t-end`` runs its cases anew). A rerun with another grid
adds its cases to the study (``study.json`` lists the cases of every run). ``write_study`` turns every case file in
``cases/`` into the study's artefacts:

    study.csv      tidy table, one row per case and step (step 0 = initial state)
    summary.md     per-case table and the largest stable tau per solver (and mesh size)
    figures/       energy vs t, iterations and time per step, largest stable tau vs h

Command line: ``willmore-nlp compare PROBLEM --solvers ipopt,lbfgs --taus tau,4tau --steps 10``.
"""

from __future__ import annotations

import csv
import itertools
import json
import logging
import os
import subprocess
import sys
import time
import traceback
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import numpy as np
from matplotlib.figure import Figure

from willmore_nlp.errors import UserInputError

STUDY_FILE = "study.json"
"""Marks a study directory; holds the grid."""

LOOSE_TOL = "loose tol"
"""A case's status when the flow warned that a step was accepted at its start only because the solver's ``tol`` is
loose (``flow.LooseToleranceWarning``): not "ok", so not a stable step size either."""


class StudyError(UserInputError):
    """A study specification is invalid (names the option and value)."""


@dataclass(frozen=True)
class Case:
    """One run of a study: a problem with parameters, a solver and a step size.

    ``tau`` is a number, a multiple of the problem's own step size written ``"<c>tau"`` (``"tau"``, ``"4tau"``) or a
    multiple of the mesh size written ``"<c>h"`` (``"h"``, ``"4h"``).
    """

    problem: str
    solver: str
    tau: str
    params: dict[str, Any] = field(default_factory=dict)
    steps: int | None = None
    t_end: float | None = None
    options: dict[str, Any] = field(default_factory=dict)
    """Flow and solver options (``max_iter``, ``tol``, ``max_retries`` ...) for WillmoreFlow."""

    @property
    def key(self) -> str:
        """File-name-safe identifier: problem, solver, tau, parameters, options and the length (``steps``, ``t_end``
        when given), so that a rerun with another ``--steps`` or ``--t-end`` runs its cases anew."""
        length = "".join(f"__{k}-{v}" for k, v in (("steps", self.steps), ("t_end", self.t_end)) if v is not None)
        return self.key_without_length + _file_safe(length)

    @property
    def key_without_length(self) -> str:
        """:attr:`key` without the length: the name of a case's file in studies written up to 2026-11-30."""
        par = "_".join(f"{k}-{v}" for k, v in sorted({**self.params, **self.options}.items()))
        return _file_safe(f"{self.problem}__{self.solver}__tau-{self.tau}" + (f"__{par}" if par else ""))


def _file_safe(raw: str) -> str:
    """``raw`` with every character other than letters, digits and ``-_.`` replaced by ``-``."""
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in raw)


def case_file(out: Path, case: Case) -> Path | None:
    """The file of ``case`` if it has finished in the study directory ``out``, else None.

    Parameters
    ----------
    out : study directory
    case : a case of its grid

    Returns
    -------
    ``out/cases/<key>.json``, or, in a study written before the length was part of :attr:`Case.key`, the file named
    by :attr:`Case.key_without_length` when the length it records is the case's (a case of another length has not
    finished: it runs anew, and the old file stays).
    """
    path = out / "cases" / f"{case.key}.json"
    if path.exists():
        return path
    old = out / "cases" / f"{case.key_without_length}.json"
    if old.exists():
        rec = json.loads(old.read_text(encoding="utf-8"))["case"]
        if (rec["steps"], rec["t_end"]) == (case.steps, case.t_end):
            return old
    return None


def parse_tau(spec: str, h: float, tau: float) -> float:
    """A step size from ``"0.01"``, ``"tau"`` or ``"4tau"`` (a multiple of the problem's own step size ``tau``, the
    one ``run`` takes: for a mesh file h L^3, which follows the file's units), or ``"h"`` or ``"4h"`` (a multiple of
    the mesh size h)."""
    s = str(spec).strip()
    unit, n = (tau, 3) if s.endswith("tau") else (h, 1) if s.endswith("h") else (1.0, 0)
    try:
        val = unit * (float(s[:-n]) if len(s) > n else 1.0) if n else float(s)
    except ValueError:
        raise StudyError(f"--taus: {spec!r} is not a number or a multiple of tau or h such as 4tau or 4h") from None
    if not (np.isfinite(val) and val > 0):
        raise StudyError(f"--taus: {spec!r} gives tau = {val}, which must be positive")
    return val


def run_case(case: Case, out: str) -> dict[str, Any]:
    """Run one case and write ``out/cases/<key>.json``; never raises for a failing flow.

    Returns
    -------
    dict with ``case``, ``status`` ("ok", "failed" or :data:`LOOSE_TOL`), ``error``, ``h``, ``tau``, ``control``
    (the resolved in-step tangential control, e.g. "meanratio 1" or "off"; absent when the flow was not built),
    ``wall`` and ``rows`` (one dict per accepted step, step 0 first).
    """
    from willmore_nlp import registry
    from willmore_nlp.flow import FlowError, LooseToleranceWarning, StepResult
    from willmore_nlp.rundir import write_text_atomic

    rows: list[dict[str, Any]] = []
    rec: dict[str, Any] = {"case": asdict(case), "status": "ok", "error": "", "h": float("nan"),
                           "tau": float("nan"), "rows": rows}
    t0 = time.perf_counter()

    def keep(r: StepResult) -> None:
        row = {k: v for k, v in r.row().items() if isinstance(v, int | float | str)}
        rows.append(row)

    # The flow's warnings (an input repair, a refinement in a step) go to the case's record, once each; printed by a
    # worker they came with Python's file:line format, in the middle of the progress lines (a new user's check).
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            pb, _ = registry.build(case.problem, **case.params)
            rec["h"] = float(pb.mesh.h)
            tau = parse_tau(case.tau, pb.mesh.h, pb.tau)
            rec["tau"] = tau
            flow = pb.make_flow(tau=tau, **case.options, solver=case.solver)
            rec["h"], rec["tau"] = float(flow.mesh.h), float(flow.tau)  # (an input repair rescales both: the
            # summary showed the input's h and tau, 0.1702, where the case ran at 0.1698; a new user's check)
            c = flow.tangential_control  # "auto" resolved: it depends on the solver (semi-implicit: off)
            rec["control"] = c.method if c.method == "off" else f"{c.method} {c.weight:g}"
            keep(flow.state())
            steps, t_end = case.steps, case.t_end
            if steps is None and t_end is None:
                steps, t_end = pb.steps, pb.t_end
            flow.run(steps=steps, t_end=t_end, callback=keep)
        except FlowError as exc:
            rec.update(status="failed", error=str(exc).splitlines()[0][:500])
            if exc.hint:  # (how to take the step: cut off the error's 500 characters, and the summary's 120)
                rec["warnings"] = [f"failed: {exc.hint.lstrip('; ')}"]
        except Exception as exc:
            rec.update(status="failed", error=f"{type(exc).__name__}: {exc}"[:500],
                       traceback=traceback.format_exc(limit=5))
    if rec["status"] == "ok" and any(issubclass(w.category, LooseToleranceWarning) for w in caught):
        rec["status"] = LOOSE_TOL  # (a step that never moved: listed "ok" with 0.0 mean iterations and counted as
        # the largest stable tau before; a new user's check)
    rec["warnings"] = list(dict.fromkeys([*rec.get("warnings", []),  # (the hint first: the summary shows five)
                                          *(str(w.message) for w in caught
                                            if not issubclass(w.category, DeprecationWarning))]))
    rec["wall"] = time.perf_counter() - t0
    write_text_atomic(Path(out) / "cases" / f"{case.key}.json", json.dumps(rec, default=float))
    return rec


def make_grid(problem: str, solvers: list[str], taus: list[str], grid: dict[str, list[Any]] | None = None,
              params: dict[str, Any] | None = None, steps: int | None = None,
              t_end: float | None = None, options: dict[str, Any] | None = None) -> list[Case]:
    """All cases of a study (solver x tau x grid values), checked before anything runs.

    Raises
    ------
    StudyError
        an unknown solver, a solver option it does not take, no solver or no tau, a tau that is not a positive number
        or multiple of tau or h, or a parameter both in ``grid`` and ``params``.
    """
    from willmore_nlp import registry
    from willmore_nlp.settings import FlowSettings, route_solver_options
    from willmore_nlp.solvers import solver_names, solver_settings

    registry.get(problem)
    known = solver_names()
    for s in solvers:
        if s not in known:
            raise StudyError(f"--solvers: unknown solver {s!r}; available: {', '.join(known)}")
        try:
            flow_options, solver_options = FlowSettings.split(case_options(s, options or {}))
            for name, given in route_solver_options(solver_options, {**flow_options, "solver": s}).items():
                solver_settings(name).from_options(given)
        except UserInputError as exc:
            raise StudyError(f"--option: {exc}") from exc
    if not solvers or not taus:
        raise StudyError("a study needs at least one solver (--solvers) and one step size (--taus)")
    for t in taus:
        parse_tau(t, 1.0, 1.0)
    grid = grid or {}
    both = sorted(set(grid) & set(params or {}))
    if both:  # (the grid's values replaced the fixed one silently)
        raise StudyError(f"--grid and --set both give {', '.join(both)}: a parameter is either varied (--grid) or "
                         "fixed (--set), not both")
    combos: list[dict[str, Any]] = [dict(params or {})]
    for k, vals in grid.items():
        combos = [{**c, k: v} for c in combos for v in vals]
    return [Case(problem, s, str(t), c, steps, t_end, case_options(s, options or {})) for c in combos
            for s in solvers for t in taus]


def case_options(solver: str, options: dict[str, Any]) -> dict[str, Any]:
    """The ``--option`` values of a study's cases of ``solver``: without the options written ``NAME.KEY`` for a solver
    NAME that the case's flow does not use (``--solvers ipopt,lbfgs --option ipopt.max_iter=500``: IPOPT's, for the
    ipopt cases; :func:`~willmore_nlp.settings.solver_of`)."""
    from willmore_nlp.settings import flow_solvers, solver_prefix

    used = flow_solvers({**options, "solver": solver}).values()
    return {k: v for k, v in options.items() if solver_prefix(k) in ("", *used)}


def check_cases(cases: list[Case]) -> None:
    """Build the flow of every case as :func:`run_case` does, without a step, so that a case that can never run is
    refused before a study writes anything (as ``willmore-nlp run`` refuses it).

    One flow per solver and parameter set: the step size does not change what can run (:func:`make_grid` has checked
    it). A flow that fails later, in a step, is the study's to record (:func:`run_case`).

    Parameters
    ----------
    cases : from :func:`make_grid`

    Raises
    ------
    StudyError
        naming the first case that cannot run and why (``--solvers semi-implicit --option volume=initial``: the
        solver has no outer equality constraints).
    """
    from willmore_nlp import registry

    built: list[tuple[str, dict[str, Any]]] = []
    for case in cases:
        if (case.solver, case.params) in built:
            continue
        built.append((case.solver, case.params))
        try:
            pb, _ = registry.build(case.problem, **case.params)
            pb.make_flow(tau=parse_tau(case.tau, pb.mesh.h, pb.tau), **case.options, solver=case.solver)
        except UserInputError as exc:
            raise StudyError(f"case {_label({'case': asdict(case)})}: {exc}") from exc


ENERGY_OPTIONS = ("c0", "anisotropy", "volume", "area", "terms")
"""Flow options that change the energy a flow lowers (its other options change the path: step sizes, solvers, the mesh
control, the tangential motion)."""


def _willmore_alone(lam: float, options: dict[str, Any]) -> bool:
    """Whether a flow with ``lam`` and the flow ``options`` (a problem's with a case's) lowers the Willmore energy
    alone, what Evolver's reference minimises. Before 2026-12-01 any option but three path options skipped the
    reference, so a file problem, which sets its step-size rules, never had one, while a case's ``--option c0=...``
    went unseen."""
    from willmore_nlp.settings import moebius_invariant

    return moebius_invariant(lam, float(options.get("c0") or 0.0), options.get("anisotropy"), options.get("volume"),
                             options.get("area")) and not options.get("terms")


def evolver_rows(cases: list[Case], iterations: int) -> list[dict[str, Any]]:
    """Surface Evolver reference energies of the initial surfaces of a study (one per parameter set).

    Rows carry ``problem``, ``params``, ``w_initial`` (this library's discrete Willmore energy of the mesh the cases
    flow, after ``input_repair``) and Evolver's ``initial``/``final`` energies of that mesh, or ``skipped`` with the
    reason (not a closed surface with the Willmore energy alone; not installed or failed, ``w_initial`` kept).
    """
    from willmore_nlp import registry
    from willmore_nlp.evolver import evolver_reference, find_evolver
    from willmore_nlp.geometry import willmore_energy

    rows: list[dict[str, Any]] = []
    seen: list[tuple[dict[str, Any], dict[str, Any]]] = []
    for c in cases:
        energy = {k: c.options[k] for k in ENERGY_OPTIONS if k in c.options}
        if (c.params, energy) in seen:
            continue
        seen.append((c.params, energy))
        row: dict[str, Any] = {"problem": c.problem, "params": c.params, **({"options": energy} if energy else {})}
        pb, _ = registry.build(c.problem, **c.params)
        mesh = pb.mesh
        if mesh.d != 2 or mesh.m != 3 or not mesh.is_closed or not _willmore_alone(pb.lam,
                                                                                  {**pb.flow_options, **energy}):
            row["skipped"] = ("the reference is for the Willmore energy alone of closed surfaces in R^3 (no boundary "
                              "conditions, anisotropy, lam, c0, volume, area or extra terms)")
            rows.append(row)
            continue
        with warnings.catch_warnings():  # (the cases' check showed them) the mesh the cases flow: input_repair's
            # (Evolver had measured the unrepaired file: 36.6539 where the cases start at 36.5464; a new user's check)
            warnings.simplefilter("ignore")
            mesh = pb.make_flow(tau=parse_tau(c.tau, pb.mesh.h, pb.tau), **c.options, solver=c.solver).mesh
        row["w_initial"] = willmore_energy(mesh)
        if find_evolver() is None:
            row["skipped"] = "Surface Evolver (evolver-nox) is not installed"
        else:
            try:
                row.update(evolver_reference(mesh, iterations))
            except (RuntimeError, OSError, subprocess.SubprocessError) as exc:
                row["skipped"] = f"Surface Evolver failed: {exc}"[:300]
        rows.append(row)
    return rows


def run_study(cases: list[Case], out: str | os.PathLike[str], *, scheduler: str | None = None,
              n_workers: int = 2, progress: bool = True, evolver: int | None = None) -> Path:
    """Run the cases not finished yet on Dask and write the study artefacts.

    Parameters
    ----------
    cases : from :func:`make_grid`
    out : study directory (created; reused by reruns, which skip finished cases)
    scheduler : address of an existing Dask scheduler; default a LocalCluster with ``n_workers``
        single-threaded worker processes
    evolver : if given, add Surface Evolver's Willmore energy after this many ``g`` iterations as a
        reference (``evolver.json``) for closed surfaces; skipped with a message when Evolver is
        not installed
    """
    from dask.distributed import Client, LocalCluster, as_completed

    from willmore_nlp.mesh.io import make_dirs

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise StudyError(f"--out {out}: is a file, not a study directory")
    if out.is_dir() and any(out.iterdir()) and not (out / STUDY_FILE).is_file():
        what = "a run directory" if (out / "config.json").is_file() else "a folder with other files"
        raise StudyError(f"--out {out}: is {what}, not a study directory; a study writes into a new or empty folder "
                         f"(or reruns into its own, skipping finished cases)")
    make_dirs(out / "cases")
    before = _study_cases(out)
    known = {c.key for c in before}
    spec = {"cases": [asdict(c) for c in [*before, *(c for c in cases if c.key not in known)]]}
    (out / STUDY_FILE).write_text(json.dumps(spec, indent=1), encoding="utf-8")
    if evolver is not None and not (out / "evolver.json").exists():
        rows = evolver_rows(cases, evolver)
        (out / "evolver.json").write_text(json.dumps(rows, indent=1, default=float), encoding="utf-8")
        if progress:
            for r in rows:
                print(f"Surface Evolver reference {r['params'] or ''}: "
                      f"{r.get('skipped') or format(r['final'], '.6g')}", file=sys.stderr)
    todo = [c for c in cases if case_file(out, c) is None]
    if progress:
        print(f"study {out}: {len(cases)} cases, {len(cases) - len(todo)} already finished", file=sys.stderr)
    if todo:
        cluster = None
        if scheduler is None:
            cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=logging.ERROR)
        try:
            client = Client(scheduler if scheduler is not None else cluster)
        except OSError as exc:  # (an address given that answers nothing: the user's to fix)
            if cluster is not None:
                cluster.close()
            raise StudyError(f"--scheduler {scheduler}: cannot connect ({exc})") from exc
        try:
            futures = [client.submit(run_case, c, str(out), key=f"case-{c.key}", pure=False) for c in todo]
            for i, fut in enumerate(as_completed(futures), 1):
                rec = fut.result()
                if progress:
                    c = rec["case"]
                    n_warn = len(rec.get("warnings", []))
                    print(f"[{i}/{len(todo)}] {c['solver']} tau={c['tau']} {c['params'] or ''}: {outcome(rec)}, "
                          f"{max(len(rec['rows']) - 1, 0)} steps, {rec['wall']:.1f} s"
                          f"{f', {n_warn} warning(s) (summary.md)' if n_warn else ''} "
                          f"{rec['error'][:100] if rec['error'] else ''}", file=sys.stderr, flush=True)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    return write_study(out)


def _study_cases(out: Path) -> list[Case]:
    """The cases ``out``'s study.json lists (every grid run into it; none when it does not exist yet)."""
    path = out / STUDY_FILE
    return [Case(**c) for c in json.loads(path.read_text(encoding="utf-8"))["cases"]] if path.is_file() else []


def _load(out: Path) -> list[dict[str, Any]]:
    """Every case file in ``out/cases``: those of the cases study.json lists first, in its order, then the others
    by name (a rerun with a smaller grid listed only its own cases, and the summary lost the rest: a new-user check).
    Temporary files of a write under way (hidden: :func:`~willmore_nlp.mesh.io.atomic_write`) are not case files."""
    listed = [p for c in _study_cases(out) if (p := case_file(out, c)) is not None]
    others = sorted(p for p in (out / "cases").glob("*.json") if not p.name.startswith("."))
    return [json.loads(p.read_text(encoding="utf-8")) for p in dict.fromkeys([*listed, *others])]


def _energy_rise(rec: dict[str, Any]) -> float:
    """Largest relative increase of the discrete energy in a step (0 if it never rises): the step's energy
    inequality, the stepped state (``energy_before_remesh`` when the mesh control acted after the step) against the
    state it started from, at the tau_tilde of the step. A mesh repair between steps and a change of tau_tilde
    (``rest_tau_tilde`` at rest, a refinement) change the functional, not the step: a resting sphere's halving of
    tau_tilde moved the recorded energy 25.136 -> 25.182, which this measure read as a rise of 1.8e-3 (and the
    summary as no stable step size at all). A step whose row changed tau_tilde with no repair is skipped (its
    stepped energy at the old tau_tilde is not recorded)."""
    rows = rec["rows"]
    worst = 0.0
    for prev, row in itertools.pairwise(rows):
        e0 = float(prev.get("energy", np.nan))
        stepped = float(row.get("energy_before_remesh", np.nan))
        if not np.isfinite(stepped):
            if row.get("tau_tilde") != prev.get("tau_tilde"):
                continue
            stepped = float(row.get("energy", np.nan))
        if np.isfinite(e0) and np.isfinite(stepped):
            worst = max(worst, (stepped - e0) / max(abs(e0), 1e-300))
    return worst


ENERGY_RISE_TOL = 1e-8
"""A case without the in-step tangential control whose discrete energy rose by more than this (relative) in a step
broke the scheme's energy inequality (:func:`outcome`)."""


SHOWN_WARNINGS = 5
"""summary.md lists this many of a case's warnings (a long run warns of each refinement)."""


def outcome(rec: dict[str, Any]) -> str:
    """A case's status as the summary shows it: ``failed``; :data:`LOOSE_TOL`; ``energy rose`` for a case that ran
    every step but whose discrete energy rose by more than :data:`ENERGY_RISE_TOL` (relative) in a step, without the
    in-step tangential control (with it a step lowers the energy plus the control's term, and the energy alone may
    rise by the control's share); ``ok`` otherwise. (A semi-implicit case whose energy grew from 7.154 to 7.248 at a
    large tau was listed ``ok``: a new user's check.)"""
    if rec["status"] != "ok":
        return str(rec["status"])
    controlled = str(rec.get("control", "off")) not in ("off", "")
    return "energy rose" if not controlled and _energy_rise(rec) > ENERGY_RISE_TOL else "ok"


def _varying(recs: list[dict[str, Any]]) -> tuple[str, ...]:
    """The options and lengths (``steps``, ``t_end``) in which the cases of ``recs`` differ: the study directory
    may hold the cases of several runs of ``compare`` (another ``--steps`` or ``--option``)."""
    def value(rec: dict[str, Any], k: str) -> str:
        return json.dumps(rec["case"].get(k, rec["case"]["options"].get(k)), default=str)

    names = dict.fromkeys(["steps", "t_end", *(k for rec in recs for k in rec["case"]["options"])])
    return tuple(k for k in names if len({value(rec, k) for rec in recs}) > 1)


def _label(rec: dict[str, Any], varying: tuple[str, ...] = ()) -> str:
    """``SOLVER tau=TAU`` with the case's parameters and its options and length among ``varying``."""
    c = rec["case"]
    par = " ".join([*(f"{k}={v}" for k, v in c["params"].items()),
                    *(f"{k}={c.get(k, c['options'].get(k))}" for k in varying if k in c or k in c["options"])])
    return f"{c['solver']} tau={c['tau']}" + (f" {par}" if par else "")


def write_study(out: str | os.PathLike[str]) -> Path:
    """Write study.csv, summary.md and figures/ from every finished case file in ``out/cases`` (the cases of every
    run of ``compare`` into ``out``); returns summary.md."""
    out = Path(out)
    if not (out / STUDY_FILE).exists():
        raise StudyError(f"{out}: not a study directory (no {STUDY_FILE})")
    recs = _load(out)
    varying = _varying(recs)
    figs = out / "figures"
    figs.mkdir(exist_ok=True)
    cols = ["case", "solver", "tau_spec", "tau", "h", "params", "case_status", "step", "status", "t", "energy",
            "willmore_energy", "iterations", "wall_time", "kkt_residual", "retries", "converged"]
    with open(out / "study.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for rec in recs:
            c = rec["case"]
            base = {"case": Case(**c).key, "solver": c["solver"], "tau_spec": c["tau"], "tau": rec["tau"],
                    "h": rec["h"], "params": json.dumps(c["params"], sort_keys=True), "case_status": rec["status"]}
            for row in rec["rows"] or [{}]:
                w.writerow({**base, **row})
    problems = ", ".join(dict.fromkeys(rec["case"]["problem"] for rec in recs)) or "(no finished cases)"
    lines = [f"# Solver comparison: {problems}", "",
             f"{len(recs)} finished case(s): every case file in `cases/`, of every `willmore-nlp compare` run into "
             f"this directory. Regenerate with `willmore-nlp report {out}`; rerun missing cases with "
             "`willmore-nlp compare` and the same options.", "",
             "In-step tangential control: the resolved `tangential_control` of each case (its weight).", "",
             "`final Willmore`: the Willmore energy of the last state, an anisotropic flow's w_gamma (what it "
             "lowers); compare the cases at the same `final t`.", "",
             "| case | h | tau | control | status | steps | final t | mean iterations | mean s/step | final energy | "
             "final Willmore | max KKT residual | max energy rise | error |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for rec in recs:
        steps = rec["rows"][1:]
        it = np.mean([r["iterations"] for r in steps]) if steps else float("nan")
        wt = np.mean([r["wall_time"] for r in steps]) if steps else float("nan")
        kkt = max((r.get("kkt_residual", float("nan")) for r in steps), default=float("nan"))
        last = rec["rows"][-1] if rec["rows"] else {}
        gamma = last.get("willmore_gamma", float("nan"))  # (an anisotropic flow's: the isotropic W may rise)
        will = gamma if isinstance(gamma, float) and np.isfinite(gamma) else last.get("willmore_energy", float("nan"))
        lines.append(f"| {_label(rec, varying)} | {rec['h']:.4g} | {rec['tau']:.4g} | {rec.get('control', '')} | "
                     f"{outcome(rec)} | {len(steps)} | {last.get('t', float('nan')):.4g} | "
                     f"{it:.1f} | {wt:.4f} | {last.get('energy', float('nan')):.6g} | "
                     f"{will:.6g}{' (w_gamma)' if will is gamma else ''} | {kkt:.2e} | {_energy_rise(rec):.1e} | "
                     f"{rec['error'][:120]} |")
    stable: dict[tuple[str, float], float] = {}
    for rec in recs:
        if outcome(rec) == "ok" and np.isfinite(rec["tau"]) and not any(r.get("retries") for r in rec["rows"]):
            k = (rec["case"]["solver"], round(rec["h"], 12))
            stable[k] = max(stable.get(k, 0.0), rec["tau"])
    lines += ["", "Largest step size that completed every step without halving and without raising the discrete "
              f"energy by more than {ENERGY_RISE_TOL:g} (relative) in any step, within the taus tried (the energy "
              "condition for the cases without the in-step control: with it a step lowers the energy plus the "
              "control's term, and the energy alone may rise by the control's share, the 'max energy rise' column; "
              "a case without the control whose energy rose has the status 'energy rose'):", "",
              "| solver | h | largest stable tau | tau / h |", "|---|---|---|---|"]
    lines += [f"| {s} | {h:.4g} | {t:.4g} | {t / h:.3g} |" for (s, h), t in sorted(stable.items())]
    ev = out / "evolver.json"
    if ev.exists():
        lines += ["", "Reference: Surface Evolver (`star_perp_sq_mean_curvature`, zero tension, converted to "
                  "w = 1/2 int (k1 + k2)^2) from the initial surface:", "",
                  "| parameters | w here (initial) | Evolver initial | Evolver after g N | N |",
                  "|---|---|---|---|---|"]
        for r in json.loads(ev.read_text(encoding="utf-8")):
            par = " ".join(f"{k}={v}" for k, v in {**r["params"], **r.get("options", {})}.items()) or "defaults"
            if "skipped" in r:
                lines.append(f"| {par} | skipped: {r['skipped']} | | | |")
            else:
                lines.append(f"| {par} | {r['w_initial']:.6g} | {r['initial']:.6g} | {r['final']:.6g} | "
                             f"{r['iterations']} |")
    warned = [rec for rec in recs if rec.get("warnings")]
    if warned:
        lines += ["", "Warnings of the cases, and what a failed case's error suggests (each once per case; the full "
                  "list in `cases/<key>.json`):", ""]
        for rec in warned:
            more = len(rec["warnings"]) - SHOWN_WARNINGS
            lines += [f"- {_label(rec, varying)}: {w}" for w in rec["warnings"][:SHOWN_WARNINGS]]
            lines += [f"- {_label(rec, varying)}: ... and {more} more"] if more > 0 else []
    lines += ["", "![energy](figures/energy.png)", "", "![cost](figures/cost.png)", "",
              "![stable tau](figures/stable_tau.png)", ""]
    _figures(recs, stable, figs, varying)
    md = out / "summary.md"
    md.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return md


def _figures(recs: list[dict[str, Any]], stable: dict[tuple[str, float], float], figs: Path,
             varying: tuple[str, ...] = ()) -> None:
    fig = Figure(figsize=(6, 4))
    ax = fig.add_subplot(1, 1, 1)
    for rec in recs:
        if rec["rows"]:
            ax.plot([r["t"] for r in rec["rows"]], [r["energy"] for r in rec["rows"]], "o-", ms=2,
                    label=_label(rec, varying))
    ax.set_xlabel("t")
    ax.set_ylabel("discrete energy")
    if ax.lines:  # (no case with a state: matplotlib warns of a legend without artists)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(figs / "energy.png", dpi=90)
    fig = Figure(figsize=(9, 3.6))
    a1, a2 = fig.subplots(1, 2)
    labels = [_label(r, varying) for r in recs]
    its = [np.mean([s["iterations"] for s in r["rows"][1:]]) if len(r["rows"]) > 1 else 0.0 for r in recs]
    wts = [np.mean([s["wall_time"] for s in r["rows"][1:]]) if len(r["rows"]) > 1 else 0.0 for r in recs]
    y = np.arange(len(recs))
    a1.barh(y, its)
    a1.set_yticks(y, labels, fontsize=6)
    a1.set_xlabel("mean iterations per step")
    a2.barh(y, wts)
    a2.set_yticks(y, [""] * len(recs))
    a2.set_xlabel("mean seconds per step")
    fig.tight_layout()
    fig.savefig(figs / "cost.png", dpi=90)
    fig = Figure(figsize=(5, 3.6))
    ax = fig.add_subplot(1, 1, 1)
    for s in sorted({k[0] for k in stable}):
        pts = sorted((h, t) for (sv, h), t in stable.items() if sv == s)
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=s)
    ax.set_xlabel("h")
    ax.set_ylabel("largest stable tau")
    if stable:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(figs / "stable_tau.png", dpi=90)
