"""Command-line interface: ``willmore-nlp run|problems|...``; a thin layer over the library."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import tomllib

from willmore_nlp.config import ConfigError, RunSpec, parse_overrides, resolve
from willmore_nlp.flow import FlowError, WillmoreFlow
from willmore_nlp.mesh.core import MeshError
from willmore_nlp.registry import ProblemError
from willmore_nlp.rundir import RunError, RunWriter

USER_ERRORS = (ConfigError, MeshError, ProblemError, RunError, FlowError, ValueError, OSError,
               tomllib.TOMLDecodeError)


def flow_kwargs(spec: RunSpec) -> dict[str, Any]:
    """Keyword arguments of :class:`WillmoreFlow` from a resolved spec."""
    kw: dict[str, Any] = dict(spec.problem.flow_options)
    for k, v in spec.flow_options.items():
        kw[k.removeprefix("ipopt.")] = v
    if kw.get("codegen", "unset") is None:
        kw.pop("codegen")
    return kw


def cmd_run(args: argparse.Namespace) -> int:
    """Run a problem or config and write a run directory."""
    overrides: dict[str, Any] = parse_overrides(args.set or [])
    if args.steps is not None:
        overrides["steps"] = args.steps
    if args.t_end is not None:
        overrides["t_end"] = args.t_end
    spec = resolve(args.target, overrides)
    if spec.steps is None and spec.t_end is None:
        raise ConfigError(f"{args.target}: give --steps or --t-end")
    pb = spec.problem
    flow = WillmoreFlow(pb.mesh, pb.tau, pb.tau_tilde, lam=pb.lam, **flow_kwargs(spec))
    writer = RunWriter(args.out, spec.config(), pb.mesh)
    writer.add(flow.state())
    bar = _progress(spec, args.quiet)
    status = 0
    try:
        def on_step(r: Any) -> None:
            writer.add(r)
            bar.update(r.t if spec.t_end is not None else 1)
            bar.set_postfix(step=r.step, t=f"{r.t:.4g}", it=r.iterations, W=f"{r.willmore:.5g}")

        flow.run(t_end=spec.t_end, steps=spec.steps, callback=on_step)
    except FlowError as exc:
        print(f"willmore-nlp: {exc}\n  accepted steps are kept in {args.out}", file=sys.stderr)
        status = 1
    finally:
        bar.close()
    if status == 0 and not args.quiet:
        print(f"wrote {args.out} ({len(writer.rows) - 1} steps)")
    return status


class _Bar:
    """Progress display: steps or simulated time (tqdm; silent with --quiet)."""

    def __init__(self, total: float | None, unit: str, quiet: bool) -> None:
        from tqdm import tqdm

        self.by_time = unit == "t"
        self.bar = tqdm(total=total, unit="" if self.by_time else "step", disable=quiet,
                        bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]"
                        if self.by_time else None)

    def update(self, v: float) -> None:
        if self.by_time:
            self.bar.update(v - self.bar.n)
        else:
            self.bar.update(v)

    def set_postfix(self, **kw: Any) -> None:
        self.bar.set_postfix(**kw)

    def close(self) -> None:
        self.bar.close()


def _progress(spec: RunSpec, quiet: bool) -> _Bar:
    if spec.t_end is not None:
        return _Bar(spec.t_end, "t", quiet)
    return _Bar(spec.steps, "step", quiet)


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


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``willmore-nlp``."""
    ap = argparse.ArgumentParser(prog="willmore-nlp", description=__doc__)
    ap.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a problem (registry name or TOML config) into a run directory")
    r.add_argument("target", help="problem name (see 'willmore-nlp problems') or a .toml config")
    r.add_argument("--out", required=True, help="run directory to write (must be new or empty)")
    r.add_argument("--steps", type=int, help="number of steps")
    r.add_argument("--t-end", type=float, dest="t_end", help="final time")
    r.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a parameter (repeatable)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_run)

    p = sub.add_parser("problems", help="list registered problems")
    p.add_argument("-v", "--verbose", action="store_true", help="also list parameters and defaults")
    p.set_defaults(func=cmd_problems)

    c = sub.add_parser("cache", help="show or clear the cache of compiled element kernels")
    c.add_argument("action", choices=["info", "clear"])
    c.set_defaults(func=cmd_cache)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; user errors print one line and exit non-zero (traceback with --debug)."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except USER_ERRORS as exc:
        if args.debug:
            raise
        print(f"willmore-nlp: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("willmore-nlp: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
