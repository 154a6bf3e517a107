"""Self-contained report of a run directory: Markdown + PNG figures + an HTML version.

Reads the run only through :func:`willmore_nlp.load_run`. Figures are matplotlib ``Figure`` objects
rendered by the Agg backend (no pyplot, so no global backend switch in the caller's session):
energies and geometry against time, mesh quality against time, solver statistics per step, and
snapshots of the shape (curves as line plots; surfaces rendered shaded from a fixed camera).
"""

from __future__ import annotations

import collections
import html
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from willmore_nlp.mesh.io import make_dirs
from willmore_nlp.references import Reference, references
from willmore_nlp.rundir import Run, load_run


def _col(run: Run, key: str) -> np.ndarray:
    return np.array([float(r[key]) if r.get(key, "") not in ("", None) else np.nan for r in run.history])


def mean_radius(V: np.ndarray) -> float:
    """Mean distance of the vertices ((N, m) array) to their mean."""
    return float(np.linalg.norm(V - V.mean(axis=0), axis=1).mean())


def _save(fig: Figure, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _ref_lines(ax: Any, t: np.ndarray, refs: Sequence[Reference]) -> None:
    for j, ref in enumerate(refs):
        lines = ((ref.smooth, "--", ref.label), (ref.matched, ":", f"mesh-matched: {ref.matched_label}"))
        for value, style, label in lines:
            if value is None:
                continue
            v = np.broadcast_to(np.asarray(value, float), t.shape)
            ax.plot(t, v, style, color=f"C{j + 1}", lw=1.2, label=label)
    if refs:
        ax.legend(fontsize=6)


LOG_SPAN = 10.0
"""A series of :func:`_series_figure`'s ``auto_log`` keys is drawn on a log axis when its positive values span this
factor (a noisy input's energies 1,076 -> 30 -> 27 made the flow after its first steps a flat line at the floor)."""


def _series_figure(run: Run, keys: list[tuple[str, str]], title: str, path: Path, log: tuple[str, ...] = (),
                   refs: Sequence[Reference] = (), extra: dict[str, np.ndarray] | None = None,
                   auto_log: tuple[str, ...] = ()) -> Figure:
    t = run.times
    fig = Figure(figsize=(4.2 * len(keys), 3.2))
    axes = fig.subplots(1, len(keys), squeeze=False)
    for ax, (key, label) in zip(axes[0], keys, strict=True):
        y = extra[key] if extra and key in extra else _col(run, key)
        ax.plot(t, y, "o-", ms=3)
        ax.set_xlabel("t")
        finite = y[np.isfinite(y)]
        positive = finite.size > 0 and bool(np.all(finite > 0))
        spread = positive and key in auto_log and finite.max() >= LOG_SPAN * finite.min()
        ax.set_title(label + (" (log axis)" if spread else ""))
        _ref_lines(ax, t, [r for r in refs if r.column == key])
        if positive and (key in log or spread):
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    _save(fig, path)
    return fig


def snapshot_indices(times: np.ndarray, energies: np.ndarray | None = None, count: int = 4) -> list[int]:
    """Up to ``count`` state indices spaced evenly along the run, first and last included.

    A state is chosen nearest to each of ``count`` equally spaced points of the run's path in (time, energy), each
    scaled by its span (in time alone without energies): a noisy input whose energy fell 564 -> 31 in its first steps
    at t < 1e-6 showed t = 0 and three alike late states, evenly spaced in time (a new user's check). When that gives
    fewer distinct states than wanted (a run whose time is spent in one long step, or stalled with tiny
    steps), states nearest to equally spaced values of ``energies`` are added. Of two chosen states
    within 1e-3 of the run's span in both time and energy only one is kept, so a stalled run shows
    no identical panels.

    Parameters
    ----------
    times : (n,) nondecreasing times of the states
    energies : (n,) energies of the states, optional
    count : wanted number of snapshots
    """
    t = np.asarray(times, float)
    e = np.full(t.shape, np.nan) if energies is None else np.asarray(energies, float)
    n = t.size
    want = min(count, n)
    chosen = {0, n - 1}
    path = t  # with energies: the length along the run's path in (t, e), each scaled by its span
    if np.all(np.isfinite(e)) and n > 1 and np.ptp(e) > 0:
        span_t = np.ptp(t) if np.ptp(t) > 0 else 1.0
        path = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(t) / span_t, np.diff(e) / np.ptp(e)))])
    for target in np.linspace(path[0], path[-1], want)[1:-1]:
        chosen.add(int(np.argmin(np.abs(path - target))))
    if len(chosen) < want and np.all(np.isfinite(e)):
        for target in np.linspace(e[0], e[-1], want)[1:-1]:
            chosen.add(int(np.argmin(np.abs(e - target))))
    # states closer than 1e-3 of the run's span in both time and energy look the same: keep one (the later)
    t_tol = 1e-3 * (t[-1] - t[0])
    e_tol = 1e-3 * np.ptp(e) if np.all(np.isfinite(e)) else np.inf
    out: list[int] = []
    for i in sorted(chosen):
        if out and abs(t[i] - t[out[-1]]) <= t_tol and not abs(e[i] - e[out[-1]]) > e_tol:
            out[-1] = i if out[-1] != 0 else 0
            continue
        out.append(i)
    if out[-1] != n - 1:
        out.append(n - 1)
    return out


def _snapshots(run: Run, path: Path, count: int = 4) -> list[int]:
    idx = snapshot_indices(run.times, _col(run, "energy"), count)
    mesh0 = run.states[0]
    if mesh0.d == 1:
        fig = Figure(figsize=(4.0 * len(idx), 4.0))
        for j, k in enumerate(idx):
            m = run.states[k]
            ax = fig.add_subplot(1, len(idx), j + 1, projection="3d" if m.m == 3 else None)
            seg = m.vertices[m.simplices]
            for s in seg:
                ax.plot(*s.T, "-", color="C0", lw=1.2)
            if m.m == 2:
                ax.set_aspect("equal")
            ax.set_title(f"step {run.history[k]['step']}, t = {run.times[k]:.4g}")
    else:
        fig = Figure(figsize=(4.0 * len(idx), 4.0))
        lo = min(s.vertices.min() for s in run.states)
        hi = max(s.vertices.max() for s in run.states)
        for j, k in enumerate(idx):
            m = run.states[k]
            ax = fig.add_subplot(1, len(idx), j + 1, projection="3d")
            ax.plot_trisurf(*m.vertices.T, triangles=m.simplices, color="0.8", edgecolor="0.35",
                            linewidth=0.15, shade=True)
            ax.view_init(elev=25, azim=-60)  # fixed camera
            ax.set_xlim(lo, hi)
            ax.set_ylim(lo, hi)
            ax.set_zlim(lo, hi)
            ax.set_box_aspect((1, 1, 1))
            # (inside the axes: tight_layout leaves a 3D title above the figure's edge, cut off)
            ax.text2D(0.5, 1.0, f"step {run.history[k]['step']}, t = {run.times[k]:.4g}", transform=ax.transAxes,
                      ha="center", va="top")
    _save(fig, path)
    return idx


def _table(rows: list[list[Any]], header: list[str]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_fmt(v).replace("|", "\\|") for v in r) + " |" for r in rows]
    return "\n".join(out)


def _fmt(v: Any) -> str:
    if isinstance(v, float | np.floating):
        return f"{v:.6g}"
    if isinstance(v, dict) and {"variant", "fixed", "n_vertices"} <= set(v):  # (a boundary's record, json_record)
        given = [k for k in ("conormal", "ring") if v.get(k)]
        return (f"{v['variant']}, {len(v['fixed'])} of {v['n_vertices']} vertices fixed"
                + "".join(f", {k} given" for k in given))
    return str(v)


def _ran_with(ran: Any, given: Any) -> Any:
    """A parameter's value the flow ran with, followed by ``(input: GIVEN)`` where the input's differs as shown."""
    return ran if _fmt(ran) == _fmt(given) else f"{_fmt(ran)} (input: {_fmt(given)})"


FAILED_STATES = ("failed", "interrupted", "abandoned", "crashed")
"""Run states whose report opens with the failure message and the rejected attempts."""


def status_lines(run: Run) -> list[str]:
    """Markdown lines of the run's status: state, message, failed step, rejected attempts, warnings, ignored files."""
    st = run.status
    state = str(st.get("state", "unknown (no status.json)"))
    last = run.history[-1]
    lines = [f"**Status: {state}** after step {last['step']} (t = {float(run.times[-1]):.6g}).", ""]
    if state == "running":
        lines += ["The run is still running, or its process died without a clean exit (`willmore-nlp run "
                  "--resume` continues it).", ""]
    if state in FAILED_STATES or st.get("message"):
        if st.get("message"):
            lines += [f"Message: `{st['message']}`", ""]
        if st.get("failed_step") is not None:
            lines += [f"Failed step: {st['failed_step']}. Steps 0..{last['step']} are kept.", ""]
        rejected = st.get("rejected") or []
        if rejected:
            lines += [f"Rejected attempts of the failed step ({len(rejected)}):", "",
                      _table([[i + 1, r] for i, r in enumerate(rejected)], ["attempt", "reason"]), ""]
    retried = [[r["step"], r["rejected"]] for r in run.history if r.get("rejected") not in (None, "", "nan")]
    if retried:
        lines += [f"Accepted steps that needed retries ({len(retried)}):", "",
                  _table(retried, ["step", "rejected attempts"]), ""]
    if st.get("warnings"):
        lines += [f"Warnings of the run ({len(st['warnings'])}, each once, as shown when it ran):", "",
                  *[f"- `{w}`" for w in st["warnings"]], ""]
    if run.ignored:
        lines += ["Files not trusted (damaged, temporary, or after a gap):", "",
                  *[f"- `{f}`" for f in run.ignored], ""]
    return lines


def _anisotropic(run: Run) -> bool:
    """Whether the run's history has the anisotropic Willmore energy (``willmore_gamma``, NaN for isotropic flows)."""
    return all(isinstance(r.get("willmore_gamma"), float) and np.isfinite(r["willmore_gamma"]) for r in run.history)


def vesicle_lines(run: Run) -> list[str]:
    """The report's vesicle section for a run of the ``vesicle`` problem, or of any closed genus-0 surface flowed with
    both volume and area fixed (a ``file`` run with ``volume`` and ``area``: a new user's capsule had no section),
    isotropic and with c0 = 0 (empty otherwise): the final state's reduced volume v, w / 8 pi and shape, and the
    axisymmetric minimiser's w / 8 pi at that v on the branch of that shape (:mod:`willmore_nlp.vesicle_reference`:
    200 and 400 contour segments, Richardson extrapolated; 2-4 s). A vesicle's report had shown only "the references
    are in docs/guide/vesicles.md" (a new user's check)."""
    from willmore_nlp import geometry
    from willmore_nlp.mesh.shapes import reduced_volume
    from willmore_nlp.mesh.topology import euler_characteristic
    from willmore_nlp.vesicle_reference import classify, extrapolated_energy, hull_share, mesh_shape, symmetry_axis

    cfg = run.config
    options = cfg.get("effective_flow_options") or {}
    M = run.states[-1]
    held = (options.get("volume") is not None and options.get("area") is not None and M.d == 2 and M.m == 3
            and M.is_closed and euler_characteristic(M.simplices) == 2)
    c0 = float(options.get("c0", cfg.get("params", {}).get("c0")) or 0.0)
    if not (cfg.get("problem") == "vesicle" or held) or c0 != 0.0 or options.get("anisotropy") is not None:
        return []
    v = reduced_volume(geometry.measure(M), geometry.enclosed_volume(M))
    w = float(run.history[-1]["willmore_energy"]) / (8 * np.pi)
    shape = mesh_shape(M)
    # the branch of the final shape (it was the start's: a new user's oblate v = 0.9 start relaxed into a prolate and
    # was compared with the oblate branch, 3.8 % off where the prolate's gap is 1.5 %); an open cup is compared with
    # the stomatocyte where that branch exists (followed down from v = 0.6)
    elongated = symmetry_axis(M)[1]
    branch = ("stomatocyte" if shape == "stomatocyte" or (shape == "cup" and v <= 0.6) else
              "prolate" if shape in ("convex", "dumbbell") and elongated else "oblate")
    if shape in ("convex", "dumbbell", "non-convex"):
        shape += (f" ({'prolate: elongated' if elongated else 'oblate: flattened'} along its symmetry axis; its volume "
                  f"{hull_share(M):.4f} of its convex hull's)")
    a, b, extrapolated = extrapolated_energy(v, branch, 200)
    lines = ["## Vesicle", "", _table([
        ["reduced volume v = 6 sqrt(pi) V / A^(3/2) (final state)", f"{v:.6f}"],
        ["w / 8 pi (final state, Willmore energy / 8 pi)", f"{w:.6f}"],
        ["shape of the final state (vesicle_reference.mesh_shape)", shape],
        [f"axisymmetric minimiser on the {branch} branch at this v (200 / 400 segments -> extrapolated)",
         f"{a.energy:.6f} / {b.energy:.6f} -> {extrapolated:.6f} ({classify(b)})"]],
        ["quantity", "value"]), ""]
    if not (a.converged and b.converged):
        lines += ["The axisymmetric solve did not report convergence: the reference is not reliable.", ""]
    return [*lines, "On the vesicle study's meshes the discrete energy lay below the smooth minimiser's (by 1-3 % at "
            "642 vertices) and approached it at second order in h (docs/guide/vesicles.md).", ""]


def write_report(run_dir: str | os.PathLike[str], out: str | os.PathLike[str] | None = None) -> Path:
    """Write ``report.md``, ``report.html`` and ``fig_*.png`` for a run; returns the Markdown path.

    The report opens with the run's status (for a failed, interrupted or abandoned run: the
    message and every rejected attempt), draws the smooth and the mesh-matched reference values
    (:mod:`willmore_nlp.references`) where the target shape is known, plots tau on a log axis, and
    shows snapshots spaced by time (or energy), not by index. ``out`` defaults to ``RUN_DIR/report``.
    """
    run = load_run(run_dir)
    d = Path(out) if out is not None else Path(run_dir) / "report"
    make_dirs(d)
    cfg = run.config
    flow_options = cfg.get("effective_flow_options", cfg.get("flow_options", {}))  # older runs lack the effective
    # a curve's references follow from its start (R0, the k-fold circle); a surface's mesh-matched value is that of the
    # mesh the run ended on (after remeshings its connectivity is not the start's); tau_tilde the last state's
    last_tt = run.history[-1].get("tau_tilde") if run.history else None
    tau_tilde = float(last_tt if isinstance(last_tt, (int, float)) and np.isfinite(last_tt)
                      else cfg.get("tau_tilde") or 0.0)
    refs, ref_note = references(run.states[0] if run.states[0].d == 1 else run.states[-1],
                                float(cfg.get("lam") or 0.0), tau_tilde, run.times, flow_options)
    radius = np.array([mean_radius(s.vertices) for s in run.states])
    figs: list[tuple[str, str]] = []
    # an anisotropic flow lowers w_gamma, not W: both are drawn (its report had shown W alone, rising; a new user)
    gamma = _anisotropic(run)
    _series_figure(run, [("energy", "scheme energy e(X)"), ("willmore_energy", "Willmore energy 1/2 int h^2"),
                         *([("willmore_gamma", "anisotropic Willmore energy 1/2 int h_gamma^2")] if gamma else [])],
                   "Energies", d / "fig_energy.png", refs=refs,
                   auto_log=("energy", "willmore_energy", "willmore_gamma"))
    figs.append(("Energies against time", "fig_energy.png"))
    space = run.states[0].d == 1 and run.states[0].m == 3
    geo = [("measure", "length / area"),
           ("volume", "vector area |1/2 sum x_i x x_(i+1)|" if space else "enclosed area / volume")]
    if any(r.column == "radius" for r in refs):
        geo.append(("radius", "mean distance to the centroid"))
    _series_figure(run, geo, "Geometry", d / "fig_geometry.png", refs=refs, extra={"radius": radius})
    figs.append(("Geometry against time", "fig_geometry.png"))
    qkeys = [(k, k.removeprefix("q_")) for k in run.history[0] if k.startswith("q_")]
    _series_figure(run, qkeys, "Mesh quality", d / "fig_quality.png")
    figs.append(("Mesh quality against time", "fig_quality.png"))
    per_step = {k: _col(run, k) for k in ("iterations", "wall_time", "tau")}
    for v in per_step.values():  # (row 0 is the initial state, not a step: its configured tau was drawn at t = 0
        v[:1] = np.nan  # beside a first step at 1e-7, and 0 iterations and seconds)
    _series_figure(run, [("iterations", "solver iterations"), ("wall_time", "wall time per step [s]"),
                         ("tau", "step size tau (log axis)")], "Solver", d / "fig_solver.png", log=("tau",),
                   extra=per_step)
    figs.append(("Solver statistics per step", "fig_solver.png"))
    idx = _snapshots(run, d / "fig_snapshots.png")
    figs.append(("Shape at t = " + ", ".join(f"{run.times[k]:.4g}" for k in idx), "fig_snapshots.png"))

    # what the flow ran with: input_repair may have remeshed the input and rescaled the step sizes chosen from its
    # edge (config.json's flow_steps; older runs lack it); the input's values follow where they differ
    ran = {"tau": cfg.get("tau", ""), "tau_tilde": cfg.get("tau_tilde", ""), **cfg.get("flow_steps", {})}
    start = run.states[0]
    ran_mesh = {"n_vertices": start.n_vertices, "n_simplices": start.n_simplices, "d": start.d, "m": start.m,
                "h": ran.get("h", start.h)}
    params = [["problem", cfg.get("problem", "")],
              *([k, _ran_with(ran[k], cfg.get(k, ""))] for k in ("tau", "tau_tilde")), ["lam", cfg.get("lam", "")]]
    length = [f"{cfg['steps']} steps" if cfg.get("steps") is not None else "",
              f"t_end = {cfg['t_end']:g}" if cfg.get("t_end") is not None else ""]
    params += [["run length", " or ".join(x for x in length if x)]]  # (the run's, not the problem's default)
    # a parameter that is also a flow option (the vesicle's c0, tangential_weight: None for "the start's default")
    # is shown once, as the flow option the run used
    params += [[k, v] for k, v in sorted(cfg.get("params", {}).items())
               if k not in ("tau", "tau_tilde", "lam", "steps", "t_end") and k not in flow_options]
    params += [[k, v] for k, v in sorted(flow_options.items())]
    params += [[f"mesh {k}", _ran_with(ran_mesh.get(k, v), v)] for k, v in cfg.get("mesh", {}).items()]
    steps = [r for r in run.history if int(r["step"]) > 0]
    first, last = run.history[0], run.history[-1]
    summary: list[list[Any]] = [
        ["states", len(run.states)], ["final time", float(run.times[-1])],
        ["scheme energy (first -> last)", f"{first['energy']:.6g} -> {last['energy']:.6g}"],
        ["Willmore energy (first -> last)", f"{first['willmore_energy']:.6g} -> {last['willmore_energy']:.6g}"],
        *([["anisotropic Willmore energy w_gamma (first -> last; what the flow lowers)",
            f"{first['willmore_gamma']:.6g} -> {last['willmore_gamma']:.6g}"]] if gamma else []),
    ]
    if steps:
        from willmore_nlp.flow import NEWTON_SOLVER

        # (a relaxation's Newton steps on normal motions record 1 iteration each: they are left out)
        timed = [r for r in steps if r.get("solver") != NEWTON_SOLVER]
        it = np.array([float(r["iterations"]) for r in timed] or [np.nan])
        wt = np.array([float(r["wall_time"]) for r in steps])
        summary += [[f"solver iterations per {'time ' if len(timed) < len(steps) else ''}step (mean / max)",
                     f"{it.mean():.3g} / {it.max():.0f}" if timed else "none (Newton steps only)"],
                    ["wall time per step (median / total) [s]", f"{np.median(wt):.3g} / {wt.sum():.3g}"],
                    ["retries (rejected attempts)", int(sum(int(r.get("retries") or 0) for r in steps))]]
        solvers = collections.Counter(r["solver"] for r in steps if r.get("solver"))
        if solvers:  # (runs written before 2026-11-28 have no solver column)
            summary.append(["steps by solver", ", ".join(f"{name} {n}" for name, n in solvers.most_common())])
    else:
        summary.append(["steps taken", "none (only the initial state)"])
    remeshes = [r for r in steps if int(r.get("remeshed") or 0)]
    if remeshes:
        # (a relaxation's move off a saddle or polish, after the repair: its own energy change, not the repair's)
        jumps = [float(r.get("energy_before_move") or r["energy_after_remesh"]) - float(r["energy_before_remesh"])
                 for r in remeshes]
        summary += [["mesh repairs (steps)", f"{len(remeshes)} ({', '.join(str(r['step']) for r in remeshes[:10])}"
                     f"{' ...' if len(remeshes) > 10 else ''})"],
                    ["vertices (first -> last)", f"{first.get('vertices', '')} -> {last.get('vertices', '')}"],
                    ["scheme energy change by repairs (sum / largest)",
                     f"{sum(jumps):.3g} / {max(jumps, key=abs):.3g}"]]
    ref_rows = []
    final = {"willmore_energy": float(last["willmore_energy"]), "radius": float(radius[-1]),
             "willmore_gamma": float(last.get("willmore_gamma", np.nan))}
    for r in refs:
        smooth = float(np.asarray(r.smooth, float).reshape(-1)[-1])
        matched = None if r.matched is None else float(np.asarray(r.matched, float).reshape(-1)[-1])
        ref_rows.append([r.column, final[r.column], f"{smooth:.6g} ({r.label})",
                         "-" if matched is None else f"{matched:.6g} ({r.matched_label})",
                         "-" if matched is None else f"{final[r.column] - matched:+.3g}"])
    md = [f"# Run report: {html.escape(str(cfg.get('problem', run.path.name)))}", "", *status_lines(run),
          f"Run directory: `{run.path}`", "", "## Summary", "", _table(summary, ["quantity", "value"]), "",
          "## References", "", f"Target: {ref_note}.", ""]
    if ref_rows:
        md += [_table(ref_rows, ["quantity", "final", "smooth reference", "mesh-matched reference",
                                 "final - mesh-matched"]), "",
               "The mesh-matched value is the discrete energy of the exact target shape at this run's resolution: "
               "the gap between it and the smooth value is discretisation bias, not an error.", ""]
    md += [*vesicle_lines(run), "## Parameters", "", _table(params, ["parameter", "value"]), ""]
    if cfg.get("input_repair"):
        md += [f"The input mesh was repaired before the first step ({cfg['input_repair']}): "
               "the values are those the flow ran with, the input's in parentheses.", ""]
    for title, f in figs:
        md += [f"## {title}", "", f"![{title}]({f})", ""]
    versions = cfg.get("versions", {})
    if versions:
        md += ["## Versions", "", _table([[k, v] for k, v in versions.items()], ["package", "version"]), ""]
    text = "\n".join(md)
    (d / "report.md").write_text(text, encoding="utf-8")
    (d / "report.html").write_text(markdown_to_html(text, title=f"Run report: {cfg.get('problem', '')}"),
                                   encoding="utf-8")
    return d / "report.md"


def markdown_to_html(text: str, title: str = "report") -> str:
    """HTML of the Markdown subset the reports use: headings, paragraphs, pipe tables, images, code spans."""
    import re

    def inline(s: str) -> str:
        s = html.escape(s, quote=False)
        s = re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", r'<img alt="\1" src="\2" style="max-width:100%">', s)
        s = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", s)
        return re.sub(r"`([^`]+)`", r"<code>\1</code>", s)

    body: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        ln = lines[i]
        if ln.startswith("#"):
            level = len(ln) - len(ln.lstrip("#"))
            body.append(f"<h{level}>{inline(ln[level:].strip())}</h{level}>")
        elif ln.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                if not set(lines[i].replace("|", "").strip()) <= set("-: "):
                    cells = re.split(r"(?<!\\)\|", lines[i].strip()[1:-1])  # "\|" is a pipe inside a cell
                    rows.append([c.strip().replace("\\|", "|") for c in cells])
                i += 1
            body.append("<table>")
            for j, r in enumerate(rows):
                tag = "th" if j == 0 else "td"
                body.append("<tr>" + "".join(f"<{tag}>{inline(c)}</{tag}>" for c in r) + "</tr>")
            body.append("</table>")
            continue
        elif ln.strip():
            body.append(f"<p>{inline(ln)}</p>")
        i += 1
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:2px 8px}")
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
