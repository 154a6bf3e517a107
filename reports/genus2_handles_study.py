"""Genus-2 double tori under the default flow: the holes close in on each other until the bar between them is
about an edge wide, where the mesh folds; the same trajectory at four resolutions.

    python reports/genus2_handles_study.py [--out reports/genus2_handles_study.md] [--hs 0.22,0.15,0.1,0.07]
        [--steps 300] [--figure reports/genus2_handles.png]

Each input is :func:`willmore_nlp.mesh.shapes.double_torus` (two tori R = 1, r = 0.5 about x3 at x = +-1.25, joined
smoothly) meshed at edge ``h``, written to an OBJ file and run as a user runs a file (the ``file`` problem with its
defaults: tau = h, adaptive, newton-krylov with the IPOPT fallback above 500 vertices, the mesh control, the fold
check; ``refine_dihedral = 180``, so that each run keeps its resolution; ``remesh_repair = 2``, the problem's
default for genus 2 when the table was made, 4 since) until the run fails or crawls (ten accepted
steps in a row below h/1,000). After every accepted step the surface is cut by the plane x2 = 0 of its symmetry and
projected on x3 = 0: the segments of the x1-axis that no triangle covers are the two holes seen from above; their
widths and the width of the bar between them (``bar``, the covered gap between the holes) are recorded. Columns of
the table: the time t, each resolution's bar and mean hole width at t (linear interpolation between steps), and for
each run where and why it ended.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from willmore_nlp import FlowError, geometry, registry
from willmore_nlp.mesh import shapes
from willmore_nlp.runner import last_reason

CRAWL, CRAWL_STEPS = 1e-3, 10
"""A run whose step size stays below CRAWL h for CRAWL_STEPS accepted steps is stopped (it crawls at the fold limit)."""


def axis_holes(V: np.ndarray, F: np.ndarray) -> list[tuple[float, float]]:
    """The segments (a, b) of the x1-axis that the projection of the triangles (V (N, 3), F (K, 3)) on x3 = 0 leaves
    uncovered between covered ones, in increasing x1: the holes of a surface whose holes the axis crosses."""
    P = V[F][:, :, :2]
    xs = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        yi, yj = P[:, i, 1], P[:, j, 1]
        cross = (yi <= 0) != (yj <= 0)
        s = np.divide(yi, yi - yj, out=np.zeros_like(yi), where=cross)
        xs.append(np.where(cross, P[:, i, 0] + s * (P[:, j, 0] - P[:, i, 0]), np.nan))
    X = np.stack(xs, axis=1)
    hit = ~np.isnan(X).all(axis=1)
    lo, hi = np.nanmin(X[hit], axis=1), np.nanmax(X[hit], axis=1)
    order = np.argsort(lo)
    holes, end = [], -np.inf
    for a, b in zip(lo[order], hi[order], strict=True):
        if a > end and np.isfinite(end):
            holes.append((float(end), float(a)))
        end = max(end, b)
    return holes


def run(h: float, steps: int, workdir: Path) -> dict:
    """One resolution: the run's records per accepted step and how it ended."""
    mesh = shapes.double_torus(h=h)
    path = workdir / f"double_torus_h{h:g}.obj"
    trimesh.Trimesh(mesh.vertices, mesh.simplices, process=False).export(path)
    pb, _ = registry.build("file", path=str(path), length=1.0)  # (tau = h, as the cached table was made)
    # each resolution as it is (no refinement), with the light repair's 2 passes the table was made with
    flow = pb.make_flow(refine_dihedral=180, remesh_repair=2, rest_dilation=False)  # (the cached table's)
    rows: list[dict[str, float]] = []

    def record(r: object) -> None:
        holes = axis_holes(r.vertices, flow.mesh.simplices)
        q = r.quality
        row = {"step": r.step, "t": r.t, "W": r.willmore, "N": len(r.vertices), "min_angle": q["min_angle"],
               "max_dihedral": q["max_dihedral"], "holes": len(holes)}
        if len(holes) == 2:
            (a1, b1), (a2, b2) = holes
            row.update(bar=a2 - b1, hole=0.5 * ((b1 - a1) + (b2 - a2)))
        rows.append(row)
        print(f"  h={h:g} step {r.step} t={r.t:.4g} W={r.willmore:.5f} bar={row.get('bar', float('nan')):.4f} "
              f"dihedral={q['max_dihedral']:.1f}", flush=True)

    record(flow.state())
    ended = f"{steps} steps"
    t0 = time.perf_counter()
    small = 0
    try:
        for _ in range(steps):
            r = flow.step()
            record(r)
            small = small + 1 if r.tau < CRAWL * mesh.h else 0
            if small == CRAWL_STEPS:
                ended = f"crawls: {CRAWL_STEPS} steps in a row below {CRAWL:g} h (stopped here)"
                break
    except FlowError as exc:
        ended = f"step {exc.step} failed at t = {exc.t:.4g}: {last_reason(exc.rejected, str(exc))}"
    return {"h": h, "N": mesh.n_vertices, "edge": float(mesh.h), "rows": rows, "ended": ended,
            "wall": time.perf_counter() - t0, "W0": geometry.willmore_energy(mesh)}


def at(rows: list[dict], key: str, t: float) -> float:
    """``key`` at time t, linear between the steps around it (NaN outside the run)."""
    ts = np.array([r["t"] for r in rows])
    vs = np.array([r.get(key, np.nan) for r in rows])
    if t > ts[-1]:
        return float("nan")
    return float(np.interp(t, ts, vs))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="reports/genus2_handles_study.md")
    ap.add_argument("--hs", default="0.22,0.15,0.1,0.07")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--figure", default="reports/genus2_handles.png")
    args = ap.parse_args()
    hs = [float(v) for v in args.hs.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        runs = [run(h, args.steps, Path(tmp)) for h in hs]
    lines = ["# Genus-2 double tori: the holes close in until the bar between them is an edge wide", "",
             f"`python reports/genus2_handles_study.py --hs {args.hs} --steps {args.steps}` on "
             f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}; the script's docstring "
             f"defines the columns.", "",
             "| h (vertices) | W at t = 0 | how the run ended | t at the end | W at the end | bar at the end | "
             "bar / mean edge | largest dihedral [deg] | wall [s] |", "|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        last = r["rows"][-1]
        lines.append(f"| {r['h']:g} ({r['N']:,}) | {r['W0']:.4f} | {r['ended']} | {last['t']:.4f} | {last['W']:.4f} | "
                     f"{last.get('bar', float('nan')):.4f} | {last.get('bar', float('nan')) / r['edge']:.2f} | "
                     f"{last['max_dihedral']:.1f} | {r['wall']:.0f} |")
    t_end = min(r["rows"][-1]["t"] for r in runs)
    times = sorted({*np.round(np.linspace(0, t_end, 9), 4)})
    lines += ["", "Bar between the holes and mean hole width along the x1-axis at the same times:", "",
              "| t | " + " | ".join(f"bar, h = {r['h']:g}" for r in runs) + " | "
              + " | ".join(f"hole, h = {r['h']:g}" for r in runs) + " |",
              "|---|" + "---|" * (2 * len(runs))]
    for t in times:
        lines.append(f"| {t:.4f} | " + " | ".join(f"{at(r['rows'], 'bar', t):.4f}" for r in runs) + " | "
                     + " | ".join(f"{at(r['rows'], 'hole', t):.4f}" for r in runs) + " |")
    if args.figure:
        lines += ["", f"![bar between the holes and largest dihedral angle against t]({Path(args.figure).name})"]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        for r in runs:
            t = [row["t"] for row in r["rows"]]
            ax[0].plot(t, [row.get("bar", np.nan) for row in r["rows"]], ".-", label=f"h = {r['h']:g} ({r['N']:,} v)")
            ax[1].plot(t, [row["max_dihedral"] for row in r["rows"]], ".-", label=f"h = {r['h']:g}")
        ax[0].set(xlabel="t", ylabel="bar between the holes", title="double torus: the holes close in")
        ax[1].set(xlabel="t", ylabel="largest dihedral angle [deg]", title="where the mesh folds")
        ax[0].legend()
        fig.tight_layout()
        fig.savefig(args.figure, dpi=90)


if __name__ == "__main__":
    main()
