"""Command-line interface: ``willmore-nlp run|problems|...``; a thin layer over the library."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys
import traceback
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from willmore_nlp import __version__, runner
from willmore_nlp.config import MESH_SUFFIXES, ConfigError, mesh_file_settings, parse_overrides, resolve
from willmore_nlp.errors import EXIT_BUG, EXIT_IO, EXIT_USAGE, IO_ERRNOS, PATH_ERRNOS, UserInputError, interrupted

__all__ = ["build_parser", "main"]



def _check_length(args: argparse.Namespace, sets: dict[str, Any]) -> None:
    """``--steps`` and ``--t-end`` of ``run`` and ``compare``: a positive count and a positive finite time, not also
    given by ``--set`` (``sets``: ``--set steps=0 --steps 3`` ran 3 steps silently, a new user's check)."""
    if args.steps is not None and args.steps < 1:
        raise ConfigError(f"--steps must be an integer >= 1 (the total number of steps), got {args.steps}")
    if args.t_end is not None and not 0 < args.t_end < math.inf:
        raise ConfigError(f"--t-end must be a finite number > 0, got {args.t_end}")
    for key, flag in (("steps", "--steps"), ("t_end", "--t-end")):
        if getattr(args, key) is not None and key in sets:
            raise ConfigError(f"{key} is given twice, by --set {key}={sets[key]} and by {flag} {getattr(args, key)}: "
                              "give one")


def cmd_run(args: argparse.Namespace) -> int:
    """Run a problem or config into a new run directory, or continue one (``--resume DIR``)."""
    if args.resume:
        if args.target or args.out or args.set or args.overwrite:
            raise ConfigError("--resume DIR continues a run as configured: give no TARGET, --out, --set or --overwrite "
                              "(--steps/--t-end set a new total length); to go on with other settings, start a new run "
                              f"from one of its states: willmore-nlp export {args.resume} --out state.obj [--step K] "
                              "(a curve: state.txt), then willmore-nlp run state.obj --set ... --out NEW")
        return runner.resume(args.resume, steps=args.steps, t_end=args.t_end, quiet=args.quiet,
                             ignore_late_signals=True)
    if not args.target:
        raise ConfigError("run needs a TARGET (problem name, .toml config or mesh file), or --resume DIR")
    if args.overwrite and not args.out:
        raise ConfigError("--overwrite needs --out DIR (the run directory to start afresh)")
    overrides: dict[str, Any] = parse_overrides(args.set or [])
    _check_length(args, overrides)
    if args.steps is not None:
        overrides["steps"] = args.steps
    if args.t_end is not None:
        overrides["t_end"] = args.t_end
    spec = resolve(args.target, overrides)
    if spec.steps is None and spec.t_end is None:
        raise ConfigError(f"{args.target}: give --steps or --t-end")
    out = args.out or default_run_dir(args.target)
    return runner.start(spec, out, quiet=args.quiet, overwrite=args.overwrite, ignore_late_signals=True,
                        announce=not args.out)


def default_run_dir(target: str, root: str | os.PathLike[str] = "runs") -> Path:
    """The run directory of ``run TARGET`` without ``--out``: ``runs/NAME``, NAME the problem's name or the file's
    stem, or the first of ``runs/NAME-2``, ``runs/NAME-3``, ... that does not exist (a run never lands in a
    directory that holds anything)."""
    base = Path(root) / (Path(target).stem or "run")
    out, k = base, 1
    while out.exists():
        k += 1
        out = base.with_name(f"{base.name}-{k}")
    return out


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                      file: Any = None, line: str | None = None) -> None:
    """Show a warning as one line ``willmore-nlp: warning: ...`` on stderr, on a line of its own above a progress bar
    (tqdm.write; printed directly, it was glued to the bar's line: a new user's check)."""
    from tqdm import tqdm

    tqdm.write(f"willmore-nlp: warning: {message}", file=sys.stderr)


def cmd_problems(args: argparse.Namespace) -> int:
    """List registered problems with their parameters."""
    from willmore_nlp.registry import load_all

    for name, e in sorted(load_all().items()):
        print(f"{name:18s} {e.description}")
        if args.verbose:
            for k, v in e.defaults().items():
                print(f"{'':20s}{k} = {v!r}")
    return 0


def cmd_cache(args: argparse.Namespace) -> int:
    """Show or clear the cache of compiled kernels."""
    from willmore_nlp import codegen

    if args.action == "clear":
        n = codegen.cache_clear()
        print(f"removed {n} compiled librar{'y' if n == 1 else 'ies'} from {codegen.cache_dir()}")
        return 0
    info = codegen.cache_info()
    cc = codegen.find_compiler()
    print(f"cache directory: {info['directory']}")
    print(f"entries: {info['entries']} ({info['bytes'] / 1e6:.1f} MB)")
    for name in info["libraries"]:
        print(f"  {name}")
    print(f"C compiler: {cc or 'none found (kernels run in the CasADi virtual machine)'}")
    print(f"flags: {' '.join(codegen.default_flags())}")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """Export a run directory as VTU files with a PVD time index, or one state as a mesh file."""
    from willmore_nlp.export import MESH_FILE_FORMATS, export_run, export_state

    suffix = Path(args.out).suffix.lower()
    formats = ", ".join(MESH_FILE_FORMATS)
    if suffix in MESH_FILE_FORMATS:
        path, step = export_state(args.run_dir, args.out, args.step, overwrite=args.overwrite)
        print(f"wrote {path} (step {step})")
        return 0
    # any other file suffix is refused (--out x.csv made a folder x.csv); a folder may still end in a number
    # (vtk_h0.5), in '/' or exist already
    if re.fullmatch(r"\.[a-z][a-z0-9]*", suffix) and not args.out.endswith(os.sep) and not Path(args.out).is_dir():
        raise UserInputError(f"--out {args.out}: {suffix} is not a mesh format: give a mesh file ({formats}) for one "
                             "state, or a folder name without a suffix for the VTU files and run.pvd")
    if args.step is not None:
        raise UserInputError(f"--step {args.step}: one state is exported to a mesh file (--out NAME with one of "
                             f"{formats}); the folder export writes every state")
    pvd = export_run(args.run_dir, args.out, overwrite=args.overwrite)
    print(f"wrote {pvd}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    """Write a Markdown + HTML + PNG report of a run directory or a study directory."""
    from willmore_nlp.apps.report import markdown_to_html, write_report
    from willmore_nlp.apps.study import STUDY_FILE, write_study

    if (Path(args.run_dir) / STUDY_FILE).exists():
        md = write_study(args.run_dir)
        md.with_suffix(".html").write_text(markdown_to_html(md.read_text(encoding="utf-8"), "study"), encoding="utf-8")
    else:
        md = write_report(args.run_dir, args.out)
    print(f"wrote {md} and {md.with_suffix('.html')}")
    return 0


def _flow_options(items: dict[str, str]) -> dict[str, Any]:
    """``compare --option`` values: flow options validated here, solver options by each case's solver."""
    from willmore_nlp.config import FLOW_KEYS, parse_option, solver_keys

    known = (set(FLOW_KEYS) | set(solver_keys())) - {"solver"}
    out = {}
    for k, v in items.items():
        if k not in known and not k.startswith("ipopt."):
            raise ConfigError(f"--option {k}: not a flow option or solver option; known: {', '.join(sorted(known))}")
        try:
            out[k] = parse_option(k, v)
        except UserInputError as exc:
            raise ConfigError(f"--option {k}: {exc}") from exc
    return out


def cmd_compare(args: argparse.Namespace) -> int:
    """Run a solver-comparison study on Dask and write its artefacts."""
    from willmore_nlp.apps.study import check_cases, make_grid, run_study
    from willmore_nlp.registry import check_params

    if args.workers < 1:
        raise ConfigError(f"--workers must be an integer >= 1, got {args.workers}")
    if args.evolver is not None and args.evolver < 1:
        raise ConfigError(f"--evolver must be an integer >= 1 (Surface Evolver's gradient iterations), got "
                          f"{args.evolver}")
    problem, sets = args.problem, parse_overrides(args.set or [])
    _check_length(args, sets)
    if Path(problem).suffix.lower() in MESH_SUFFIXES:  # a mesh file, as 'run' takes it: the file problem (it was
        problem, sets = "file", {**sets, **mesh_file_settings(problem, sets)}  # "unknown problem 'm/capsule.obj'",
        # a new user's check)
    params = check_params(problem, sets)
    grid_raw = parse_overrides(args.grid or [])
    grid = {k: [check_params(problem, {k: v})[k] for v in vals.split(",")] for k, vals in grid_raw.items()}
    cases = make_grid(problem, [s.strip() for s in args.solvers.split(",") if s.strip()],
                      [t.strip() for t in args.taus.split(",") if t.strip()], grid, params, args.steps, args.t_end,
                      _flow_options(parse_overrides(args.option or [])))
    check_cases(cases)
    md = run_study(cases, args.out, scheduler=args.scheduler, n_workers=args.workers, progress=not args.quiet,
                   evolver=args.evolver)
    print(f"wrote {md}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Reproduce the paper's Sec. 5 into OUT/REPRODUCTION.md and OUT/figures."""
    from willmore_nlp.apps.reproduce import reproduce

    doc = reproduce(args.out, args.only)
    print(f"wrote {doc}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``willmore-nlp``."""
    ap = argparse.ArgumentParser(prog="willmore-nlp", description=__doc__)
    ap.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                    help="show the version of willmore_nlp and exit")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a problem (registry name, TOML config or mesh file) into a run directory")
    r.add_argument("target", nargs="?",
                   help="problem name (see 'willmore-nlp problems'), a .toml config, or a mesh file (.obj .off .ply "
                   ".stl .npz, or a curve .txt/.xy/.xyz; open meshes need --set clamp=conormal|ring)")
    r.add_argument("--out", help="run directory to write (must be new or empty; default runs/NAME, or runs/NAME-2, "
                   "... when that exists, NAME the problem's name or the file's stem)")
    r.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its last checkpoint "
                   "(after an interruption, a crash or a failure)")
    r.add_argument("--steps", type=int, help="number of steps (total, counting from the initial state); with "
                   "--t-end the run ends at whichever comes first")
    r.add_argument("--t-end", type=float, dest="t_end", help="final time (with --steps: whichever comes first)")
    r.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a parameter (repeatable)")
    r.add_argument("--quiet", action="store_true", help="no progress bar and nothing on standard output (the "
                   "outcome is in DIR/status.json; warnings and errors still go to standard error)")
    r.add_argument("--overwrite", action="store_true", help="if --out holds a run, start it afresh (deletes only "
                   "the files the run wrote, once the new run has been set up)")
    r.set_defaults(func=cmd_run)

    p = sub.add_parser("problems", help="list registered problems")
    p.add_argument("-v", "--verbose", action="store_true", help="also list parameters and defaults")
    p.set_defaults(func=cmd_problems)

    c = sub.add_parser("cache", help="show or clear the cache of compiled element kernels")
    c.add_argument("action", choices=["info", "clear"])
    c.set_defaults(func=cmd_cache)

    e = sub.add_parser("export", help="export a run as VTU files + a PVD time index (ParaView), or one state as a "
                                      "mesh file (a surface: OBJ, OFF, PLY, STL, npz; a curve: text, npz)")
    e.add_argument("run_dir", help="run directory written by 'willmore-nlp run'")
    e.add_argument("--out", required=True, help="output directory (a name without a suffix) for the .vtu files and "
                                                "run.pvd, or a mesh file for one state (a surface: .obj, .off, .ply, "
                                                ".stl, .npz; a curve: .txt, .curve, .xy, .xyz, .npz)")
    e.add_argument("--step", type=int, help="with a mesh file: the step whose state is written (default the last)")
    e.add_argument("--overwrite", action="store_true", help="replace an existing mesh file; for a folder, replace "
                   "the run.pvd and state_*.vtu files of an earlier export there (deleting the state files its run.pvd "
                   "lists that the new export does not write; other files stay). A run's own files and states/ "
                   "folder are never written")
    e.set_defaults(func=cmd_export)

    rp = sub.add_parser("report", help="write a report (Markdown, HTML, PNG figures) of a run or study directory")
    rp.add_argument("run_dir", help="run directory ('willmore-nlp run') or study directory ('willmore-nlp compare')")
    rp.add_argument("--out", help="output directory (default RUN_DIR/report)")
    rp.set_defaults(func=cmd_report)

    cp = sub.add_parser("compare", help="solver-comparison study: solvers x step sizes (x parameters) on Dask")
    cp.add_argument("problem", help="registered problem name, or a mesh file (the 'file' problem, as for 'run')")
    cp.add_argument("--solvers", default="ipopt", help="comma-separated solver names (default ipopt)")
    cp.add_argument("--taus", default="tau", help="comma-separated step sizes: numbers, multiples of the problem's own "
                    "step size (tau, 4tau; the default: tau, the one 'run' takes) or of the mesh size h (4h)")
    cp.add_argument("--grid", action="append", metavar="KEY=V1,V2", help="problem parameter values to vary")
    cp.add_argument("--set", action="append", metavar="KEY=VALUE", help="fixed problem parameter (repeatable)")
    cp.add_argument("--option", action="append", metavar="KEY=VALUE",
                    help="flow/solver option for every case, e.g. max_iter=1000 (repeatable)")
    cp.add_argument("--steps", type=int, help="steps per case (default: the problem's)")
    cp.add_argument("--t-end", type=float, dest="t_end", help="final time per case")
    cp.add_argument("--out", required=True, help="study directory (a rerun skips finished cases)")
    cp.add_argument("--scheduler", help="address of an existing Dask scheduler (default: a LocalCluster)")
    cp.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    cp.add_argument("--evolver", type=int, metavar="N", help="add Surface Evolver's Willmore energy after N "
                    "gradient iterations as a reference (closed surfaces; skipped if evolver is not installed)")
    cp.add_argument("--quiet", action="store_true", help="no progress lines")
    cp.set_defaults(func=cmd_compare)

    rr = sub.add_parser("reproduce", help="reproduce the paper's Sec. 5 (REPRODUCTION.md + figures)")
    rr.add_argument("--out", default="reports", help="output directory (default: reports)")
    rr.add_argument("--only", action="append", help="run only this section (e.g. 'Fig. 2'); repeatable")
    rr.set_defaults(func=cmd_reproduce)
    for cmd in sub.choices.values():  # --debug after the command too (SUPPRESS: one given before it is kept)
        cmd.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks on errors")
    return ap


def _bug() -> int:
    """An internal error (a bug, never the user's input): its traceback, a line saying so, :data:`EXIT_BUG`."""
    traceback.print_exc()
    print("willmore-nlp: internal error (a bug, not a problem with your input): please report it with the "
          "traceback above", file=sys.stderr)
    return EXIT_BUG


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; user errors print one line and exit non-zero (traceback with --debug)."""
    args = build_parser().parse_args(argv)
    shown = warnings.showwarning
    warnings.showwarning = _one_line_warning
    try:
        return int(args.func(args))
    except UserInputError as exc:
        if args.debug:
            raise
        print(f"willmore-nlp: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. 'willmore-nlp problems | head': the reader left
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:
        if args.debug:
            raise
        if exc.errno not in IO_ERRNOS | PATH_ERRNOS:
            return _bug()
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"willmore-nlp: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_IO if exc.errno in IO_ERRNOS else EXIT_USAGE
    except KeyboardInterrupt:
        return interrupted()
    except MemoryError:  # (e.g. --set n=1e9: the input's size, not a bug)
        if args.debug:
            raise
        print("willmore-nlp: error: out of memory: the problem is too large for this machine (fewer vertices, or a "
              "machine with more memory)", file=sys.stderr)
        return EXIT_USAGE
    except Exception:
        if args.debug:
            raise
        return _bug()
    finally:
        warnings.showwarning = shown


if __name__ == "__main__":
    sys.exit(main())
