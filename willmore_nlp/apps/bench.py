"""Scale benchmark of one time step (outside the test suite).

    python -m willmore_nlp.bench [--spheres 3 4 5 6] [--torus [96x48]] [--vm-max 10242] [--out reports/benchmark_scale]
                                 [--solvers ipopt newton-krylov] [--ipopt-max 40962] [--control-steps K]

Every case runs in its own subprocess (so peak memory is per case) and measures: build time of the
step problem and solver, compile time of the generated kernels cold (empty cache) and cached, the
wall time of one step (and of the next two, with codegen), IPOPT iterations, the time IPOPT spent
in function evaluations and in its own algorithm (mostly MUMPS), one MUMPS factorisation of the
step's KKT matrix at the solution (CasADi's MUMPS interface, symmetric indefinite mode), and peak
resident memory. Cases with codegen off (CasADi's virtual machine) run up to ``--vm-max`` vertices. The summary fits the
exponent of per-step time against N over the spheres and writes a Markdown table and a CSV.

Every other solver of ``--solvers`` (default: ``newton-krylov``) runs the same step, with generated C,
in its own subprocess of the same run; a second table compares it with IPOPT: step time and speed-up,
its iterations, CG iterations, factorisations and time split, peak memory of both, and the largest
difference of X^{k+1} from IPOPT's, in units of the mean edge length h. Cases above ``--ipopt-max``
vertices run the other solvers alone. A case that fails or runs longer than ``--timeout`` seconds (stopped) becomes
a row saying so, and the others go on. ``--control-steps K`` adds, per case and solver, K steps of the flow with
the surface defaults and the mesh control's share of a step (the light repair, flips and remeshing between
steps). Every row records the machine's 1-minute load average at the start
and end of its case (the machine is shared).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

LATER_STEPS = (2, 3)
"""Steps measured after the first with generated C (the first starts from the input; from step 3 on the
newton-krylov preconditioner is no longer the first step's, so steps 2 and 3 differ)."""


def _blas_threads() -> str:
    """The thread count OpenBLAS takes from the environment (OPENBLAS_NUM_THREADS, else OMP_NUM_THREADS), as text."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        if os.environ.get(var):
            return f"{os.environ[var]} ({var})"
    return "unset (one per core)"


def _mesh(case: str) -> Any:
    from willmore_nlp.mesh import shapes

    kind, arg = case.split(":")
    if kind == "sphere":
        m = shapes.icosphere(int(arg))
        return m.with_vertices(m.vertices * np.array([1.0, 1.0, 1.3]))  # not stationary
    if kind == "torus":
        a, b = (int(x) for x in arg.split("x"))
        return shapes.torus(1.0, 0.5, a, b)
    raise ValueError(f"unknown case {case!r}")


def kkt_factorisation_time(flow: Any, X: np.ndarray, Y: np.ndarray, tau: float, lam_g: np.ndarray) -> float:
    """Seconds IPOPT + MUMPS (same options as the flow) spend on one factorisation of this step's KKT.

    The equality-constrained QP  min 1/2 d.H d + grad.d  s.t.  J d = -g  with H the Lagrangian
    Hessian and J the constraint Jacobian at the step's solution has exactly the KKT matrix
    [[H, J^T], [J, 0]] of the step; IPOPT solves it in one iteration, i.e. one MUMPS analysis
    (METIS) and factorisation. Returns IPOPT's time outside function evaluations per iteration.
    """
    import casadi as ca

    from willmore_nlp.solvers.ipopt import IPOPT_DEFAULTS

    ev, P = flow.evaluator, flow.problem
    p = flow.params(flow.mesh.vertices, tau)
    z = P.pack_z(X, Y)
    H = ca.DM(ev.fn["hess_lag"](z, p, 1.0, lam_g))  # upper triangle
    J = ca.DM(ev.fn["jac_g"](z, p)[1])
    grad = ev.grad_f(z, p)
    d = ca.MX.sym("d", P.nx)
    Hs = ca.MX(H + ca.triu(H, False).T)
    qp = {"x": d, "f": 0.5 * ca.dot(d, ca.mtimes(Hs, d)) + ca.dot(ca.DM(grad), d),
          "g": ca.mtimes(ca.MX(J), d)}
    opts = dict(IPOPT_DEFAULTS, hessian_constant="yes", jac_c_constant="yes")
    S = ca.nlpsol("kkt_qp", "ipopt", qp, {"ipopt": opts, "print_time": False, "record_time": True})
    S(x0=np.zeros(P.nx), lbg=-ev.g(z, p), ubg=-ev.g(z, p))
    st = S.stats()
    evals = sum(st.get(f"t_wall_nlp_{k}", 0.0) for k in ("f", "g", "grad_f", "jac_g", "hess_l", "grad"))
    return (st["t_wall_total"] - evals) / max(int(st["iter_count"]), 1)


def run_case(case: str, codegen: bool, solver: str = "ipopt", save: str | None = None) -> dict[str, Any]:
    """Measure one case in this process (called in a subprocess by :func:`main`).

    ``save``: path of a ``.npy`` file that receives X^{k+1} (for the comparison of solvers).
    """
    from willmore_nlp import WillmoreFlow
    from willmore_nlp import codegen as cgm

    mesh = _mesh(case)
    h = mesh.h
    tau, tt = 0.2 * h, h * h / 100
    row: dict[str, Any] = {"case": case, "N": mesh.n_vertices, "K": mesh.n_simplices, "codegen": codegen,
                           "solver": solver, "h": h, "load": _load()}
    if codegen and solver == "ipopt":
        from willmore_nlp.model.build import build_step

        kernels = build_step(mesh).problem.kernels
        with tempfile.TemporaryDirectory() as cold:
            info: dict[str, Any] = {}
            t0 = time.perf_counter()
            cgm.compile_kernels(kernels, directory=Path(cold), info=info)
            row["compile_cold_s"] = time.perf_counter() - t0
            row["source_bytes"] = info["source_bytes"]
            t0 = time.perf_counter()
            cgm.compile_kernels(kernels, directory=Path(cold), info=info)
            row["compile_cached_s"] = time.perf_counter() - t0
            assert info["cached"]
    t0 = time.perf_counter()
    # the step alone, as measured before the mesh control existed (a repair also drops the multipliers
    # that the KKT timing below needs)
    flow = WillmoreFlow(mesh, tau, tt, codegen=codegen, solver=solver, mesh_control="off")
    if solver == "ipopt":  # (IPOPT's NLP is built at its first solve: counted in the build, as before 2026-11-30)
        flow.solver.build()
    row["build_s"] = time.perf_counter() - t0 - flow.codegen_info.get("compile_time", 0.0)
    r = flow.step()
    st = r.stats
    if save:
        np.save(save, r.vertices)
    for k in LATER_STEPS if codegen else ():  # steps from states the flow reached (the first: from the input)
        rk = flow.step()
        row.update({f"step{k}_s": rk.wall_time, f"iterations{k}": rk.iterations})
        if solver != "ipopt":
            row.update({f"n_cg{k}": rk.stats.get("n_cg"), f"n_precond{k}": rk.stats.get("n_precond_builds", 0),
                        f"factor{k}_s": rk.stats.get("t_wall_factor"), f"cg{k}_s": rk.stats.get("t_wall_cg")})
    if solver != "ipopt":
        row.update(rejected=list(r.rejected), rejected_iterations=st.get("rejected_iterations"),
                   tau_taken=r.tau / tau)
        row.update(step_s=r.wall_time, iterations=r.iterations, retries=r.retries, eval_s=st.get("t_wall_eval"),
                   factor_s=st.get("t_wall_factor"), cg_s=st.get("t_wall_cg"), n_cg=st.get("n_cg"),
                   n_fact=st.get("n_factorizations"), n_precond=st.get("n_precond_builds"), shift=st.get("delta_max"),
                   blas=st.get("blas"), load_end=_load(),
                   peak_rss_gb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)
        return row
    row.update(
        step_s=r.wall_time,
        iterations=r.iterations,
        ipopt_s=st["t_wall_total"],
        eval_s=st["t_wall_eval"],
        solver_s=st["t_wall_solver"],
        n_hess=st["n_eval_hess"],
        eval_fraction=st["t_wall_eval"] / r.wall_time,
    )
    if codegen:
        row["kkt_fact_s"] = kkt_factorisation_time(flow, r.vertices, r.Y, r.tau, flow.lam_g)
        row["step_over_fact"] = r.wall_time / (r.iterations * row["kkt_fact_s"])
    row["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    row["load_end"] = _load()
    return row


def run_control_case(case: str, steps: int, solver: str = "ipopt") -> dict[str, Any]:
    """``steps`` steps of the flow with the surface defaults (mesh control on, tau = 0.2 h, tau_tilde = h^2/100):
    the mean wall time of a step and of its mesh control (``t_wall_control``, part of the step), in this process."""
    from willmore_nlp import WillmoreFlow

    mesh = _mesh(case)
    flow = WillmoreFlow(mesh, 0.2 * mesh.h, mesh.h**2 / 100, solver=solver)
    rs = flow.run(steps=steps)
    step = sum(r.wall_time for r in rs)
    control = sum(r.stats["t_wall_control"] for r in rs)
    return {"case": case, "N": mesh.n_vertices, "solver": solver, "steps": len(rs), "step_s": step / len(rs),
            "control_s": control / len(rs), "control_share": control / step,
            "actions": ", ".join(sorted({a for r in rs for a in r.remeshed.split("+") if a})) or "none",
            "load": _load()}


def control_table(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown lines of :func:`run_control_case` rows."""
    return ["", "The mesh control's share of a step (`--control-steps`: that many steps of the flow with the surface "
            "defaults, in one process per case; means per step; the control is part of the step's wall time):", "",
            "| case | N | solver | steps | step [s] | mesh control [s] | share | actions | load |",
            "|---|---|---|---|---|---|---|---|---|",
            *(f"| {r['case']} | | {r['solver']} | failed: {r['error']} |" if "error" in r else
              f"| {r['case']} | {r['N']} | {r['solver']} | {r['steps']} | {r['step_s']:.3g} | {r['control_s']:.3g} | "
              f"{100 * r['control_share']:.0f} % | {r['actions']} | {r['load']} |" for r in rows)]


def _load() -> str:
    """The machine's 1-minute load average (the benchmark shares the machine: times depend on it)."""
    return f"{os.getloadavg()[0]:.1f}"


def _subprocess(case: str, codegen: bool, timeout: float, solver: str = "ipopt",
                save: str | None = None, control_steps: int = 0) -> dict[str, Any]:
    """Measure one case in a subprocess (:func:`run_case`, or :func:`run_control_case` with ``control_steps``).

    Returns
    -------
    The case's row, or a row with ``error`` (the last line of the subprocess's stderr, or that it timed out after
    ``timeout`` seconds and was stopped) and ``total_s``: a failing case does not stop the benchmark.
    """
    cmd = [sys.executable, "-m", "willmore_nlp.apps.bench", "--one", case, "--codegen", str(int(codegen)),
           "--solver", solver, "--control-steps", str(control_steps)] + (["--save", save] if save else [])
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"case": case, "codegen": codegen, "solver": solver,
                "error": [f"timed out after {timeout:g} s (--timeout), stopped"], "total_s": time.perf_counter() - t0}
    if r.returncode != 0:
        return {"case": case, "codegen": codegen, "solver": solver, "error": r.stderr.strip().splitlines()[-1:],
                "total_s": time.perf_counter() - t0}
    row = json.loads(r.stdout.strip().splitlines()[-1])
    row["total_s"] = time.perf_counter() - t0
    return row


COLUMNS = [
    ("case", "case"), ("N", "N"), ("codegen", "codegen"), ("build_s", "build [s]"),
    ("compile_cold_s", "compile cold [s]"), ("compile_cached_s", "compile cached [s]"), ("step_s", "step [s]"),
    ("iterations", "IPOPT it"), ("eval_s", "f/g/J/H eval [s]"), ("solver_s", "IPOPT+MUMPS [s]"),
    ("eval_fraction", "eval share"), ("kkt_fact_s", "1 KKT fact [s]"), ("step_over_fact", "step/(it x fact)"),
    ("peak_rss_gb", "peak RSS [GB]"),
]


SOLVER_COLUMNS = [
    ("case", "case"), ("N", "N"), ("solver", "solver"), ("ipopt_step_s", "IPOPT step [s]"), ("step_s", "step [s]"),
    ("speedup", "speed-up"), ("iterations", "Newton it"), ("n_cg", "CG it"), ("n_fact", "J_Y fact"),
    ("n_precond", "B fact"), ("shift", "max shift"), ("eval_s", "eval [s]"), ("factor_s", "fact [s]"),
    ("cg_s", "CG [s]"),
    ("ipopt_rss_gb", "IPOPT peak RSS [GB]"), ("peak_rss_gb", "peak RSS [GB]"), ("dx_h", "max abs dX / h"),
    *[col for k in LATER_STEPS for col in (
        (f"ipopt_step{k}_s", f"IPOPT step {k} [s]"), (f"step{k}_s", f"step {k} [s]"), (f"speedup{k}", f"speed-up {k}"),
        (f"ipopt_iterations{k}", f"IPOPT it {k}"), (f"iterations{k}", f"Newton it {k}"), (f"n_cg{k}", f"CG it {k}"),
        (f"n_precond{k}", f"B fact {k}"))],
    ("blas", "BLAS"), ("ipopt_load", "IPOPT load"), ("load", "load"),
]


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v) if v is not None else ""


def write_report(rows: list[dict[str, Any]], out: Path, command: str) -> str:
    """Markdown table + CSV; returns the Markdown."""
    out.parent.mkdir(parents=True, exist_ok=True)
    keys = [k for k, _ in COLUMNS]
    keys += [k for k, _ in SOLVER_COLUMNS if k not in keys]
    with open(out.with_suffix(".csv"), "w", newline="", encoding="utf-8") as fh:
        wr = csv.DictWriter(fh, fieldnames=[*keys, "error", "total_s"], extrasaction="ignore")
        wr.writeheader()
        wr.writerows(rows)
    import casadi

    all_rows, rows = rows, [r for r in rows if r.get("solver", "ipopt") == "ipopt"]

    lines = [
        "# Scale benchmark: one time step of the nested scheme",
        "",
        f"Command: `{command}`",
        "",
        f"Machine: {platform.platform()}, {os.cpu_count()} cores; Python {platform.python_version()}, "
        f"CasADi {casadi.__version__}, numpy {np.__version__}; BLAS threads (`OPENBLAS_NUM_THREADS`, else "
        f"`OMP_NUM_THREADS`, read by CasADi's OpenBLAS under MUMPS): {_blas_threads()}. "
        "Sphere = icosphere scaled 1:1:1.3 in z, "
        "torus R = 1, r = 0.5; tau = 0.2 h, tau_tilde = h^2/100 (the library's default for surfaces), "
        "IPOPT tol 1e-9, MUMPS with METIS ordering. '1 KKT fact' is IPOPT + MUMPS (same options) solving "
        "the equality-constrained QP whose KKT matrix is the step's [[H, J^T], [J, 0]] at the solution: "
        "one iteration = one METIS analysis + factorisation + solve, measured in the same process.",
        "",
        "| " + " | ".join(t for _, t in COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | | {r['codegen']} | failed: {r['error']} |")
            continue
        lines.append("| " + " | ".join(_fmt(r.get(k)) for k, _ in COLUMNS) + " |")
    sph = [r for r in rows if r.get("codegen") and str(r["case"]).startswith("sphere") and "step_s" in r]
    if len(sph) >= 2:
        from willmore_nlp.analysis import fit_order

        expo = fit_order([r["N"] for r in sph], [r["step_s"] for r in sph])
        lines += ["", f"Fitted exponent of per-step wall time vs N (spheres, codegen): **{expo:.2f}**"]
    on = {r["case"]: r for r in rows if r.get("codegen") and "eval_s" in r}
    off = {r["case"]: r for r in rows if r.get("codegen") is False and "eval_s" in r}
    sp_rows = [
        f"| {c} | {off[c]['eval_s'] / off[c]['n_hess']:.3g} | {on[c]['eval_s'] / on[c]['n_hess']:.3g} | "
        f"{(off[c]['eval_s'] / off[c]['n_hess']) / (on[c]['eval_s'] / on[c]['n_hess']):.1f}x |"
        for c in on if c in off
    ]
    if sp_rows:
        lines += ["", "Function evaluation per IPOPT iteration, virtual machine vs generated C:", "",
                  "| case | VM [s/it] | C [s/it] | speed-up |", "|---|---|---|---|", *sp_rows]
    lines += _solver_table(all_rows)
    text = "\n".join(lines) + "\n"
    out.with_suffix(".md").write_text(text, encoding="utf-8")
    return text


def _solver_table(rows: list[dict[str, Any]]) -> list[str]:
    """Markdown lines comparing the other solvers' rows (with ``speedup`` etc. filled in) with IPOPT."""
    other = [r for r in rows if r.get("solver", "ipopt") != "ipopt"]
    if not other:
        return []
    lines = ["", "Other step solvers on the same step (generated C, own subprocess each): speed-up = IPOPT step / "
             "step; 'max abs dX / h' = largest difference of X^{k+1} from IPOPT's (tol 1e-9 both) in mean edge "
             "lengths; 'J_Y fact' and 'B fact' = factorisations of M + tt L and of the preconditioner; 'max shift' = "
             "largest shift delta of the Newton systems of step 1 (in units of D). "
             "'step 2', 'step 3': the next steps of the same flow (from X^1 and X^2, as in a running flow; the "
             "first step starts from the initial mesh); peak RSS covers all three steps.", "",
             "| " + " | ".join(t for _, t in SOLVER_COLUMNS) + " |", "|" + "---|" * len(SOLVER_COLUMNS)]
    for r in other:
        if "error" in r:
            lines.append(f"| {r['case']} | | {r['solver']} | failed: {r['error']} |")
            continue
        lines.append("| " + " | ".join(_fmt(r.get(k)) for k, _ in SOLVER_COLUMNS) + " |")
    from willmore_nlp.analysis import fit_order

    for name in dict.fromkeys(r["solver"] for r in other):
        sph = [r for r in other if r["solver"] == name and str(r["case"]).startswith("sphere") and "step_s" in r]
        if len(sph) >= 2:
            fits = [f"step {k} **{fit_order([r['N'] for r in sph], [r[key] for r in sph]):.2f}**"
                    for k, key in ((1, "step_s"), *((k, f"step{k}_s") for k in LATER_STEPS))
                    if all(key in r for r in sph)]
            lines += ["", f"Fitted exponent of {name}'s step time vs N (spheres): " + ", ".join(fits)]
    return lines


def _compare(row: dict[str, Any], ref: dict[str, Any], x: Path, x_ref: Path) -> None:
    """Fill ``row`` (another solver) with its speed-up over and difference from the IPOPT row ``ref``."""
    row["load"] = f"{row.get('load')}-{row.get('load_end')}"
    if "error" in row or "error" in ref or not ref:
        return
    row["ipopt_step_s"] = ref["step_s"]
    row["ipopt_rss_gb"] = ref["peak_rss_gb"]
    row["speedup"] = ref["step_s"] / row["step_s"]
    row["dx_h"] = float(np.abs(np.load(x) - np.load(x_ref)).max()) / row["h"]
    row["ipopt_load"] = f"{ref.get('load')}-{ref.get('load_end')}"
    for k in LATER_STEPS:
        if f"step{k}_s" in ref and f"step{k}_s" in row:
            row[f"ipopt_step{k}_s"] = ref[f"step{k}_s"]
            row[f"ipopt_iterations{k}"] = ref[f"iterations{k}"]
            row[f"speedup{k}"] = ref[f"step{k}_s"] / row[f"step{k}_s"]


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark grid (or one case with --one) and print/save the table."""
    ap = argparse.ArgumentParser(prog="python -m willmore_nlp.bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spheres", type=int, nargs="*", default=[3, 4, 5, 6],
                    help="icosphere subdivisions (3: 642, 4: 2562, 5: 10242, 6: 40962 vertices)")
    ap.add_argument("--torus", nargs="*", default=["96x48"],
                    help="torus grids n_major x n_minor (default 96x48, 4,608 vertices, also when only --spheres is "
                         "given; a small one: --torus 24x12; none: --torus with no grid)")
    ap.add_argument("--vm-max", type=int, default=10242, help="largest N also run without codegen")
    ap.add_argument("--ipopt-max", type=int, default=40962,
                    help="largest N run with IPOPT (larger cases: the other solvers alone, without comparison)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per case")
    ap.add_argument("--out", default="reports/benchmark_scale", help="output path without suffix (.md, .csv)")
    ap.add_argument("--solvers", nargs="*", default=["ipopt", "newton-krylov"],
                    help="step solvers to run on every case (IPOPT always; the others with generated C only)")
    ap.add_argument("--control-steps", type=int, default=0,
                    help="also run this many steps of the flow with the surface defaults per case and solver and "
                         "report the mesh control's share of a step (0: not)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--codegen", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--solver", default="ipopt", help=argparse.SUPPRESS)
    ap.add_argument("--save", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        if args.control_steps:
            print(json.dumps(run_control_case(args.one, args.control_steps, args.solver)))
        else:
            print(json.dumps(run_case(args.one, bool(args.codegen), args.solver, args.save)))
        return 0
    cases = [f"sphere:{s}" for s in args.spheres] + [f"torus:{t}" for t in args.torus]
    others = [s for s in args.solvers if s != "ipopt"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            n_vert = _mesh(case).n_vertices
            x_ref = Path(tmp) / "ipopt.npy"
            ref: dict[str, Any] = {}
            for cg in (True, False):
                if (not cg and n_vert > args.vm_max) or n_vert > args.ipopt_max:
                    continue
                row = _subprocess(case, cg, args.timeout, save=str(x_ref) if cg else None)
                rows.append(row)
                ref = row if cg else ref
                print(json.dumps(row), flush=True)
            for name in others:
                x = Path(tmp) / "other.npy"
                row = _subprocess(case, True, args.timeout, solver=name, save=str(x))
                _compare(row, ref, x, x_ref)
                rows.append(row)
                print(json.dumps(row), flush=True)
        control = []
        for case in cases if args.control_steps else []:
            for name in args.solvers:
                control.append(_subprocess(case, True, args.timeout, solver=name, control_steps=args.control_steps))
                print(json.dumps(control[-1]), flush=True)
    command = "python -m willmore_nlp.bench " + " ".join(sys.argv[1:] if argv is None else argv)
    text = write_report(rows, Path(args.out), command.strip())
    if control:
        text += "\n".join(control_table(control)) + "\n"
        Path(args.out).with_suffix(".md").write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
