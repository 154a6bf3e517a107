"""Equilibrium of the ellipsoid 1:1:2: ordinary flow, relax mode and Surface Evolver (issues 15, 17).

    nice python reports/relax_study.py [--cases NAME ...] [--table-only]

Ellipsoid 1:1:2 (an icosphere stretched along x3; 642 and 2,562 vertices, as in
``mesh_quality_study.py``), tau = h, tau_tilde = h^2/100. Cases per mesh:

* ``flow_nobudget``: the ordinary flow with the IPOPT iteration budget and stall test off
  (``iteration_budget=0, stall_iterations=0``: the behaviour before they existed);
* ``flow``: the ordinary flow with the defaults (budget 2 x median, floor 30, none before the first
  accepted step; stall test 15);
* ``relax``: ``relax=true`` with the defaults of its time (time steps: ``relax_newton=false``, the default until
  2026-12-01; tau doubles while steps are accepted, stop after the
  first state whose last 3 steps lowered the Willmore energy by less than 1e-4 relative per nominal
  step, or raised it without a Delaunay flip: ``FlowSettings.relax``);
* ``relax_nk``: the same with ``solver="newton-krylov"``;
* ``relax_nk_quarter``: ``relax_nk`` started at tau = h/4 (then doubling as above);
* ``relax_newton``: ``relax=true, relax_newton=true``: Newton steps on normal motions of the scheme's energy (the
  flow's step where there is none), the relaxation's test and check as for ``relax``;
* ``evolver``: Surface Evolver 2.70 on the same mesh (zero tension, ``star_perp_sq_mean_curvature``
  as the only energy, :mod:`willmore_nlp.evolver`), ``hessian_seek`` repeated 40 times.

The ordinary flows stop at the first state within 1% of the equilibrium energy. The equilibrium
energy ``W_eq`` is the mesh-matched round sphere: the discrete Willmore energy
(:func:`willmore_nlp.geometry.willmore_energy`) of the initial mesh's vertices projected radially
onto a sphere (a sphere is the minimiser for genus 0). Every energy in the table is this library's
discrete Willmore energy of the state's vertices, Evolver's states included (Evolver's own energy,
a different discretisation, is given beside it). Columns: time to within 1% of ``W_eq`` (wall
seconds of the steps for the flows, the step problem's build excluded and given separately;
Evolver's own CPU clock), the CPU time of this process to that point (the comparable figure:
Evolver's is a CPU clock too, and wall times depend on the machine's load), solver iterations to
that point (the rejected attempts' included; newton-krylov: Newton iterations),
the final energy and its distance to ``W_eq`` and to the final mesh's own projected sphere, the
smallest triangle angle over all states (before any mesh repair).

Cases are cached in ``reports/studies/relax/NAME.json`` (delete to rerun).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from mesh_quality_study import ellipsoid, sphere_reference  # the sibling study script (python reports/...)

from willmore_nlp import FlowError, WillmoreFlow, geometry
from willmore_nlp.evolver import evolver_trajectory, find_evolver
from willmore_nlp.mesh.core import Mesh

CACHE = Path("reports/studies/relax")
BAND = 0.01
"""Within 1% of the equilibrium energy."""


def run_flow(mesh: Mesh, max_steps: int, stop_in_band: bool, tau_factor: float = 1.0,
             **options: Any) -> dict[str, Any]:
    """One flow from ``mesh`` (tau = ``tau_factor`` h, tau_tilde = h^2/100) with its figures (see the docstring)."""
    w_eq = sphere_reference(mesh)
    t0 = time.perf_counter()
    # the cached tables predate tangential_control = auto (the surface default since then)
    flow = WillmoreFlow(mesh, tau_factor * mesh.h, 0.01 * mesh.h**2,
                        **{"tangential_control": "off", "rest_dilation": False, "relax_newton": False,
                           **options})  # (the cached table's: time steps unless relax_newton is asked for)
    build = time.perf_counter() - t0
    s0 = flow.state()
    rows: list[dict[str, Any]] = []
    wall = cpu = 0.0
    iters = 0
    t_band = it_band = steps_band = cpu_band = float("nan")
    failed = ""
    min_angle = s0.quality["min_angle"]
    for _ in range(max_steps):
        c0 = time.process_time()
        try:
            r = flow.step()
        except FlowError as exc:
            failed = f"step {exc.step}: {exc.rejected[-1] if exc.rejected else exc}"
            break
        wall += r.wall_time
        cpu += time.process_time() - c0
        iters += r.iterations + r.stats["rejected_iterations"]
        q = r.quality["min_angle"]
        min_angle = min(min_angle, q, r.stats.get("min_angle_before_remesh", q) if r.remeshed else q)
        rows.append({"step": r.step, "t": r.t, "tau": r.tau, "W": r.willmore, "iterations": r.iterations,
                     "rejected": r.rejected, "wall": r.wall_time, "min_angle": r.quality["min_angle"],
                     "remeshed": r.remeshed, "relaxed": r.relaxed})
        print(f"  step {r.step} tau={r.tau:.4g} it={r.iterations} retries={r.retries} W={r.willmore:.6f} "
              f"wall={r.wall_time:.1f} min angle {r.quality['min_angle']:.3g}", flush=True)
        if np.isnan(t_band) and r.willmore <= (1 + BAND) * w_eq:
            t_band, it_band, steps_band, cpu_band = wall, iters, r.step, cpu
            if stop_in_band:
                break
        if r.relaxed:
            break
    final = flow.mesh.with_vertices(flow.X)
    return {"N": mesh.n_vertices, "W0": s0.willmore, "W_eq": w_eq, "build": build, "wall": wall, "cpu": cpu,
            "iterations": iters, "t_band": t_band, "cpu_band": cpu_band, "iterations_band": it_band,
            "steps_band": steps_band,
            "steps": flow.k, "t": flow.t, "W": rows[-1]["W"] if rows else s0.willmore,
            "W_ref_final": sphere_reference(final), "min_angle": float(min_angle), "failed": failed,
            "relaxed": flow.relaxed, "rows": rows, "options": options}


def run_evolver(mesh: Mesh, stages: int = 40) -> dict[str, Any]:
    """Surface Evolver's ``hessian_seek`` repeated ``stages`` times on ``mesh``."""
    w_eq = sphere_reference(mesh)
    tr = evolver_trajectory(mesh, ["hessian_seek"] * stages)
    rows = []
    for o in tr:
        m = mesh.with_vertices(o["vertices"])
        rows.append({"W": geometry.willmore_energy(m), "W_evolver": o["energy"], "cpu": o["cpu"],
                     "min_angle": float(geometry.min_angles(m.vertices, m.simplices).min())})
    band = [k for k, r in enumerate(rows) if r["W"] <= (1 + BAND) * w_eq]
    k = band[0] if band else None
    final = mesh.with_vertices(tr[-1]["vertices"])
    return {"N": mesh.n_vertices, "W0": rows[0]["W"], "W_eq": w_eq, "build": 0.0, "wall": rows[-1]["cpu"],
            "iterations": stages, "t_band": rows[k]["cpu"] if k is not None else float("nan"),
            "cpu_band": rows[k]["cpu"] if k is not None else float("nan"),
            "iterations_band": k if k is not None else float("nan"), "steps_band": k if k is not None else float("nan"),
            "steps": stages, "W": rows[-1]["W"], "W_evolver": rows[-1]["W_evolver"],
            "W_ref_final": sphere_reference(final),
            "min_angle": min(r["min_angle"] for r in rows),
            "min_angle_to_band": min(r["min_angle"] for r in rows[: (k if k is not None else len(rows) - 1) + 1]),
            "failed": "", "rows": rows, "program": find_evolver()}


def cases() -> dict[str, Any]:
    """name -> thunk returning the case's result."""
    out: dict[str, Any] = {}
    for sub in (3, 4):
        n = {3: 642, 4: 2562}[sub]
        out[f"flow_nobudget_{n}"] = lambda sub=sub: run_flow(ellipsoid(sub), 30, True, iteration_budget=0,
                                                             stall_iterations=0)
        out[f"flow_{n}"] = lambda sub=sub: run_flow(ellipsoid(sub), 30, True)
        out[f"relax_{n}"] = lambda sub=sub: run_flow(ellipsoid(sub), 30, False, relax=True)
        out[f"relax_nk_{n}"] = lambda sub=sub: run_flow(ellipsoid(sub), 30, False, relax=True,
                                                        solver="newton-krylov")
        out[f"relax_nk_quarter_{n}"] = lambda sub=sub: run_flow(ellipsoid(sub), 30, False, tau_factor=0.25,
                                                                relax=True, solver="newton-krylov")
        out[f"relax_newton_{n}"] = lambda sub=sub: run_flow(ellipsoid(sub), 30, False, relax=True, relax_newton=True)
        out[f"evolver_{n}"] = lambda sub=sub: run_evolver(ellipsoid(sub))
    return out


def table(results: dict[str, dict[str, Any]]) -> list[str]:
    lines = ["| case | N | steps to 1% | time to 1% [s] | CPU to 1% [s] | iterations to 1% | build [s] | steps run | "
             "W final | W/W_eq - 1 | W/W_ref(final) - 1 | min angle [deg] | relaxed / failed |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        end = "relaxed" if r.get("relaxed") else (r["failed"] or "-")
        cpu = f"{r['t_band']:.3g}" if "evolver" in name else (f"{r['cpu_band']:.3g}" if "cpu_band" in r else "-")
        lines.append(f"| {name.rsplit('_', 1)[0]} | {r['N']} | {r['steps_band']} | {r['t_band']:.3g} | {cpu} | "
                     f"{r['iterations_band'] if 'evolver' not in name else '-'} | {r['build']:.3g} | {r['steps']} | "
                     f"{r['W']:.5f} | {r['W'] / r['W_eq'] - 1:+.2e} | {r['W'] / r['W_ref_final'] - 1:+.2e} | "
                     f"{r['min_angle']:.3g} | {end} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", help="subset of cases (default: all)")
    ap.add_argument("--out", default="reports/relax_study.md")
    ap.add_argument("--table-only", action="store_true", help="only write the table of the cached cases")
    args = ap.parse_args()
    CACHE.mkdir(parents=True, exist_ok=True)
    todo = cases()
    for name in [] if args.table_only else (args.cases or list(todo)):
        f = CACHE / f"{name}.json"
        if f.is_file():
            continue
        print(f"{name} ...", flush=True)
        res = todo[name]()
        f.write_text(json.dumps(res, indent=1))
        print(f"{name}: " + json.dumps({k: v for k, v in res.items() if k != "rows"}), flush=True)
    results = {k: json.loads((CACHE / f"{k}.json").read_text()) for k in todo if (CACHE / f"{k}.json").is_file()}
    lines = ["# Equilibrium of the ellipsoid 1:1:2: flow, relax mode and Surface Evolver", "",
             f"`nice python reports/relax_study.py` on {platform.processor() or platform.machine()} (2 cores shared "
             f"with other jobs: wall times are indicative), {time.strftime('%Y-%m-%d')}; the script's docstring "
             "defines the columns.", ""]
    lines += table(results)
    ev = {k: r for k, r in results.items() if k.startswith("evolver")}
    if ev:
        lines += ["", "Surface Evolver (`hessian_seek` x 40): its own energy (a different discretisation) at the "
                  "end, and the smallest angle up to the first state within 1%:", "",
                  "| N | Evolver's energy (final) | min angle up to 1% [deg] | CPU for 40 hessian_seek [s] |",
                  "|---|---|---|---|"]
        lines += [f"| {r['N']} | {r['W_evolver']:.5f} | {r['min_angle_to_band']:.3g} | {r['wall']:.3g} |"
                  for r in ev.values()]
    lines += ["", "Reading the table: `flow_nobudget` and `flow` accept the same states (the same Willmore energies); "
              "the budget only cuts the attempt that fails (200 IPOPT iterations before, a multiple of the median "
              "after), so compare their iteration counts (wall times depend on the machine's load). `relax` and "
              "`evolver` reach the equilibrium energy; the min angle column shows what the mesh went through. "
              "The flows run with the default mesh control (the light repair after every step, "
              "docs/guide/mesh_quality.md); the runs before it existed are kept in "
              "`reports/studies/relax/superseded/before_light_repair/`. "
              "Interpretation and the history of the defaults: docs/guide/solver_studies.md."]
    Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
