"""Mesh-quality control of surfaces with the defaults on: long flows on general meshes (issue 14).

    nice python reports/mesh_quality_study.py [--cases NAME ...] [--scale 1.0] [--table-only]
    nice python reports/mesh_quality_study.py --diagnose     # why single steps degrade the mesh
    nice python reports/mesh_quality_study.py --first-step   # the first step against tangential_weight

Every case runs with the library defaults (mesh control "auto", tau = h unless stated,
tau_tilde = h^2/100) and, where the issue asks for it, the same case with ``mesh_control=off``
(the paper's scheme). Columns:

* steps, t: accepted steps and final time; "failed" gives the one-line reason when a step failed;
* min angle: the smallest triangle angle over the whole run, *before* any repair (so the
  worst mesh the solver ever produced, the initial mesh included), and the smallest after repairs;
  "steps" columns: the same over the states produced by steps (the initial mesh excluded);
* remeshes (column "repaired states"): states after which the mesh control acted (the light repair, flips
  or an isotropic remeshing; the torus series count isotropic remeshings separately);
* W final vs ref: the final Willmore energy and its relative difference to the mesh-matched
  reference: the final mesh's vertices projected onto the limit surface (the round sphere for
  genus 0; the Clifford torus R/r = sqrt 2 fitted to the cross-section for the torus; the exact
  torus for the restoration); NaN where no closed-form limit exists (genus 2, blends);
* stationarity: relative change of the Willmore energy in the last step.

Cases ``KEY_beta1``, ``KEY_beta10``, ``KEY_beta100`` (KEY in :data:`BETA_CASES`) rerun the genus-0 and boundary
cases with today's defaults and tangential_weight 1, 10, 100 (own table, with the final shapes compared).

Finished cases are cached in ``reports/studies/mesh_quality/NAME.json`` (delete to rerun);
``--scale`` multiplies the run lengths (e.g. 0.25 for a quick look).
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from willmore_nlp import FlowError, WillmoreFlow, geometry, registry
from willmore_nlp.analysis import (
    clifford_reference,
    conformal_ratios,
    fit_order,
    minimal_s3_fit,
    sector_ratios,
    torus_fit,
    torus_frame,
    torus_grid_asymmetry,
    torus_projection,
)
from willmore_nlp.analysis import surface_distance as mesh_distance
from willmore_nlp.analysis import torus_distance as exact_torus_distance
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.mesh.io import save_mesh

CACHE = Path("reports/studies/mesh_quality")
BETAS = (1.0, 10.0, 100.0)
"""tangential_weight values of the weight study (issue 14: is a weight > 1 the right surface default?)."""
REST = 1e-8
"""Stationarity target of issue 14: relative change of the Willmore energy per step below this."""
STATES: Path | None = None  # --save-states DIR: the torus states at the series' times (npz), for later analysis


def ellipsoid(subdivisions: int) -> Mesh:
    """Ellipsoid 1:1:2: an icosphere stretched by 2 along x3 (642 or 2562 vertices)."""
    s = shapes.icosphere(subdivisions)
    V = np.array(s.vertices)
    V[:, 2] *= 2.0
    return Mesh(V, s.simplices, f"ellipsoid 1:1:2 ({s.n_vertices} v)")


def capsule() -> Mesh:
    """trimesh's capsule (height 1, radius 1, count 16 x 32: 514 vertices, min angle 5 deg)."""
    c = trimesh.creation.capsule(height=1.0, radius=1.0, count=[16, 32])
    return Mesh(np.asarray(c.vertices), np.asarray(c.faces), "trimesh capsule")


def noisy_capsule(seed: int = 0) -> Mesh:
    """trimesh's capsule (height 2, radius 0.6, count 24 x 24: 578 v) with its vertices moved along their normals
    by Gaussian noise of standard deviation 0.06 h (h = mean edge; largest offset about 0.2 h). The user's
    ``capsule_noisy.obj`` of the issue follow-up is this mesh with another draw (normal offsets of standard
    deviation 0.059 h, largest 0.19 h): initial W = 158.6 (160.5 there), min angle 4.39 deg (4.38), edge ratio 100."""
    c = trimesh.creation.capsule(height=2.0, radius=0.6, count=[24, 24])
    V, n = np.asarray(c.vertices), np.asarray(c.vertex_normals)
    h = Mesh(V, np.asarray(c.faces)).h
    offset = 0.06 * h * np.random.default_rng(seed).standard_normal(len(V))
    return Mesh(V + offset[:, None] * n, np.asarray(c.faces), "noisy capsule")


def smoothed_box() -> Mesh:
    """A unit box subdivided 3 times (386 v) and Laplacian-smoothed 10 times (trimesh)."""
    b = trimesh.creation.box().subdivide().subdivide().subdivide()
    trimesh.smoothing.filter_laplacian(b, iterations=10)
    return Mesh(np.asarray(b.vertices), np.asarray(b.faces), "smoothed box")


BETA_GENUS0 = {"ellipsoid642": lambda: ellipsoid(3), "capsule": capsule, "capsule_noisy": noisy_capsule,
               "box": smoothed_box}
BETA_BOUNDARY: dict[str, tuple[str, int, bool, dict[str, Any]]] = {
    "blend_conormal": ("surface_blending", 200, False, {"variant": "conormal"}),
    "blend_ring": ("surface_blending", 200, False, {"variant": "ring"}),
    "torus_hole": ("torus_hole", 100, True, {"fill": "noisy"}),
    "torus_hole_flat": ("torus_hole", 100, True, {"fill": "flat"}),
    "blend_conormal_400": ("surface_blending", 400, False, {"variant": "conormal"}),
    "blend_ring_400": ("surface_blending", 400, False, {"variant": "ring"})}
"""The weight study's cases: problem, steps at scale 1, exact-torus reference?, parameters (as the beta = 1 rows)."""
BETA_CASES = [*BETA_GENUS0, *BETA_BOUNDARY]


def sphere_reference(mesh: Mesh) -> float:
    """Willmore energy of the mesh's vertices projected radially onto a sphere about their centroid."""
    V = mesh.vertices - mesh.vertices.mean(axis=0)
    return geometry.willmore_energy(Mesh(V / np.linalg.norm(V, axis=1, keepdims=True), mesh.simplices))


def grid_minimum(n: int) -> tuple[float, float, float]:
    """Minimiser of the discrete Willmore energy over the tori of revolution meshed on the n x n/2 grid.

    Returns (R/r at the minimum, the minimum, W at R/r = sqrt 2). The energy is scale invariant, so
    r = 1 and R = R/r; a bounded scalar minimisation to 1e-7 in R/r.
    """
    from scipy.optimize import minimize_scalar

    def w(q: float) -> float:
        return geometry.willmore_energy(shapes.torus(q, 1.0, n, n // 2))

    res = minimize_scalar(w, bounds=(1.2, 1.7), method="bounded", options={"xatol": 1e-7})
    return float(res.x), float(res.fun), w(np.sqrt(2))


def grid_table() -> list[str]:
    """The grid minimisers of :func:`grid_minimum` for n = 16 ... 96 and the fitted order of sqrt 2 - R/r."""
    ns = [16, 24, 32, 48, 64, 96]
    rows = [grid_minimum(n) for n in ns]
    out = ["| grid | R/r at the minimum | sqrt 2 - R/r | order (vs previous) | W min | W(sqrt 2) | 4 pi^2 |",
           "|---|---|---|---|---|---|---|"]
    prev: tuple[int, float] | None = None
    for n, (q, wmin, wc) in zip(ns, rows, strict=True):
        d = np.sqrt(2) - q
        order = "" if prev is None else f"{np.log(prev[1] / d) / np.log(n / prev[0]):.2f}"
        out.append(f"| {n}x{n // 2} | {q:.5f} | {d:.5f} | {order} | {wmin:.4f} | {wc:.4f} | {4 * np.pi**2:.4f} |")
        prev = (n, d)
    return out


def frame_measures(t: float, V: np.ndarray, F: np.ndarray, W: float, h: float) -> list[float]:
    """A torus state measured in the frame of its fitted torus of revolution (:func:`torus_frame`: free centre and
    axis): [t, R/r, sector R/r min, max, conformal R/r min, max, W, W_ref (the mesh on the Clifford torus of that
    frame and tube radius), distance of the fitted centre from the origin, tilt of the axis from x3 (deg), rms
    distance of the vertices from the fitted torus / h]. The study's other measures take the axis x3 through the
    origin (circle fit, W_ref) or the vertex centroid (sectors): a translation or tilt of the torus, or vertices
    gathering on one side of it, reads there as a departure from the tori of revolution."""
    U, c, a, R, r, d = torus_frame(V)
    sec, conf = sector_ratios(U, centred=True), conformal_ratios(U, centred=True)
    return [t, R / r, float(sec.min()), float(sec.max()), float(conf.min()), float(conf.max()), W,
            clifford_reference(U, F), float(np.linalg.norm(c)), float(np.degrees(np.arccos(min(1.0, abs(a[2]))))),
            float(np.sqrt(np.mean(d**2))) / h]


def frame_from_states(directory: Path, names: list[str]) -> None:
    """Add ``frame`` (:func:`frame_measures` at each saved time) to the cached torus cases ``names`` from the states
    that ``--save-states`` wrote to ``directory`` (for runs made before the callback recorded it)."""
    for key in names:
        f = CACHE / f"{key}.json"
        res = json.loads(f.read_text())
        rows = []
        for x in res["series"]:
            st = np.load(directory / f"{res['name'].replace(' ', '_')}_t{x[0]:.4f}.npz")
            rows.append(frame_measures(x[0], st["vertices"], st["simplices"], x[2], res["h"]))
            print(f"  {key}: frame {rows[-1]}", flush=True)
        res["frame"] = rows
        f.write_text(json.dumps(res, indent=1))


def frame_table(tor: list[dict[str, Any]]) -> list[str]:
    """The torus cases' :func:`frame_measures` next to the fixed-axis circle fit and centroid sectors."""
    out = ["| case | t | R/r, fixed axis (sectors about the centroid) | R/r in the torus's frame (sectors; conformal) "
           "| W/W_ref - 1 (fixed axis / frame) | W/W_grid - 1 | centre moved, tilt | rms distance / h |",
           "|---|---|---|---|---|---|---|---|"]
    for r in tor:
        for x, y in zip(r["series"], r.get("frame", []), strict=False):
            out.append(f"| {r['name']} | {y[0]:.3g} | {x[1]:.3f} ({x[6]:.3f}-{x[7]:.3f}) | {y[1]:.4f} ({y[2]:.3f}-"
                       f"{y[3]:.3f}; {y[4]:.3f}-{y[5]:.3f}) | {x[2] / x[5] - 1:+.2%} / {y[6] / y[7] - 1:+.2%} | "
                       f"{y[6] / r['clifford_grid'] - 1:+.2%} | {y[8]:.3f}, {y[9]:.2f} deg | {y[10]:.3f} |")
    return out


def resolution_table(tor: list[dict[str, Any]], times: tuple[float, ...] = (0.1, 0.2, 0.5, 1.0)) -> list[str]:
    """R/r, sector spread, conformal R/r, W/W_ref - 1, min angles, asymmetry and (where recorded) mean IPOPT
    iterations per step, retries and wall time so far of the torus cases' series at ``times`` (within 1% + 1e-3)."""
    out = ["| case | " + " | ".join(f"t = {t:g}" for t in times) + " |", "|---" * (len(times) + 1) + "|"]
    for r in tor:
        ser = [x for x in r.get("series", []) if len(x) > 7]
        if not ser:
            continue
        cells = []
        for t in times:
            x = next((x for x in ser if abs(x[0] - t) <= 0.01 * t + 1e-3), None)
            cells.append("" if x is None else
                         f"{x[1]:.3f} ({x[6]:.2f}-{x[7]:.2f}"
                         + (f"; conformal {x[8]:.3f}-{x[9]:.3f}" if len(x) > 9 else "")
                         + f"), {x[2] / x[5] - 1:+.2%}, {x[3]:.3g} / {x[4]:.3g} deg"
                         + (f", asym {x[10]:.1e}" if len(x) > 10 and np.isfinite(x[10]) else "")
                         + (f", {x[12]:.1f} it/step, {x[13]:.0f} retries, {x[11]:.0f} s" if len(x) > 13 else ""))
        out.append(f"| {r['name']} | " + " | ".join(cells) + " |")
    return out


LAWSON_21 = 2 * 21.9
"""Willmore energy of Lawson's genus-2 surface xi_{2,1} in this library's normalisation w = 1/2 int (k1 + k2)^2
(a round sphere 8 pi): 21.9 in int H^2, H the mean of the principal curvatures (Hsu, Kusner, Sullivan 1992,
Experimental Math. 1:191-207), times 2."""


def lawson_start(out: Path = shapes.LAWSON_GENUS2_DATA) -> None:
    """Make the stored surface of :func:`willmore_nlp.mesh.shapes.lawson_genus2` (about 5 min of CPU).

    The 839-v :func:`~willmore_nlp.mesh.shapes.double_torus` flows (adaptive from tau = h, tangential_weight 100)
    toward a stereographic image of a minimal surface in S^3 whose bar across the hole gets thinner than the
    edges; its state of smallest minimal-S^3 residual (:func:`~willmore_nlp.analysis.minimal_s3_fit`, within
    the first 25 steps) is subdivided twice (Loop), lifted to S^3 with the fitted centre and radius and
    projected back from the point of S^3 farthest from it (the best of 200,000 seeded random points;
    :func:`~willmore_nlp.geometry.stereographic_reprojection`), put on its principal axes, remeshed to h = 0.2
    and flowed 5 steps with ``conformal_gauge``."""
    import gpytoolbox
    from scipy.spatial import cKDTree

    from willmore_nlp.analysis import minimal_s3_fit
    from willmore_nlp.remesh import isotropic_remesh

    dt = shapes.double_torus(h=0.22)
    flow = WillmoreFlow(dt, dt.h, 0.01 * dt.h**2, adaptive=True, max_retries=12, tangential_weight=100.0,
                        tangential_control="off", rest_dilation=False)  # how the stored surface was made (before
    # the control's and the rest rule's defaults)
    best: tuple[float, np.ndarray, np.ndarray] = (np.inf, dt.vertices, dt.simplices)
    for _ in range(25):
        r = flow.step()
        fit = minimal_s3_fit(r.vertices, flow.mesh.simplices)
        print(f"  double torus step {r.step}: t = {r.t:.3f}, W = {r.willmore:.4f}, residual {fit[2]:.4f}", flush=True)
        if fit[2] < best[0]:
            best = (fit[2], r.vertices, flow.mesh.simplices)
    V, F = best[1], best[2]
    c, rho, res = minimal_s3_fit(V, F)
    Vs, Fs = V, F
    for _ in range(2):
        Vs, Fs = gpytoolbox.subdivide(Vs, Fs, method="loop")
    Y = geometry.inverse_stereographic(np.asarray(Vs), c, rho)
    P = np.random.default_rng(0).normal(size=(200_000, 4))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    pole = P[np.argmax(cKDTree(Y).query(P)[0])]
    Z = geometry.stereographic_reprojection(np.asarray(Vs), c, rho, pole)
    Z -= Z.mean(axis=0)
    U = np.linalg.eigh(np.cov(Z.T))[1]
    U[:, 0] *= np.sign(np.linalg.det(U))  # a rotation
    Z = Z @ U
    rm = isotropic_remesh(Z, np.asarray(Fs, np.int64), 0.2, smooth=False)  # as the stored surface was made
    start = Mesh(rm.vertices, rm.simplices, "reprojected")
    if geometry.enclosed_volume(start) < 0:
        start = Mesh(rm.vertices, rm.simplices[:, ::-1].copy(), "reprojected")
    print(f"  state of residual {res:.4f} (W {geometry.willmore_energy(Mesh(V, F)):.4f}), pole {np.round(pole, 3)}: "
          f"{start.n_vertices} v, W {geometry.willmore_energy(start):.4f}", flush=True)
    flow = WillmoreFlow(start, start.h, 0.01 * start.h**2, adaptive=True, max_retries=12, tangential_weight=100.0,
                        conformal_gauge=True, tangential_control="off", rest_dilation=False)
    flow.run(steps=5)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, vertices=flow.X, simplices=flow.mesh.simplices)
    final = flow.mesh.with_vertices(flow.X)
    print(f"  stored {out}: {final.n_vertices} v, h = {final.h:.4f}, W = {geometry.willmore_energy(final):.4f}, "
          f"residual {minimal_s3_fit(flow.X, flow.mesh.simplices)[2]:.4f}", flush=True)


def genus2_evolver(mesh: Mesh) -> dict[str, Any]:
    """Surface Evolver from ``mesh`` (no volume or area constraint, normal motion, the default schedule of
    :func:`willmore_nlp.evolver.evolver_equilibrium`): its energy before and after, this library's W of its
    final mesh and that mesh's min angle; the final mesh itself (vertices, triangles) for later use."""
    from willmore_nlp.evolver import evolver_equilibrium

    e = evolver_equilibrium(mesh, volume=None, area=None)
    return {"evolver_initial": e["initial_energy"], "evolver_final": e["energy"], "evolver_commands": e["commands"],
            "W_of_evolver_mesh": geometry.willmore_energy(e["mesh"]),
            "evolver_min_angle": geometry.quality(e["mesh"])["min_angle"],
            "final_vertices": mesh.vertices.tolist(), "final_simplices": mesh.simplices.tolist()}


def run_case(name: str, mesh: Mesh, tau: float, tt: float, *, steps: int | None = None, t_end: float | None = None,
             reference: Any = None, switch: tuple[float, float] | None = None, keep_final: bool = False,
             **options: Any) -> dict[str, Any]:
    """Run one flow, collecting the table's figures (see the module docstring).

    ``switch = (t_s, tau_2)``: step with tau up to t_s, then with tau_2 up to t_end. ``keep_final``: also store
    the final mesh (``final_vertices``, ``final_simplices``) for the shape comparisons of :func:`beta_table`.
    """
    # the cached tables predate tangential_control = auto (the surface default since then) and rest_dilation
    flow = WillmoreFlow(mesh, tau, tt, **{"tangential_control": "off", "rest_dilation": False, **options})
    rows: list[dict[str, Any]] = [flow.state().row()]
    last: list[Any] = []
    failed = ""
    t0 = time.perf_counter()

    series: list[list[float]] = []
    frame: list[list[float]] = []
    marks = [0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0]

    gauge: list[float] = []  # conformal_gauge_shift of the steps since the last mark

    def cb(r: Any) -> None:
        rows.append(r.row())
        last[:] = [r]
        if "conformal_gauge_shift" in r.stats:
            gauge.append(r.stats["conformal_gauge_shift"])
        if name.startswith("torus ") and marks and r.t >= marks[0] * (t_end or 1.0) - 1e-12:
            while marks and r.t >= marks[0] * (t_end or 1.0) - 1e-12:
                marks.pop(0)
            R, rr = torus_fit(r.vertices)
            before = [x["min_angle_before_remesh"] if x["remeshed"] else x["q_min_angle"] for x in rows[1:]]
            m = flow.mesh.with_vertices(r.vertices)
            sec, conf = sector_ratios(r.vertices), conformal_ratios(r.vertices)
            n = int(np.rint(np.sqrt(2 * mesh.n_vertices)))
            frame.append(frame_measures(r.t, r.vertices, flow.mesh.simplices, r.willmore, mesh.h))
            series.append([r.t, R / rr, r.willmore, float(min(before)), float(min(x["q_min_angle"] for x in rows)),
                           float(reference(m, flow)), float(sec.min()), float(sec.max()), float(conf.min()),
                           float(conf.max()), torus_grid_asymmetry(r.vertices, n, n // 2) / rr,
                           time.perf_counter() - t0, float(np.mean([x["iterations"] for x in rows[1:]])),
                           float(sum(x["retries"] for x in rows[1:])),
                           abs(rows[-1]["willmore_energy"] / rows[-2]["willmore_energy"] - 1),
                           float(sum("remesh" in x["remesh_action"].split("+") for x in rows[1:])),
                           float(np.median(gauge)) / mesh.h if gauge else float("nan"),
                           float(np.max(gauge)) / mesh.h if gauge else float("nan")])
            gauge.clear()
            if STATES is not None:
                STATES.mkdir(parents=True, exist_ok=True)
                np.savez(STATES / f"{name.replace(' ', '_')}_t{r.t:.4f}.npz", vertices=r.vertices,
                         simplices=flow.mesh.simplices)
            print(f"  {name}: series {series[-1]} N = {r.vertices.shape[0]}", flush=True)
        if len(rows) % 50 == 0:
            print(f"  {name}: step {r.step} t = {r.t:.4g} W = {r.willmore:.5g} min angle "
                  f"{r.quality['min_angle']:.3g} N = {r.vertices.shape[0]}", flush=True)

    try:
        if switch is not None:
            flow.run(t_end=switch[0], callback=cb)
            flow.tau = switch[1]
        flow.run(steps=steps, t_end=t_end, callback=cb)
    except FlowError as exc:
        failed = f"step {exc.step} at t = {exc.t:.4g}: {exc.rejected[-1] if exc.rejected else exc}"
    wall = time.perf_counter() - t0
    W = np.array([r["willmore_energy"] for r in rows])
    after = np.array([r["q_min_angle"] for r in rows])
    before = np.array([r["min_angle_before_remesh"] if r["remeshed"] else r["q_min_angle"] for r in rows])
    final = flow.mesh.with_vertices(flow.X)
    ref = float("nan") if reference is None else float(reference(final, flow))
    quiet = [k for k in range(1, len(rows)) if not rows[k]["remeshed"]]
    k = quiet[-1] if quiet else len(rows) - 1
    stat = abs(W[k] - W[k - 1]) / abs(W[k]) if k >= 1 else float("nan")
    out = {"name": name, "N0": mesh.n_vertices, "N": final.n_vertices, "h": mesh.h, "tau": tau, "tau_tilde": tt,
           "options": {k: v for k, v in options.items() if k != "boundary"}, "steps": len(rows) - 1,
           "t": flow.t, "min_angle_before": float(before.min()),
           "min_angle_steps": float(before[1:].min()) if len(before) > 1 else float("nan"),
           # after the first step (whose stepped state still has the input's triangles)
           "min_angle_steps_after_first": float(before[2:].min()) if len(before) > 2 else float("nan"),
           "min_angle_after_first": float(after[1:].min()) if len(after) > 1 else float("nan"),
           "min_angle_after": float(after.min()),
           "min_angle_final": float(after[-1]), "remeshes": int(sum(r["remeshed"] for r in rows)),
           "retries": int(sum(r["retries"] for r in rows[1:])), "failed": failed, "W0": float(W[0]),
           "W": float(W[-1]), "W_ref": ref, "stationarity": float(stat), "wall": wall,
           "min_tau_seen": float(min((r["tau"] for r in rows[1:]), default=float("nan"))),
           "tau_tilde_final": flow.tau_tilde,
           "iterations_mean": float(np.mean([x["iterations"] for x in rows[1:]])) if len(rows) > 1 else float("nan")}
    if keep_final:
        change = np.abs(np.diff(W)) / np.abs(W[1:])
        late = np.flatnonzero(change >= REST)
        out.update({"final_vertices": final.vertices.tolist(), "final_simplices": final.simplices.tolist(),
                    "W_last": W[-20:].tolist(),
                    "rest_from": -1 if not change.size or change[-1] >= REST
                    else (int(late[-1]) + 2 if late.size else 1)})
    if name.startswith("torus "):
        R, r = torus_fit(flow.X)
        n = int(np.rint(np.sqrt(2 * mesh.n_vertices)))
        out.update({"R_over_r": R / r, "sector_R_over_r": sector_ratios(flow.X).tolist(),
                    "conformal_R_over_r": conformal_ratios(flow.X).tolist(),
                    "clifford_grid": geometry.willmore_energy(shapes.torus(np.sqrt(2), 1.0, n, n // 2)),
                    "W_min": float(W.min()), "series": series, "frame": frame,
                    "iterations": [int(x["iterations"]) for x in rows[1:]]})
    return out


def cases(scale: float) -> dict[str, Any]:
    """name -> thunk returning the case's result."""
    def n(s: int) -> int:
        return max(2, round(s * scale))

    def genus0(mesh: Mesh, note: str = "", **kw: Any) -> Any:
        return lambda: run_case(mesh.source + note, mesh, mesh.h, 0.01 * mesh.h**2, steps=n(200),
                                reference=lambda m, f: sphere_reference(m), **kw)

    def clifford(m: Mesh, f: Any) -> float:
        return clifford_reference(m.vertices, m.simplices)

    def torus(n: int = 48, switch: bool = True, note: str = "", **kw: Any) -> Any:
        """R = 1, r = 0.5 on n x n/2 to t = scale, tau = 1e-3 (4e-3 after t = 0.1 when ``switch`` and scale = 1)."""
        mesh = shapes.torus(1.0, 0.5, n, n // 2)
        label = {(): "", ("mesh_control",): " (mesh control off)", ("remesh_repair",): " (threshold repair only)",
                 ("remesh",): " (no repair between steps)",
                 ("tangential_weight",): ""}.get(tuple(kw), "") + ("" if switch else ", tau = 1e-3") + note
        return lambda: run_case(f"torus {n}x{n // 2}" + label, mesh, 1e-3,
                                0.01 * mesh.h**2, t_end=1.0 * scale, reference=clifford,
                                switch=(0.1, 4e-3) if scale == 1.0 and switch else None, **kw)

    def boundary(name: str, steps: int, reference: Any = None, flow: dict[str, Any] | None = None,
                 **params: Any) -> Any:
        def go() -> dict[str, Any]:
            pb, _ = registry.build(name, **params)
            label = f"{name} " + " ".join(f"{k}={v}" for k, v in {**params, **(flow or {})}.items())
            return run_case(label, pb.mesh, pb.tau, pb.tau_tilde, steps=n(steps), reference=reference, lam=pb.lam,
                            **pb.flow_options, **(flow or {}))
        return go

    def torus_exact(m: Mesh, f: Any) -> float:
        return geometry.willmore_energy(m.with_vertices(torus_projection(m.vertices, 1.0, 0.5)), f.energy_nodes)

    g2 = shapes.genus2()

    def file_case(mesh: Mesh, label: str, steps: int) -> dict[str, Any]:
        """``mesh`` written to an OBJ file and flowed as ``willmore-nlp run FILE`` does: the ``file`` problem's
        mesh, steps and flow options (with the library's ``rest_dilation``, which :func:`run_case` turns off)."""
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "surface.obj"
            save_mesh(mesh, path)
            pb, _ = registry.build("file", path=str(path))
        return run_case(label, pb.mesh, pb.tau, pb.tau_tilde, steps=n(steps), rest_dilation=True, **pb.flow_options)

    def genus2(mesh: Mesh | Callable[[], Mesh], label: str, steps: int = 200, **kw: Any) -> Any:
        """Genus 2, adaptive steps from tau = h, ``n(steps)`` steps, then Surface Evolver from the final mesh
        (normal motion, :func:`willmore_nlp.evolver.evolver_equilibrium`) as a second solver, and the final
        surface's distance from a stereographic image of a minimal surface in S^3 (:func:`minimal_s3_fit`).
        ``mesh``: a mesh or a function making it (built only when the case runs)."""
        def go() -> dict[str, Any]:
            m = mesh() if callable(mesh) else mesh
            final: list[Mesh] = []
            out = run_case(f"{label} ({m.n_vertices} v), adaptive"
                           + "".join(f", {k} = {v}" for k, v in kw.items() if k != "max_retries"),
                           m, m.h, 0.01 * m.h**2, steps=n(steps), adaptive=True, keep_final=True,
                           reference=lambda x, f: final.append(x) or float("nan"), **kw)
            _, rho, res = minimal_s3_fit(final[0].vertices, final[0].simplices)
            return out | genus2_evolver(final[0]) | {"s3_residual": res, "s3_rho": rho,
                                                      "s3_residual_initial": minimal_s3_fit(m.vertices, m.simplices)[2]}
        return go

    def beta(key: str, b: float, **kw: Any) -> Any:
        """The case ``key`` with tangential_weight ``b`` and today's other defaults (the tangential_weight study,
        :func:`beta_table`; ``kw``: further flow options); the final mesh is kept for the shape comparison."""
        label = f", tangential_weight {b:g}" + "".join(f", {k} = {v}" for k, v in kw.items())
        if key in BETA_GENUS0:
            mesh = BETA_GENUS0[key]()
            return lambda: run_case(mesh.source + label, mesh, mesh.h, 0.01 * mesh.h**2, steps=n(200),
                                    reference=lambda m, f: sphere_reference(m), keep_final=True,
                                    tangential_weight=b, **kw)
        pname, steps, ref, params = BETA_BOUNDARY[key]

        def go() -> dict[str, Any]:
            pb, _ = registry.build(pname, **params)
            opts = {**pb.flow_options, "tangential_weight": b}
            return run_case(f"{pname} " + " ".join(f"{k}={v}" for k, v in params.items()) + label, pb.mesh,
                            pb.tau, pb.tau_tilde, steps=n(steps), reference=torus_exact if ref else None,
                            lam=pb.lam, keep_final=True, **opts)
        return go

    beta_cases = {f"{key}_beta{b:g}": beta(key, b) for key in BETA_CASES for b in BETAS}
    # the first step at tau = h fails with weight 10 on the box and the noisy capsule: two more halvings
    beta_cases |= {f"{key}_beta10_retries6": beta(key, 10.0, max_retries=6) for key in ("box", "capsule_noisy")}

    return {
        "ellipsoid642": genus0(ellipsoid(3)),
        "ellipsoid2562": genus0(ellipsoid(4)),
        "capsule": genus0(capsule()),
        "capsule_noisy": genus0(noisy_capsule()),
        "box": genus0(smoothed_box()),
        # today's surface defaults (tangential_control = auto: the in-step control on these genus-0 meshes)
        **{f"{key}_today": genus0(make(), tangential_control="auto")
           for key, make in (("ellipsoid642", lambda: ellipsoid(3)), ("ellipsoid2562", lambda: ellipsoid(4)),
                             ("capsule", capsule), ("capsule_noisy", noisy_capsule), ("box", smoothed_box))},
        # the library's defaults of 2026-11-30 (also rest_dilation, the near-rest flip rule flip_rest and input_repair)
        **{f"{key}_defaults1130": genus0(make(), ", defaults of 2026-11-30", tangential_control="auto",
                                          rest_dilation=True)
           for key, make in (("ellipsoid642", lambda: ellipsoid(3)), ("ellipsoid2562", lambda: ellipsoid(4)),
                             ("capsule", capsule), ("capsule_noisy", noisy_capsule), ("box", smoothed_box))},
        "box_relax": lambda: run_case("smoothed box, relax", smoothed_box(), smoothed_box().h,
                                      0.01 * smoothed_box().h ** 2, steps=n(200), relax=True, relax_newton=False,
                                      reference=lambda m, f: sphere_reference(m)),
        "genus2": lambda: run_case(f"genus-2 ({g2.n_vertices} v), adaptive", g2, g2.h, 0.01 * g2.h**2,
                                   steps=n(200), adaptive=True, max_retries=12),
        "genus2_relax": lambda: run_case(f"genus-2 ({g2.n_vertices} v), relax", g2, g2.h, 0.01 * g2.h**2,
                                         steps=n(200), relax=True, relax_newton=False, max_retries=12),
        "genus2_dt": genus2(lambda: shapes.double_torus(h=0.22), "double torus", max_retries=12,
                            tangential_weight=100.0),
        "genus2_dt_fine": genus2(lambda: shapes.double_torus(h=0.15), "double torus", max_retries=12,
                                 tangential_weight=100.0),
        # the double torus as a user's file, with the file problem's defaults of 2026-11-30 (adaptive_max_wait 64)
        "genus2_dt_file1130": lambda: file_case(shapes.double_torus(h=0.22), "double torus (839 v) read from a file, "
                                                "defaults of 2026-11-30", 1500),
        "genus2_lawson": genus2(shapes.lawson_genus2, "Lawson start", max_retries=12, tangential_weight=100.0,
                                conformal_gauge=True),
        "genus2_lawson_nogauge": genus2(shapes.lawson_genus2, "Lawson start", 40, max_retries=12,
                                        tangential_weight=100.0),
        **{f"genus2_lawson_h{h:g}": genus2(lambda h=h: shapes.lawson_genus2(h), "Lawson start", 60, max_retries=12,
                                           tangential_weight=100.0, conformal_gauge=True) for h in (0.4, 0.28)},
        "genus2_off": lambda: run_case(f"genus-2 ({g2.n_vertices} v), adaptive, mesh control off", g2, g2.h,
                                       0.01 * g2.h**2, steps=n(200), adaptive=True, max_retries=12,
                                       mesh_control="off"),
        "torus": torus(),
        "torus_threshold": torus(remesh_repair=0),
        "torus24": torus(24),
        "torus32": torus(32),
        "torus36": torus(36),
        "torus64": torus(64),
        "torus48_fixed_tau": torus(48, switch=False),
        "torus24_fixed_tau": torus(24, switch=False),
        "torus32_fixed_tau": torus(32, switch=False),
        "torus48_substeps": torus(48, switch=False, note=" (light repair in quarter steps)"),
        "torus24_beta10": torus(24, switch=False, note=", tangential_weight 10", tangential_weight=10.0),
        "torus32_beta10": torus(32, switch=False, note=", tangential_weight 10", tangential_weight=10.0),
        "torus48_beta10": torus(48, switch=False, note=", tangential_weight 10", tangential_weight=10.0),
        "torus64_beta10": torus(64, switch=False, note=", tangential_weight 10", tangential_weight=10.0),
        # every option explicit (the defaults of tangential_control may change)
        **{f"torus{k}" + ("_gauge" if g else "") + ("_meanratio" if c == "meanratio" else ""):
           torus(k, switch=False,
                 note=(", conformal_gauge" if g else "") + (", meanratio 1" if c == "meanratio" else ""),
                 tangential_weight=1.0, tangential_control=c, tangential_control_weight=1.0, conformal_gauge=g)
           for k in (24, 48, 64) for c in ("off", "meanratio") for g in (False, True) if g or c == "meanratio"},
        # the same, run after the isotropic remeshing began to anticipate the step's fall of the smallest angle
        # (_early: cached at c9c933b, new vertices on the old polyhedron; _smooth: cached after the smooth placement)
        **{f"torus48{'_gauge' if g else ''}_meanratio_{v}":
           torus(48, switch=False, note=(", conformal_gauge" if g else "") + ", meanratio 1, anticipated remeshing"
                 + (", smooth placement" if v == "smooth" else ""),
                 tangential_weight=1.0, tangential_control="meanratio", tangential_control_weight=1.0,
                 conformal_gauge=g)
           for g in (False, True) for v in ("early", "smooth")},
        "torus24_off": torus(24, mesh_control="off"),
        "torus64_off": torus(64, mesh_control="off"),
        "torus32_threshold": torus(32, remesh_repair=0),
        "torus32_off": torus(32, mesh_control="off"),
        "torus_off": torus(mesh_control="off"),
        "blend_conormal": boundary("surface_blending", 200, variant="conormal"),
        "blend_ring": boundary("surface_blending", 200, variant="ring"),
        "blend_conormal_400": boundary("surface_blending", 400, variant="conormal"),
        "blend_ring_400": boundary("surface_blending", 400, variant="ring"),
        "torus_hole": boundary("torus_hole", 100, torus_exact, fill="noisy"),
        "torus_hole_off": boundary("torus_hole", 100, torus_exact, {"mesh_control": "off"}, fill="noisy"),
    } | beta_cases


def diagnose(steps: int = 10) -> None:
    """Print the min angle after 1 and ``steps`` steps of the paper's scheme on the torus 24x12 for several
    tau, tau_tilde and in-step tangential terms (the diagnosis table of docs/guide/mesh_quality_measurements.md)."""
    mesh = shapes.torus(1.0, 0.5, 24, 12)
    h = mesh.h
    runs = [(1e-4, 0.01, {}), (1e-3, 0.25, {}), (1e-3, 0.01, {}), (1e-3, 0.001, {}), (1e-2, 0.01, {}),
            (1e-3, 0.01, {"tangential_weight": 10.0}), (1e-3, 0.01, {"tangential_weight": 1000.0}),
            (1e-3, 0.01, {"tangential_control": "meanratio"}),
            (1e-3, 0.01, {"tangential_control": "meanratio", "tangential_control_weight": 3.0})]
    print(f"torus 24x12, h = {h:.4g}, min angle {geometry.quality(mesh)['min_angle']:.2f} deg; mesh_control=off")
    for tau, ttf, kw in runs:
        flow = WillmoreFlow(mesh, tau, ttf * h * h, mesh_control="off", **kw)
        out = flow.run(steps=steps)
        a = [r.quality["min_angle"] for r in out]
        print(f"tau = {tau:g}, tau_tilde = {ttf:g} h^2, {kw}: min angle {a[0]:.2f} / {a[-1]:.2f}, "
              f"loss per unit time {(geometry.quality(mesh)['min_angle'] - a[-1]) / flow.t:.0f} deg, "
              f"W {out[-1].willmore:.3f}", flush=True)
    for q in (2.0, 1.757, 1.571, np.sqrt(2)):
        g = shapes.torus(1.0, 1.0 / q, 24, 12)
        print(f"grid 24x12 on the exact torus R/r = {q:.4g}: min angle {geometry.quality(g)['min_angle']:.2f}")


def first_step_probe(betas: tuple[float, ...] = (1.0, 3.0, 10.0, 30.0, 100.0)) -> None:
    """Print whether the first step of the smoothed box and the noisy capsule converges and passes the mesh checks
    at tau = h, h/4, h/16, h/64 for several tangential weights (one attempt each, no iteration budget): where a
    weight > 1 hurts (docs/guide/mesh_quality_measurements.md, "Which tangential_weight")."""
    for mesh in (smoothed_box(), noisy_capsule()):
        h = mesh.h
        for b in betas:
            cells = []
            for frac in (1, 4, 16, 64):
                flow = WillmoreFlow(mesh, h / frac, 0.01 * h * h, tangential_weight=b, max_retries=0,
                                    first_step_budget=0, tangential_control="off", rest_dilation=False)
                try:
                    r = flow.run(steps=1)[0]
                    cells.append(f"h/{frac}: {r.iterations} it, W {r.willmore:.3f}, {r.quality['min_angle']:.3g} deg")
                except FlowError as exc:
                    cells.append(f"h/{frac}: " + str(exc.rejected[-1] if exc.rejected else exc).split(": ", 1)[-1])
            print(f"{mesh.source}, tangential_weight {b:g}: " + "; ".join(cells), flush=True)


def conformal_torus(q: float, n: int, m: int, r: float = 1.0) -> Mesh:
    """The torus R/r = q (tube radius r) on the n x m grid of :func:`shapes.torus`, its meridian nodes at equal steps
    of the conformal coordinate w = int dv / (q + cos v) instead of the angle v (the grid's quads then all have the
    same aspect ratio, 2:1 for n = 2m on the Clifford torus, whose conformal modulus is 1)."""
    from scipy.integrate import cumulative_trapezoid

    v = np.linspace(-np.pi, np.pi, 20001)
    w = cumulative_trapezoid(1 / (q + np.cos(v)), v, initial=0)
    w -= np.interp(0.0, v, w)
    period = w[-1] - w[0]
    target = np.arange(m) / m * period
    target = np.where(target > period / 2, target - period, target)
    vv = np.interp(target, w, v)
    U, W = np.meshgrid(2 * np.pi * np.arange(n) / n, vv, indexing="ij")
    P = r * np.stack([(q + np.cos(W)) * np.cos(U), (q + np.cos(W)) * np.sin(U), np.sin(W)], -1).reshape(-1, 3)
    return Mesh(P, shapes.torus(q, 1.0, n, m).simplices, f"conformal torus R/r={q:.4g} {n}x{m}")


def symmetry(steps: int = 3) -> None:
    """Print why the torus flows leave the rotational symmetry (docs/guide/mesh_quality.md): the paper's scheme
    (mesh control off) from grids on the exact tori R/r = 1.6 and sqrt 2, uniform and conformal node spacing, with
    tangential_weight 1 and 10: asymmetry (`torus_grid_asymmetry` / r) after each step and its wavenumber; then
    the light repair alone on the uniform grid of R/r = 1.571 against the min angle of the conformal spacing."""
    from willmore_nlp import remesh
    from willmore_nlp.analysis import torus_grid_asymmetry_wavenumber

    n, m = 24, 12
    for q in (1.6, np.sqrt(2)):
        for kind in ("uniform", "conformal"):
            g = shapes.torus(q, 1.0, n, m) if kind == "uniform" else conformal_torus(q, n, m)
            mesh = g.with_vertices(g.vertices / 2)
            for beta in (1.0, 10.0):
                out = WillmoreFlow(mesh, 1e-3, 0.01 * mesh.h**2, mesh_control="off",
                                   tangential_weight=beta).run(steps=steps)
                print(f"{n}x{m} R/r = {q:.4g}, {kind} spacing (min angle {geometry.quality(mesh)['min_angle']:.1f}), "
                      f"tangential_weight {beta:g}: asymmetry/r "
                      + ", ".join(f"{torus_grid_asymmetry(r.vertices, n, m) / 0.5:.1e}" for r in out)
                      + f"; wavenumber {torus_grid_asymmetry_wavenumber(out[-1].vertices, n, m)}; IPOPT iterations "
                      f"{[r.iterations for r in out]}", flush=True)
    for n in (24, 48):
        g = shapes.torus(1.571, 1.0, n, n // 2)
        X = remesh.tangential_relax(g.vertices, g.simplices, iterations=40)
        print(f"{n}x{n // 2} on R/r = 1.571: min angle {geometry.quality(g)['min_angle']:.2f} uniform, "
              f"{geometry.triangle_quality(X, g.simplices)['min_angle']:.2f} after 40 light-repair passes, "
              f"{geometry.quality(conformal_torus(1.571, n, n // 2))['min_angle']:.2f} with conformal spacing",
              flush=True)


def surface_distance(a: dict[str, Any], b: dict[str, Any]) -> float:
    """:func:`willmore_nlp.analysis.surface_distance` between the final meshes of two cached results."""
    return mesh_distance(np.asarray(a["final_vertices"]), np.asarray(a["final_simplices"]),
                         np.asarray(b["final_vertices"]), np.asarray(b["final_simplices"]))


def rest_from(r: dict[str, Any]) -> str:
    """The step from which the relative change of W stayed below :data:`REST` ("never": not at the end; blank:
    not recorded)."""
    k = r.get("rest_from")
    return "" if k is None else ("never" if k < 0 else str(k))


def torus_distance(r: dict[str, Any]) -> str:
    """Largest distance of the final vertices from the exact torus R = 1, r = 0.5, in initial mean edges, for the
    ``torus_hole`` cases (the fixed vertices lie on it, so this is the free vertices' largest distance)."""
    if not r["name"].startswith("torus_hole") or "final_vertices" not in r:
        return ""
    return f"{exact_torus_distance(np.asarray(r['final_vertices']), 1.0, 0.5).max() / r['h']:.3g}"


def beta_table(cached: dict[str, dict[str, Any]]) -> list[str]:
    """The tangential_weight study: per case the cached beta = 1 row of the earlier defaults (if any) and the
    rows of :data:`BETAS` with today's defaults; then the final shapes of beta = 10, 100 against beta = 1."""
    def ok(r: dict[str, Any]) -> str:
        return f"{r['failed'].split(': ', 1)[0]}: {r['failed'].split(': ')[-1][:48]}" if r["failed"] else "no"

    lines = ["| case | tangential_weight | run length (x default) | steps | t | retries | failed | min angle before / "
             "after repair | stepped states | final | IPOPT it/step | wall [s] | W final | W/W_ref - 1 | "
             "stationarity | below 1e-8 from step | exact torus: max distance / h |", "|---" * 17 + "|"]
    shapes_ = ["| case | beta | W(beta) / W(1) - 1 | same vertex count | max vertex distance / h | "
               "max surface distance / h | genus 0: R / R(1) - 1; max abs(r - R) / h, beta (1) |",
               "|---|---|---|---|---|---|---|"]

    def radii(r: dict[str, Any]) -> np.ndarray:
        V = np.asarray(r["final_vertices"])
        return np.linalg.norm(V - V.mean(axis=0), axis=1)

    for key in BETA_CASES:
        rows = [("1 (cached)", cached.get(key)), *((f"{b:g}", cached.get(f"{key}_beta{b:g}")) for b in BETAS),
                ("10, max_retries 6", cached.get(f"{key}_beta10_retries6"))]
        for beta, r in rows:
            if r is None:
                continue
            rel = r["W"] / r["W_ref"] - 1 if np.isfinite(r["W_ref"]) and not r["failed"] else float("nan")
            it = r.get("iterations_mean", float("nan"))
            lines.append(f"| {key} | {beta} | {r.get('scale', 1.0):g} | {r['steps']} | {r['t']:.4g} | "
                         f"{r['retries']} | {ok(r)} | {r['min_angle_before']:.3g} / {r['min_angle_after']:.3g} | "
                         f"{r.get('min_angle_steps', float('nan')):.3g} | {r['min_angle_final']:.3g} | {it:.2f} | "
                         f"{r['wall']:.0f} | {r['W']:.6g} | {rel:.2e} | {r['stationarity']:.1e} | "
                         f"{rest_from(r)} | {torus_distance(r)} |")
        base = cached.get(f"{key}_beta1")
        for b, r in [(f"{b:g}", cached.get(f"{key}_beta{b:g}")) for b in BETAS[1:]] + [
                ("10, max_retries 6", cached.get(f"{key}_beta10_retries6"))]:
            if base is None or r is None or base["failed"] or r["failed"] or "final_vertices" not in r:
                continue
            Va, Vb = np.asarray(base["final_vertices"]), np.asarray(r["final_vertices"])
            same = Va.shape == Vb.shape
            vd = f"{np.linalg.norm(Va - Vb, axis=1).max() / base['h']:.3g}" if same else ""
            sphere = ""
            if key in BETA_GENUS0:
                ra, rb = radii(base), radii(r)
                sphere = (f"{rb.mean() / ra.mean() - 1:+.2e}; {np.abs(rb - rb.mean()).max() / base['h']:.3g} "
                          f"({np.abs(ra - ra.mean()).max() / base['h']:.3g})")
            shapes_.append(f"| {key} | {b} | {r['W'] / base['W'] - 1:+.2e} | {'yes' if same else 'no'} | {vd} | "
                           f"{surface_distance(base, r) / base['h']:.3g} | {sphere} |")
    return [*lines, "", "Final shapes against tangential_weight 1 (same case, same run length; h: the initial mean "
            "edge):", "", *shapes_]


def cached_genus2(todo: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The cached genus-2 cases that started from :func:`willmore_nlp.mesh.shapes.lawson_genus2`."""
    return {k: json.loads((CACHE / f"{k}.json").read_text()) for k in todo
            if k.startswith("genus2_lawson") and (CACHE / f"{k}.json").is_file()}


def lawson_table(cached: dict[str, dict[str, Any]]) -> list[str]:
    """Flows from the Lawson start: distance from a stereographic image of a minimal surface in S^3
    (:func:`minimal_s3_fit`) at the start and the end, and the final energies against mesh size h (the gap to
    Lawson's 43.8 and its observed order over the refinements)."""
    if not cached:
        return []

    def size(r: dict[str, Any]) -> float:
        return float(np.sqrt(geometry.measure(Mesh(np.array(r["final_vertices"]), np.array(r["final_simplices"])))
                             / (4 * np.pi)))

    out = ["", "Flows from `shapes.lawson_genus2` (a Moebius image of Lawson's surface in which the mesh resolves "
           "the curvature; see docs/guide/mesh_quality_measurements.md, Genus 2). "
           "residual: `analysis.minimal_s3_fit`, the L^2 "
           "distance of H from the mean curvature of a stereographic image of a minimal surface in S^3 (0 for "
           "Lawson's surface and its Moebius images; 0.0055 for the Clifford torus on the 48 x 24 grid); rho / L: the "
           "fitted radius of the sphere over the surface's size L = sqrt(area / 4 pi) (it moves when the surface "
           "slides along its Moebius orbit; the stored start: 0.45).", "",
           "| case | h | steps, t | retries, failed | min angle after repair (end) | W start -> end | W / 43.8 - 1 "
           "| rest (last step) | residual start -> end | rho / L end |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in cached.values():
        out.append(f"| {r['name']} | {r['h']:.3f} | {r['steps']}, {r['t']:.2f} | {r['retries']}, "
                   f"{r['failed'] or 'no'} | {r['min_angle_after']:.1f} ({r['min_angle_final']:.1f}) | "
                   f"{r['W0']:.3f} -> {r['W']:.4f} | {r['W'] / LAWSON_21 - 1:+.2%} | {r['stationarity']:.1e} | "
                   f"{r['s3_residual_initial']:.3f} -> {r['s3_residual']:.3f} | {r['s3_rho'] / size(r):.3f} |")
    ref = [r for r in cached.values() if "conformal_gauge" in r["options"] and not r["failed"]]
    if len(ref) >= 3:
        ref.sort(key=lambda r: -r["h"])
        h = np.array([r["h"] for r in ref])
        w = np.array([r["W"] for r in ref])
        p = np.log((w[0] - w[1]) / (w[1] - w[2])) / np.log(h[0] / h[1]) if (w[0] - w[1]) * (w[1] - w[2]) > 0 \
            else float("nan")
        out += ["", f"Refinement with `conformal_gauge` (h = {', '.join(f'{x:.3f}' for x in h)}): W = "
                f"{', '.join(f'{x:.4f}' for x in w)}; gap to 43.8: "
                f"{', '.join(f'{x / LAWSON_21 - 1:+.2%}' for x in w)}, "
                f"observed order of the gap {fit_order(h, np.abs(w - LAWSON_21)):.2f}; order of the successive "
                f"differences {p:.2f}."]
    return out


def table(results: list[dict[str, Any]]) -> list[str]:
    lines = ["| case | run length (x default) | N0 -> N | steps | t | min angle (before / after repair) | "
             "min angle of the stepped states | failed | "
             "repaired states | retries | "
             "W0 -> W | W_ref (mesh-matched) | W/W_ref - 1 | stationarity | tau_tilde end / start | wall [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        rel = r["W"] / r["W_ref"] - 1 if np.isfinite(r["W_ref"]) else float("nan")
        lines.append(f"| {r['name']} | {r.get('scale', 1.0):g} | {r['N0']} -> {r['N']} | {r['steps']} | {r['t']:.4g} | "
                     f"{r['min_angle_before']:.3g} / {r['min_angle_after']:.3g} | "
                     f"{r.get('min_angle_steps', float('nan')):.3g} | "
                     f"{r['failed'] or 'no'} | "
                     f"{r['remeshes']} | {r['retries']} | {r['W0']:.5g} -> {r['W']:.5g} | {r['W_ref']:.5g} | "
                     f"{rel:.2e} | {r['stationarity']:.1e} | "
                     f"{r.get('tau_tilde_final', float('nan')) / r['tau_tilde']:.3g} | {r['wall']:.0f} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", help="subset of cases (default: all)")
    ap.add_argument("--scale", type=float, default=1.0, help="multiply run lengths")
    ap.add_argument("--out", default="reports/mesh_quality_study.md")
    ap.add_argument("--table-only", action="store_true", help="only write the table of the cached cases")
    ap.add_argument("--diagnose", action="store_true", help="only print the single-step diagnosis (torus 24x12)")
    ap.add_argument("--symmetry", action="store_true", help="only print why the torus flows leave the symmetry")
    ap.add_argument("--first-step", action="store_true",
                    help="only print the first step of the box and noisy capsule against tangential_weight")
    ap.add_argument("--lawson-start", action="store_true",
                    help="only make the stored surface of shapes.lawson_genus2 (about 5 min)")
    ap.add_argument("--save-states", type=Path, help="write the torus states of the series to this directory")
    ap.add_argument("--frame-from-states", type=Path,
                    help="add the frame measures to the cached --cases from the states saved in this directory")
    args = ap.parse_args()
    if args.frame_from_states:
        frame_from_states(args.frame_from_states, args.cases)
        return
    global STATES
    STATES = args.save_states
    if args.diagnose:
        diagnose()
        return
    if args.lawson_start:
        lawson_start()
        return
    if args.symmetry:
        symmetry()
        return
    if args.first_step:
        first_step_probe()
        return
    CACHE.mkdir(parents=True, exist_ok=True)
    todo = cases(args.scale)
    names = [] if args.table_only else (args.cases or list(todo))
    for name in names:
        f = CACHE / f"{name}.json"
        if f.is_file():
            continue
        print(f"{name} ...", flush=True)
        res = todo[name]()
        res["scale"] = args.scale
        f.write_text(json.dumps(res, indent=1))
        print(f"{name}: {res}", flush=True)
    study = {f"{k}_beta{b:g}" for k in BETA_CASES for b in BETAS} | {f"{k}_beta10_retries6" for k in BETA_CASES}
    results = [json.loads((CACHE / f"{k}.json").read_text()) for k in todo
               if k not in study and (CACHE / f"{k}.json").is_file()]
    lines = ["# Mesh-quality control: long surface flows with the defaults", "",
             f"`nice python reports/mesh_quality_study.py` on {platform.processor() or platform.machine()}, "
             f"{time.strftime('%Y-%m-%d')} (see the script's docstring for the columns).", ""]
    lines += table(results)
    g2 = [r for r in results if "evolver_final" in r]
    if g2:
        lines += ["", f"Genus 2 against Lawson's xi_(2,1), W = {LAWSON_21:.1f} in this normalisation, and Surface "
                  "Evolver started from the final mesh (`genus2_evolver`):", "",
                  "| case | W final | W / 43.8 - 1 | Evolver's energy of the final mesh | Evolver minimised "
                  "(commands) | W of Evolver's mesh | its min angle |", "|---|---|---|---|---|---|---|"]
        lines += [f"| {r['name']} | {r['W']:.4f} | {r['W'] / LAWSON_21 - 1:+.2%} | {r['evolver_initial']:.4f} | "
                  f"{r['evolver_final']:.4f} ({r['evolver_commands']}) | {r['W_of_evolver_mesh']:.4f} | "
                  f"{r['evolver_min_angle']:.3g} |" for r in g2]
        lines += lawson_table(cached_genus2(todo))
    cached = {k: json.loads((CACHE / f"{k}.json").read_text()) for k in todo if (CACHE / f"{k}.json").is_file()}
    if any(f"{k}_beta{b:g}" in cached for k in BETA_CASES for b in BETAS):
        lines += ["", "## tangential_weight 1, 10, 100 (`--cases KEY_beta1 KEY_beta10 KEY_beta100`)", "",
                  "Today's defaults apart from the weight; \"(cached)\" is the case's row of the main table (earlier "
                  "defaults, see the notes). W_ref as in the main table (NaN: no closed-form limit). Min angle: the "
                  "smallest before / after repair over the run (the input included), of the stepped states, at the "
                  "end. A first pass at `--scale 0.25` is kept in `reports/studies/mesh_quality/beta_scale0.25/`. "
                  "`--first-step` prints the first step of the box and the noisy capsule against the weight. "
                  "\"below 1e-8 from step\": the step from which the relative change of W per step stayed below "
                  "1e-8 (\"never\": not at the end; blank: run before the column existed); \"exact torus\": the "
                  "largest distance of the final vertices from the exact torus R = 1, r = 0.5 in initial mean edges "
                  "(`torus_hole`; its fixed vertices lie on it). Since these rows `torus_hole` defaults to "
                  "tangential_weight 10 (the cached main-table row ran with 1 and the earlier defaults).", ""]
        lines += beta_table(cached)
    tor = [r for r in results if "R_over_r" in r]
    if tor:
        lines += ["", "Tori toward the Clifford torus (R/r -> sqrt 2 = 1.41421). W_grid: the Clifford torus meshed "
                  "on the same n x n/2 grid; W_ref: the final mesh projected onto the Clifford torus of the fitted "
                  "size "
                  "(mesh-matched, same vertices and connectivity):", "",
                  "| case | t | R/r (circle fit) | W final | W_grid | W/W_grid - 1 | min W over the run / W_grid - 1 | "
                  "W_ref | W/W_ref - 1 | min angle before / after repair |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['name']} | {r['t']:.4g} | {r['R_over_r']:.4f} | {r['W']:.4f} | {r['clifford_grid']:.4f} | "
                  f"{r['W'] / r['clifford_grid'] - 1:+.2%} | {r['W_min'] / r['clifford_grid'] - 1:+.2%} | "
                  f"{r['W_ref']:.4f} | {r['W'] / r['W_ref'] - 1:+.2%} | "
                  f"{r['min_angle_before']:.3g} / {r['min_angle_after']:.3g} |" for r in tor]
        for r in tor:
            if r.get("series"):
                lines += ["", f"{r['name']} over time (W_ref: the mesh of that time projected onto the Clifford "
                          "torus of the fitted size):", "",
                          "| t | R/r | R/r in 8 sectors, min - max | W | W/W_grid - 1 | W_ref | W/W_ref - 1 | "
                          "min angle so far, before / after repair |",
                          "|---|---|---|---|---|---|---|---|"]
                lines += [f"| {x[0]:.4g} | {x[1]:.4f} | "
                          + (f"{x[6]:.3f} - {x[7]:.3f} | " if len(x) > 7 else "| ")
                          + f"{x[2]:.4f} | {x[2] / r['clifford_grid'] - 1:+.2%} | "
                          + (f"{x[5]:.4f} | {x[2] / x[5] - 1:+.2%} | " if len(x) > 5 else "| | ")
                          + f"{x[3]:.3g} / {x[4]:.3g} |" for x in r["series"]]
        lines += ["", "The same times across resolutions and mesh controls (tau = 1e-3): R/r by circle fit, its "
                  "spread over 8 angular sectors (about 0.005 even for a symmetric state: the sectors are not "
                  "congruent), W/W_ref - 1 (W_ref: that state's mesh projected onto the fitted "
                  "Clifford torus), the smallest angle so far before / after repair and, while the vertex count is "
                  "the grid's, the asymmetry (`analysis.torus_grid_asymmetry` / r: 0 for an exactly rotationally "
                  "symmetric state):", ""]
        lines += resolution_table(tor)
        if any(r.get("frame") for r in tor):
            lines += ["", "The same states in the frame of their fitted torus of revolution (`analysis.torus_frame`: "
                      "free centre and axis; W_ref: the mesh on the Clifford torus of that frame; \"centre moved\": "
                      "the fitted centre's distance from the origin; rms distance: of the vertices from the fitted "
                      "torus, in initial mean edges). The fixed-axis measures above misread a translation or tilt of "
                      "the torus, and sectors about the vertex centroid misread vertices gathering on one side, as a "
                      "departure from the tori of revolution:", ""]
            lines += frame_table([r for r in tor if r.get("frame")])
        lines += ["", "The discrete Willmore energy of the tori of revolution meshed on the n x n/2 grid (R/r varied, "
                  "`grid_minimum`): its minimiser lies below sqrt 2 by O(h^2):", ""]
        lines += grid_table()
    lines += ["", "Notes: rows named \"threshold repair only\" and \"mesh control off\" are cached from the runs "
              "before the light repair (`remesh_repair = 0`, trigger 20 deg, target = initial mean edge; "
              "`reports/studies/mesh_quality/threshold_only/` keeps the other cases of that default). The torus 48x24 "
              "with the switch to tau = 4e-3 at t = 0.1 was stopped at t = 0.2 (IPOPT > 200 iterations per step); "
              "`torus48_fixed_tau` keeps tau = 1e-3 to t = 1. The tori 24x12, 32x16 and 64x32 ran with `--scale 0.2` "
              "(to t = 0.2). The noisy capsule is `noisy_capsule()` (seed 0). Run with `rest_tau_tilde` and the light "
              "repair in quarter steps (`remesh.RELAX_SUBSTEPS`): the smoothed box and the ellipsoid 2,562 v (200 "
              "steps, with today's defaults); `torus32_fixed_tau` ran with the first version of the rest test "
              "(rest_tol 1e-5 per step, not per unit time L^4), which lowered the torus's tau_tilde to 1/100; the "
              "other rows are cached from before those changes (tau_tilde end / start NaN). `torus48_substeps` "
              "(today's defaults) and the `tangential_weight 10` tori ran with the current rest test (never at rest "
              "at tau = 1e-3); their series also hold the wall time, mean IPOPT iterations and retries so far "
              "(`--save-states DIR` keeps "
              "the states)."]
    Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
