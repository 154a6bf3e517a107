"""Running a flow into a run directory: start, resume, signals, status, progress display.

This is the engine of ``willmore-nlp run``. A run writes every accepted state atomically
(:class:`~willmore_nlp.rundir.RunWriter`) and records its state in ``status.json``:

- ``completed``: the configured steps or final time were reached (exit 0);
- ``failed``: a step was rejected after every retry (:class:`~willmore_nlp.flow.FlowError`);
  the rejected attempts are in status.json (exit 1);
- ``interrupted``: SIGINT or SIGTERM arrived; the step under way was abandoned within one
  solver iteration (never retried, never accepted half-solved), every accepted step is kept
  (exit 128 + signal number: 130 or 143);
- ``abandoned``: a second signal arrived before the first took effect (a solver that does not
  poll for stops); the step under way was dropped (same exit codes);
- ``crashed``: an internal error (a bug; its traceback is shown); ``running`` with no live
  process means the process was killed (kill -9, power loss).

Every outcome leaves a valid run directory that :func:`resume` continues. A resumed run
gives bit-identical states to an uninterrupted one: it restarts the flow from the last
trusted checkpoint with the stored Y and multipliers, and restores the BLAS thread settings
recorded at the start (the thread count changes the last bits of MUMPS' factorisation).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np

from willmore_nlp import registry
from willmore_nlp.config import ConfigError, RunSpec, check_spec, resolve
from willmore_nlp.errors import EXIT_FAILED, IO_ERRNOS, UserInputError
from willmore_nlp.flow import (
    EDGE_RATIO_REASON,
    FLOOR_REASON,
    FOLD_REASON,
    FlowError,
    InputRepairWarning,
    StepInterrupted,
    StepResult,
    WillmoreFlow,
)
from willmore_nlp.geometry import willmore_energy
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.references import resolution_warning
from willmore_nlp.rundir import (
    Checkpoint,
    RunError,
    RunWriter,
    check_new_run_dir,
    clear_run_dir,
    load_solver_state,
    read_config,
    read_mesh_npz,
    require_run_dir,
    write_text_atomic,
)
from willmore_nlp.settings import FlowSettings, flow_solvers

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Environment variables that set BLAS/OpenMP thread counts (recorded in config.json)."""


def last_reason(rejected: list[str], message: str) -> str:
    """The last rejected attempt's reason for the one-line error of a failed step (``message`` when there is none);
    when that is only the step-size floor, with the last attempt that the solver or a check refused (the cause)."""
    if not rejected:
        return message
    cause = next((r for r in reversed(rejected) if FLOOR_REASON not in r), None)
    return rejected[-1] if cause is None or cause == rejected[-1] else f"{rejected[-1]}; before it: {cause}"


def fold_hint(h: float, remeshes_input: bool = True, input_repair: bool = True) -> str:
    """What the one-line error of a run stopped by the fold check adds: why a mesh folds and what resolves it
    (docs/guide/mesh_quality.md, "Folds"), with ``h`` the mean edge of the mesh it folded on. ``remesh_target``
    remeshes the input only while the flow remeshes (``remeshes_input``: mesh_control and remesh auto, a surface in
    R^3) and ``input_repair`` is on; the hint names what makes it act (the vesicle problem turns ``input_repair``
    off: its ``--set remesh_target=H`` alone changed nothing, a new-user check)."""
    why = ("; a mesh folds where it no longer resolves the surface (a bar or tube about an edge wide): a finer mesh "
           "from the start resolves a narrower one")
    if not remeshes_input:
        return f"{why} (a finer input: remesh_target remeshes the input only while mesh_control and remesh are auto)"
    repair = "" if input_repair else "--set input_repair=true "
    return f"{why}, e.g. {repair}--set remesh_target={h / 2:.3g} (half the mean edge {h:.3g})"


def spacing_hint(settings: FlowSettings, mesh: Mesh, rejected: list[str]) -> str:
    """What the one-line error adds when a closed curve's step was rejected for its edge ratio (``rejected``: the
    attempts' reasons) and ``redistribute`` is off: the nodes bunched along the curve, and redistribution spaces them
    evenly after every step. Measured (a new user's noisy 300-vertex space curve, noise 0.003): edge ratio 8.7 -> 1000
    in 28 steps and the run stopped; with ``redistribute=true`` 200 steps, W 1909 -> 1.77, edge ratio at most 8.7."""
    if settings.redistribute or mesh.d != 1 or not mesh.is_closed or not any(EDGE_RATIO_REASON in r for r in rejected):
        return ""
    return ("; the curve's nodes bunched up along it (edge ratio): --set redistribute=true moves them to equal "
            "arc-length spacing after every step (not the paper's scheme: docs/theory/scheme.md)")


def thread_environment() -> dict[str, Any]:
    """The thread settings that decide the last bits of the linear algebra."""
    env: dict[str, Any] = {v: os.environ.get(v) for v in THREAD_VARS}
    env["cpu_count"] = os.cpu_count()
    return env


def restore_thread_environment(saved: dict[str, Any]) -> list[str]:
    """Set the :data:`THREAD_VARS` as recorded; returns one note per change.

    Effective for CasADi's own OpenBLAS (loaded with the IPOPT plugin, i.e. when the first
    solver is built), which is what MUMPS uses.
    """
    notes = []
    for v in THREAD_VARS:
        want, have = saved.get(v), os.environ.get(v)
        if want == have:
            continue
        if want is None:
            os.environ.pop(v, None)
        else:
            os.environ[v] = str(want)
        notes.append(f"{v}: {have!r} -> {want!r} (as when the run started)")
    if saved.get("cpu_count") not in (None, os.cpu_count()):
        warnings.warn(f"the run started on a machine with {saved['cpu_count']} CPUs, this one has "
                      f"{os.cpu_count()}: resumed states may differ in the last bits", stacklevel=2)
    return notes


# -- signals -------------------------------------------------------------------------------
class _StopRequestedError(Exception):
    """Raised from the step callback after a signal, once the step is written."""


class SignalGuard:
    """SIGINT/SIGTERM: stop at once, keeping every accepted step.

    The first signal sets :attr:`signum`; the flow polls it (:attr:`WillmoreFlow.stop_requested`)
    before every attempt and IPOPT once per iteration, so the step under way is abandoned within
    one solver iteration and never retried. A second signal raises KeyboardInterrupt once (for
    solvers that do not poll); later ones are ignored, so the exit path that records the status
    cannot itself be interrupted. Use as a context manager; the previous handlers are restored on exit,
    unless a signal arrived and ``ignore_after`` is set (the command line, which is about to exit: a
    late second signal must not kill it before it returns its exit code).
    """

    def __init__(self, ignore_after: bool = False) -> None:
        self.ignore_after = ignore_after
        self.signum: int | None = None
        self.count = 0
        self._old: dict[int, Any] = {}
        self._deferring = False
        self._pending = False

    def stop_requested(self) -> bool:
        """True once a signal has arrived."""
        return self.signum is not None

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        self.count += 1
        name = signal.Signals(signum).name
        if self.count == 1:
            self.signum = signum
            msg = (f"\nwillmore-nlp: {name} received: stopping (the step under way is abandoned, finished steps "
                   "are kept)\n")
        elif self.count == 2:
            msg = f"willmore-nlp: second {name}: abandoning at once\n"
        else:
            return
        with contextlib.suppress(OSError):
            os.write(2, msg.encode())  # not print(): a handler may interrupt a write to sys.stderr
        if self.count == 2:
            if self._deferring:
                self._pending = True
            else:
                raise KeyboardInterrupt

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        """A block that the second signal's KeyboardInterrupt does not cut: it is raised when the block ends. Around
        the writing of an accepted state and its history row, so that status.json names the last state on disk (a
        second SIGINT between the two had left a state one step past the status, under load)."""
        self._deferring = True
        try:
            yield
        finally:
            self._deferring = False
        if self._pending:
            self._pending = False
            raise KeyboardInterrupt

    def __enter__(self) -> SignalGuard:
        for s in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(s) is not signal.SIG_IGN:  # an ignored signal stays ignored (a shell's 'run ... &'
                self._old[s] = signal.signal(s, self._handler)  # ignores SIGINT in the background job)
        return self

    def __exit__(self, *exc: object) -> None:
        for s, h in self._old.items():
            signal.signal(s, signal.SIG_IGN if self.ignore_after and self.count else h)


# -- progress ------------------------------------------------------------------------------
HEARTBEAT_SECONDS = 1.0
"""The progress bar is redrawn this often while a step is under way, so that its elapsed time runs (a new user's check,
2026-12-01: a torus of 8,192 vertices showed "0/8 [00:00<?" for the 340 s of its first step)."""


class _Bar:
    """Progress display: steps or simulated time (tqdm; silent with ``quiet``), redrawn every
    :data:`HEARTBEAT_SECONDS` by a daemon thread (display only: it reads nothing of the flow)."""

    def __init__(self, total: float | None, unit: str, quiet: bool, initial: float = 0.0) -> None:
        from tqdm import tqdm

        self.by_time = unit == "t"
        self.bar = tqdm(total=total, unit="" if self.by_time else "step", disable=quiet, initial=initial,
                        bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]"
                        if self.by_time else None)
        self._stop = threading.Event()
        self._beat = None if quiet else threading.Thread(target=self._heartbeat, name="willmore-nlp progress",
                                                         daemon=True)
        if self._beat is not None:
            self._beat.start()

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            self.bar.refresh()

    def update(self, r: StepResult) -> None:
        self.bar.set_postfix(step=r.step, t=f"{r.t:.4g}", it=r.iterations, W=f"{r.willmore:.5g}",
                             **({"retries": r.retries} if r.retries else {}), refresh=False)
        if self.by_time:
            self.bar.update(r.t - self.bar.n)
        else:
            self.bar.update(1)

    def note(self, text: str) -> None:
        """Show ``text`` in place of the step figures until the next step (a retry under way)."""
        self.bar.set_postfix_str(text)

    def close(self) -> None:
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
        self.bar.close()


# -- the loop ------------------------------------------------------------------------------
@contextlib.contextmanager
def _kept_warnings(writer: RunWriter) -> Iterator[None]:
    """Every warning shown meanwhile is also kept in the run's status.json (:meth:`RunWriter.warned`)."""
    shown = warnings.showwarning

    def keep(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None,
             line: str | None = None) -> None:
        writer.warned(str(message))
        shown(message, category, filename, lineno, file, line)

    warnings.showwarning = keep
    try:
        yield
    finally:
        warnings.showwarning = shown


def _warn(writer: RunWriter, text: str) -> None:
    """A warning of the command line's own (``willmore-nlp: warning: TEXT`` on standard error), kept in the run."""
    print(f"willmore-nlp: warning: {text}", file=sys.stderr)
    writer.warned(text)


def _advance(flow: WillmoreFlow, writer: RunWriter, steps: int | None, t_end: float | None,
             guard: SignalGuard, quiet: bool) -> int:
    """Step to ``steps`` (total) or ``t_end``, writing every state and keeping the warnings shown
    (:func:`_kept_warnings`); returns the exit code."""
    with _kept_warnings(writer):
        return _advance_kept(flow, writer, steps, t_end, guard, quiet)


def _advance_kept(flow: WillmoreFlow, writer: RunWriter, steps: int | None, t_end: float | None,
                  guard: SignalGuard, quiet: bool) -> int:
    """:func:`_advance`'s work."""
    out = writer.out
    again = f"continue with 'willmore-nlp run --resume {out}'"
    remaining = None if steps is None else steps - flow.k
    bar = _Bar(t_end if t_end is not None else steps, "t" if t_end is not None else "step", quiet,
               initial=flow.t if t_end is not None else flow.k)

    def on_step(r: StepResult) -> None:
        with guard.deferred():
            writer.add(r, flow.lam_g, flow.warm_state())
            writer.progress()
        bar.update(r)
        if guard.signum is not None:
            raise _StopRequestedError

    def on_retry(text: str) -> None:
        bar.note(text)
        with guard.deferred():
            writer.progress(under_way=text)

    flow.stop_requested = guard.stop_requested
    flow.on_retry = on_retry
    try:
        if guard.signum is None and (remaining is None or remaining > 0):
            flow.run(t_end=t_end, steps=remaining, callback=on_step)
        if guard.signum is None:
            relaxed = flow.relax_message()
            cut = flow.settings.relax and not relaxed  # (a relaxation that its length ended)
            if cut:
                relaxed = (f"not relaxed: the run's length ended it at step {flow.k} before its relax test; continue "
                           f"with 'willmore-nlp run --resume {out} --steps N' (N a larger total)")
            writer.set_status("completed", **({"message": relaxed} if relaxed else {}))
            if not quiet:
                bar.close()
                print(f"wrote {out} ({flow.k} steps, t = {flow.t:.6g}{'; ' + relaxed if relaxed else ''})")
            elif cut:
                _warn(writer, relaxed)
            last = flow.mesh.with_vertices(flow.X)
            coarse = resolution_warning(last, willmore_energy(last))
            if coarse:
                _warn(writer, coarse)
            return 0
        raise _StopRequestedError
    except (_StopRequestedError, StepInterrupted) as exc:
        name = signal.Signals(guard.signum or signal.SIGINT).name
        during = (f" (step {exc.step} under way was abandoned: a resume starts it over)"
                  if isinstance(exc, StepInterrupted) else "")
        writer.set_status("interrupted", signal=name, message=f"stopped by {name} after step {flow.k}{during}")
        bar.close()
        print(f"willmore-nlp: interrupted by {name} after step {flow.k} (t = {flow.t:.6g}){during}; {out} is a "
              f"valid run directory: {again}", file=sys.stderr)
        return 128 + int(guard.signum or signal.SIGINT)
    except FlowError as exc:
        writer.set_status("failed", message=str(exc), failed_step=exc.step, rejected=exc.rejected)
        bar.close()
        why = last_reason(exc.rejected, str(exc))
        print(f"willmore-nlp: error: step {exc.step} at t = {exc.t:.6g} failed after {len(exc.rejected)} "
              f"attempts (last: {why}); all attempts are in {out / 'status.json'}; steps 0..{flow.k} are kept"
              + (fold_hint(flow.mesh.h, flow.remesh, flow.settings.input_repair) if FOLD_REASON in why else "")
              + spacing_hint(flow.settings, flow.mesh, exc.rejected) + exc.hint,
              file=sys.stderr)
        return EXIT_FAILED
    except Exception as exc:
        if isinstance(exc, OSError) and exc.errno in IO_ERRNOS:  # disk full, read-only: one line, exit 74
            with contextlib.suppress(OSError):
                writer.set_status("failed", message=f"cannot write: {exc}")
            k = int(writer.rows[-1]["step"]) if writer.rows else -1
            raise OSError(exc.errno, f"{exc.strerror or exc} (steps 0..{k} are kept; when it can be written "
                                     f"again: willmore-nlp run --resume {out})", str(exc.filename or out)) from exc
        if isinstance(exc, UserInputError):  # found only when the step ran (the CLI's one line, exit 2): not a bug
            writer.set_status("failed", message=f"{exc} (fix it, then --overwrite)")
            raise
        writer.set_status("crashed", message=f"{type(exc).__name__}: {exc}")  # a bug: record it, show the traceback
        raise
    finally:
        bar.close()


def _abandoned(writer: RunWriter, guard: SignalGuard) -> int:
    """Record a second signal's KeyboardInterrupt (it is raised only once: this cannot be interrupted)."""
    signum = int(guard.signum or signal.SIGINT)
    name = signal.Signals(signum).name
    k = int(writer.rows[-1]["step"]) if writer.rows else -1  # the last state written
    writer.set_status("abandoned", signal=name, message=f"step {k + 1} abandoned on a second {name}")
    print(f"willmore-nlp: abandoned step {k + 1} on a second {name}; {writer.out} holds steps 0..{k}: "
          f"continue with 'willmore-nlp run --resume {writer.out}'", file=sys.stderr)
    return 128 + signum


def start(spec: RunSpec, out: str | os.PathLike[str], *, quiet: bool = False, overwrite: bool = False,
          ignore_late_signals: bool = False, announce: bool = False) -> int:
    """Run ``spec`` into the new run directory ``out``; returns the exit code.

    Nothing is written when the flow cannot be built (bad mesh or options). ``announce``: say on stderr
    "writing the run to OUT" once the flow has been built (``run`` without ``--out``: never for a run refused,
    which writes nothing). With ``overwrite``
    an existing run directory ``out`` is cleared first (:func:`~willmore_nlp.rundir.clear_run_dir`:
    only the files the run wrote; others stay), once the new flow has been built.
    ``ignore_late_signals``: see :class:`SignalGuard` (``ignore_after``).
    """
    if spec.steps is None and spec.t_end is None:
        raise ConfigError("give --steps or --t-end")
    o = Path(out)
    if not (overwrite and (o / "config.json").is_file()):
        check_new_run_dir(o)
    pb = spec.problem
    with warnings.catch_warnings(record=True) as built:  # (shown at once, and kept in the run once it is written)
        flow = pb.make_flow(**spec.flow_options)
    for w in built:
        warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    if announce:
        print(f"willmore-nlp: writing the run to {o}", file=sys.stderr)
    if overwrite and (o / "config.json").is_file():
        removed = clear_run_dir(o)
        if not quiet:
            print(f"willmore-nlp: --overwrite: removed {len(removed)} files of the previous run in {o}",
                  file=sys.stderr)
    cfg = spec.config()
    cfg["cwd"] = os.getcwd()
    cfg["environment"] = thread_environment()
    cfg["tangential_control"] = {"method": flow.tangential_control.method, "weight": flow.tangential_control.weight}
    cfg["input_repair"] = flow.input_repair
    cfg["refine_scope"] = "local" if flow.settings.refine_local else "global"
    cfg["rest_dilation"] = flow.settings.rest_dilation
    cfg["flip_rest"] = flow.settings.flip_rest
    cfg["adaptive_max_wait"] = flow.settings.adaptive_max_wait
    cfg["relax_newton"] = flow.relax_newton
    cfg["flow_steps"] = {"tau": flow.tau, "tau_tilde": flow.tau_tilde, "h": flow.mesh.h}  # of the mesh flowed
    with SignalGuard(ignore_late_signals) as guard:
        writer = RunWriter(out, cfg, pb.mesh, keep_foreign=overwrite)
        try:
            writer.set_status("running")
            for w in built:
                writer.warned(str(w.message))
            with guard.deferred():
                writer.add(flow.state(), flow.lam_g, flow.warm_state())
                writer.progress()  # (status.json names state 0 at once)
            return _advance(flow, writer, spec.steps, spec.t_end, guard, quiet)
        except KeyboardInterrupt:
            return _abandoned(writer, guard)
        finally:
            writer.close()


def stored_control(cfg: dict[str, Any], clamped: bool = False) -> dict[str, Any]:
    """The tangential control, conformal gauge, steps_from_h, solvers, refinement, rest rule and input repair a run
    directory's flow ran with, as flow options (a resumed run keeps them even when the library's defaults changed):
    ``config.json``'s ``tangential_control`` entry, or, for runs written before it existed (when the default was "off"
    at weight 0.3), the options they gave; the ``conformal_gauge`` of its effective options (false for ``file`` tori
    written before the problem turned it on, 2026-11-27, and ``torus`` runs written before 2026-11-29) and its
    ``steps_from_h`` ("none" for runs written before it
    existed: their tau and tau_tilde were the input's); its ``solver``, ``first_step_solver`` and ``fallback_solver``
    ("ipopt", "" and "" for runs written before the ``file`` problem chose newton-krylov for large surfaces, 2026-11-28)
    and ``large_solver`` and ``large_vertices`` ("" and 0 for runs written before they existed, 2026-11-29); its
    ``remesh_repair`` (2 unless the run was given another: the ``file`` problem's genus >= 2 surfaces got 4 later, its
    tori and the ``torus`` problem later still, 2026-11-29); its
    ``refine_scope`` record as ``refine_local`` (for runs written before it existed: their ``refine_local`` record on
    a closed surface and false on a ``clamped`` one, whose refinements were global before the scope record; false
    without either record, 2026-11-29: their refinements were global); its ``rest_dilation`` record (false for runs
    written before it existed, 2026-11-29: their drift was kept); its ``flip_rest`` record (0 for runs written before it
    existed, 2026-11-30: every non-Delaunay edge was flipped); its ``adaptive_max_wait`` record (0, no limit, for runs
    written before it existed, 2026-11-30); its ``relax_newton`` record (for runs written before it existed, 2026-12-01,
    the option they gave, else false: their relaxations took time steps); and
    ``input_repair = false`` for runs written before the input repair existed (no ``input_repair`` record: their initial
    state is the input as given, and the repair would give the flow another connectivity) and for runs whose repair did
    nothing (an empty record: the input as given, also when a later rule would remesh it, as a ``remesh_target`` does
    since 2026-11-28)."""
    given = cfg.get("effective_flow_options", cfg.get("flow_options", {}))
    stored = cfg.get("tangential_control")
    if stored is None:
        stored = {"method": given.get("tangential_control", "off"),
                  "weight": given.get("tangential_control_weight", 0.3)}
    out = {"tangential_control": stored["method"], "tangential_control_weight": stored["weight"],
           "conformal_gauge": given.get("conformal_gauge", False), "steps_from_h": given.get("steps_from_h", "none"),
           "solver": given.get("solver", "ipopt"), "first_step_solver": given.get("first_step_solver", ""),
           "fallback_solver": given.get("fallback_solver", ""), "large_solver": given.get("large_solver", ""),
           "large_vertices": given.get("large_vertices", 0),
           "remesh_repair": given.get("remesh_repair", given.get("remesh_relax", 2)),
           "refine_local": (cfg["refine_scope"] == "local" if "refine_scope" in cfg
                            else bool(cfg.get("refine_local", False)) and not clamped),
           "rest_dilation": bool(cfg.get("rest_dilation", False)), "flip_rest": float(cfg.get("flip_rest", 0.0)),
           "adaptive_max_wait": int(cfg.get("adaptive_max_wait", 0)),
           "relax_newton": bool(cfg.get("relax_newton", given.get("relax_newton", False)))}
    return out if cfg.get("input_repair") else {**out, "input_repair": False}


@contextlib.contextmanager
def _chdir(path: str | None) -> Iterator[None]:
    old = os.getcwd()
    if path and Path(path).is_dir():
        os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def spec_from_config(cfg: dict[str, Any], where: str, run_dir: Path | None = None) -> RunSpec:
    """Rebuild the RunSpec of a stored configuration (relative paths as seen from its ``cwd``). ``ipopt.NAME`` options
    of a run that used no IPOPT, written when they counted as ``NAME`` of its ``solver``, are given as ``NAME``.

    With ``run_dir``, a run of a mesh file (problem ``file``) reads the run's own copy of the
    initial mesh, ``run_dir/mesh.npz``, so the original file may have moved, changed or gone.
    """
    for k in ("problem", "params"):
        if k not in cfg:
            raise RunError(f"{where}: no {k!r} entry")
    entry = registry.load_all().get(str(cfg["problem"]))
    if entry is None:  # (a problem registered in a user's own module, which the command line does not import)
        raise RunError(f"{where}: problem {cfg['problem']!r} is not registered here (known: "
                       f"{', '.join(sorted(registry.load_all()))}); a problem of your own code is resumed from Python "
                       "after importing the module that registers it: willmore_nlp.runner.resume(RUN)")
    before = {} if entry is None else {k: v for k, v in entry.before.items() if k not in cfg["params"]}
    given = dict(cfg.get("flow_options", {}))
    if "ipopt" not in flow_solvers(cfg.get("effective_flow_options", given)).values():
        # written before ipopt.NAME keys were IPOPT's alone (2026-11-30; refused since without IPOPT): solver's NAME
        given = {k.removeprefix("ipopt."): v for k, v in given.items()}
    overrides = {**before, **cfg["params"], **given}
    if run_dir is not None and cfg["problem"] == "file":
        overrides["path"] = str(Path(run_dir).resolve() / "mesh.npz")
    with _chdir(cfg.get("cwd")):
        spec = resolve(str(cfg["problem"]), overrides, source=where)
    spec.steps = cfg.get("steps")
    spec.t_end = cfg.get("t_end")
    return spec


class _NothingToResumeError(Exception):
    """:func:`resume` of a completed run with no new length: the message says so, nothing is changed."""


def resume(run_dir: str | os.PathLike[str], *, steps: int | None = None, t_end: float | None = None,
           quiet: bool = False, ignore_late_signals: bool = False) -> int:
    """Continue the run in ``run_dir`` from its last trusted state; returns the exit code.

    The problem is rebuilt from config.json and must reproduce the stored initial mesh and
    step sizes exactly; otherwise nothing is changed and :class:`RunError` names the difference.

    Parameters
    ----------
    run_dir : a directory written by :func:`start` (interrupted, killed, failed or completed)
    steps, t_end : a new total length (extends the run; stored in config.json); default: as configured
    quiet : no progress bar and nothing on standard output (warnings and errors still go to standard error)
    ignore_late_signals : see :class:`SignalGuard` (``ignore_after``)
    """
    d = Path(run_dir)
    require_run_dir(d)
    where = str(d / "config.json")
    cfg = read_config(d)
    for note in restore_thread_environment(cfg.get("environment", {})):
        print(f"willmore-nlp: note: {note}", file=sys.stderr)
    spec = spec_from_config(cfg, where, d)
    if steps is not None or t_end is not None:
        spec.steps, spec.t_end = steps, t_end
        check_spec(spec, {"steps": "--steps", "t_end": "--t-end"})
    if spec.steps is None and spec.t_end is None:
        raise RunError(f"{where}: neither steps nor t_end is set")
    pb = spec.problem
    V0, S0 = read_mesh_npz(d)
    if not (np.array_equal(V0, pb.mesh.vertices) and np.array_equal(S0, pb.mesh.simplices)):
        raise RunError(f"{d}: cannot resume: the problem rebuilt from config.json has a different initial mesh "
                       f"than {d / 'mesh.npz'} (was an input file changed?)")
    for k in ("tau", "tau_tilde", "lam"):
        if cfg.get(k) != getattr(pb, k):
            raise RunError(f"{where}: cannot resume: {k} = {cfg.get(k)!r} but the problem now gives "
                           f"{getattr(pb, k)!r}")
    with warnings.catch_warnings(record=True) as built:  # (shown once the run goes on: a no-op says nothing of them)
        flow = pb.make_flow(**{**spec.flow_options,
                               **stored_control(cfg, pb.flow_options.get("boundary") is not None)})

    def before_changes(ck: Checkpoint | None, row: dict[str, Any], status: dict[str, Any]) -> None:  # (RunWriter.
        # resume calls it first)
        done_k, done_t = (0, 0.0) if ck is None else (ck.step, ck.t)
        if (steps is not None and steps < done_k) or (t_end is not None and t_end < done_t):
            raise RunError(f"{d}: holds {done_k} steps up to t = {done_t:.6g} already; --steps/--t-end give the "
                           f"new total length, which cannot be shorter (the run is unchanged)")
        relaxed = bool(float(row.get("relaxed") or 0))
        same = (spec.steps, spec.t_end) == (cfg.get("steps"), cfg.get("t_end"))  # (the length given again: a new
        # user's --steps 3 on a completed 3-step run said "resuming" and added an empty session to status.json)
        ended = status.get("state") == "completed" and status.get("step") == done_k  # (its last state is the end's)
        if ended and ((steps, t_end) == (None, None) or (same and not relaxed)):
            # (relax=true ended the run before its length: resuming took a step past the rest and ended anew; a run
            # at its length said "resuming" and "wrote" and added a session to status.json: a new user's check)
            why = status.get("message", "relaxed") if relaxed else "its configured length"
            raise _NothingToResumeError(f"{d}: the run ended at step {done_k}, {why}; nothing to resume (a "
                                        f"{'' if relaxed else 'larger '}--steps or --t-end continues it"
                                        f"{' past its rest' if relaxed else ''})")

    with SignalGuard(ignore_late_signals) as guard:
        try:
            writer, _, ck, notes = RunWriter.resume(d, before_changes)
        except _NothingToResumeError as done:
            if not quiet:
                print(done)
            return 0
        try:
            for note in notes:
                print(f"willmore-nlp: note: {note}", file=sys.stderr)
            done_k = 0 if ck is None else ck.step
            for w in built:  # (the input repair's only when the run is still before its first step)
                if done_k == 0 or not issubclass(w.category, InputRepairWarning):
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)
                    writer.warned(str(w.message))
            if (spec.steps, spec.t_end) != (cfg.get("steps"), cfg.get("t_end")):
                cfg.update({"steps": spec.steps, "t_end": spec.t_end})
                write_text_atomic(d / "config.json", json.dumps(cfg, indent=2, sort_keys=True, default=str))
            if ck is None:
                writer.set_status("running")
                with guard.deferred():
                    writer.add(flow.state(), flow.lam_g, flow.warm_state())
                    writer.progress()
            else:
                last = ck.row if ck.step > 0 else {}
                flow.restart(ck.vertices, ck.Y, ck.t, ck.step, ck.lam_g, last.get("tau"), int(last.get("retries", 0)),
                             simplices=ck.simplices, free=ck.free,
                             iterations=flow.budget_iterations(writer.rows),
                             history=writer.rows,
                             tau_tilde=last.get("tau_tilde"), rest_steps=int(float(last.get("rest_steps") or 0)),
                             warm=load_solver_state(d, ck.step))
                writer.set_status("running")
            if not quiet:
                print(f"resuming {d} at step {flow.k} (t = {flow.t:.6g})")
            return _advance(flow, writer, spec.steps, spec.t_end, guard, quiet)
        except KeyboardInterrupt:
            return _abandoned(writer, guard)
        finally:
            writer.close()
