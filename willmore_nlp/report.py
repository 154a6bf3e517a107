"""Self-contained report of a run directory: Markdown + PNG figures + an HTML version.

Reads the run only through :func:`willmore_nlp.load_run`. Figures are matplotlib ``Figure`` objects
rendered by the Agg backend (no pyplot, so no global backend switch in the caller's session):
energies and geometry against time, mesh quality against time, solver statistics per step, and
snapshots of the shape (curves as line plots; surfaces rendered shaded from a fixed camera).
"""

from __future__ import annotations

import html
import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from willmore_nlp.rundir import Run, load_run


def _col(run: Run, key: str) -> np.ndarray:
    return np.array([float(r[key]) if r.get(key, "") != "" else np.nan for r in run.history])


def _save(fig: Figure, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _series_figure(run: Run, keys: list[tuple[str, str]], title: str, path: Path, log: bool = False) -> None:
    t = run.times
    fig = Figure(figsize=(4.2 * len(keys), 3.2))
    axes = fig.subplots(1, len(keys), squeeze=False)
    for ax, (key, label) in zip(axes[0], keys, strict=True):
        y = _col(run, key)
        ax.plot(t, y, "o-", ms=3)
        ax.set_xlabel("t")
        ax.set_title(label)
        if log and np.all(y[np.isfinite(y)] > 0):
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    _save(fig, path)


def snapshot_indices(n: int, count: int = 4) -> list[int]:
    """Up to ``count`` state indices spread evenly over ``n`` states (first and last included)."""
    return sorted({round(float(x)) for x in np.linspace(0, n - 1, min(count, n))})


def _snapshots(run: Run, path: Path, count: int = 4) -> list[int]:
    idx = snapshot_indices(len(run.states), count)
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
            ax.set_title(f"t = {run.times[k]:.4g}")
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
            ax.set_title(f"t = {run.times[k]:.4g}")
    _save(fig, path)
    return idx


def _table(rows: list[list[Any]], header: list[str]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(out)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def write_report(run_dir: str | os.PathLike[str], out: str | os.PathLike[str] | None = None) -> Path:
    """Write ``report.md``, ``report.html`` and ``fig_*.png`` for a run; returns the Markdown path.

    ``out`` defaults to ``RUN_DIR/report``.
    """
    run = load_run(run_dir)
    d = Path(out) if out is not None else Path(run_dir) / "report"
    d.mkdir(parents=True, exist_ok=True)
    figs: list[tuple[str, str]] = []
    _series_figure(run, [("energy", "scheme energy e(X)"), ("willmore_energy", "Willmore energy 1/2 int h^2")],
                   "Energies", d / "fig_energy.png")
    figs.append(("Energies against time", "fig_energy.png"))
    _series_figure(run, [("measure", "length / area"), ("volume", "enclosed area / volume")], "Geometry",
                   d / "fig_geometry.png")
    figs.append(("Geometry against time", "fig_geometry.png"))
    qkeys = [(k, k.removeprefix("q_")) for k in run.history[0] if k.startswith("q_")]
    _series_figure(run, qkeys, "Mesh quality", d / "fig_quality.png")
    figs.append(("Mesh quality against time", "fig_quality.png"))
    _series_figure(run, [("iterations", "solver iterations"), ("wall_time", "wall time per step [s]"),
                         ("tau", "step size tau")], "Solver", d / "fig_solver.png")
    figs.append(("Solver statistics per step", "fig_solver.png"))
    idx = _snapshots(run, d / "fig_snapshots.png")
    figs.append(("Shape at t = " + ", ".join(f"{run.times[k]:.4g}" for k in idx), "fig_snapshots.png"))

    cfg = run.config
    params = [["problem", cfg.get("problem", "")], ["tau", cfg.get("tau", "")], ["tau_tilde", cfg.get("tau_tilde", "")],
              ["lam", cfg.get("lam", "")]]
    params += [[k, v] for k, v in sorted(cfg.get("params", {}).items()) if k not in ("tau", "tau_tilde", "lam")]
    flow_options = cfg.get("effective_flow_options", cfg.get("flow_options", {}))  # older runs lack the effective
    params += [[k, v] for k, v in sorted(flow_options.items())]
    mesh = cfg.get("mesh", {})
    params += [[f"mesh {k}", v] for k, v in mesh.items()]
    steps = [r for r in run.history if int(r["step"]) > 0]
    it = np.array([float(r["iterations"]) for r in steps]) if steps else np.array([np.nan])
    wt = np.array([float(r["wall_time"]) for r in steps]) if steps else np.array([np.nan])
    retries = int(sum(int(r.get("retries") or 0) for r in steps))
    first, last = run.history[0], run.history[-1]
    summary = [
        ["states", len(run.states)], ["final time", float(run.times[-1])],
        ["scheme energy (first -> last)", f"{first['energy']:.6g} -> {last['energy']:.6g}"],
        ["Willmore energy (first -> last)", f"{first['willmore_energy']:.6g} -> {last['willmore_energy']:.6g}"],
        ["iterations per step (mean / max)", f"{np.nanmean(it):.3g} / {np.nanmax(it):.0f}"],
        ["wall time per step (median / total) [s]", f"{np.nanmedian(wt):.3g} / {np.nansum(wt):.3g}"],
        ["retries (tau halved)", retries],
    ]
    md = [f"# Run report: {html.escape(str(cfg.get('problem', run.path.name)))}", "",
          f"Run directory: `{run.path}`", "", "## Parameters", "", _table(params, ["parameter", "value"]), "",
          "## Summary", "", _table(summary, ["quantity", "value"]), ""]
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
                    rows.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
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
