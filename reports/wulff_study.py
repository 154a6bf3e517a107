"""Closed anisotropic surfaces at rest against the Wulff shape: the ``anisotropic_sphere`` problem refined.

    OMP_NUM_THREADS=1 nice python reports/wulff_study.py [--subdivisions 2,3,4] [--jobs 2]
    # writes reports/wulff_study.md; one pickle per run in reports/studies/wulff/ (reruns only what is missing)

The registered ``anisotropic_sphere`` problem (an icosphere of radius 3, gamma1 = sqrt(z1^2 + 4 z2^2 + z3^2), tau =
h, tau_tilde = h^2 / 100, the library's defaults otherwise) flows to t = T_END at every refinement (75, 150, 300
steps at subdivisions 2, 3, 4: tau = h halves with h). Among closed surfaces the anisotropic Willmore energy
w_gamma = 1/2 int h_gamma^2 is least on the Wulff shapes (h_gamma = 2 / R there), here the ellipsoid x1^2 + x2^2 / 4
+ x3^2 <= 1 scaled, whose value is independent of the scale: w_gamma = 1/2 (2 / R)^2 |W_R|_gamma = 2 |W_1|, twice
the Euclidean area of the unit Wulff shape (for a Wulff shape the anisotropic area is 3 volume / R), the prolate
spheroid's 2 pi (1 + 2 arcsin(e) / e), e = sqrt(3) / 2: :data:`W_WULFF` = 42.96. Per run:

* ``x2/x1``, ``x2/x3``: the final surface's extents (2 and 2 on the Wulff shape);
* ``Wulff spread``: max / min - 1 of the Wulff gauge sqrt(x1^2 + x2^2 / 4 + x3^2) of the vertices about their
  centroid (0 on a scaled Wulff shape);
* ``w_gamma`` (:func:`willmore_nlp.anisotropy.anisotropic_willmore_energy`) against the closed form and against
  the mesh-matched reference, the final mesh projected onto the Wulff shape along the gauge (its own nodes);
* ``rest``: the relative change of w_gamma in the last step; the smallest angle of the stepped states (before the
  mesh control acts) and after it; retries.

``--control-off`` rows: the same with ``mesh_control = "off"`` (the paper's scheme), at subdivisions 2 and 3.
The orders are least-squares slopes against the initial mean edge over the refinements run with the defaults.
"""

from __future__ import annotations

import argparse
import pickle
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.analysis import fit_order
from willmore_nlp.anisotropy import (
    anisotropic_willmore_energy,
    gamma1_wulff_energy,
    gamma1_wulff_gauge,
    gamma1_wulff_nodes,
    get_anisotropy,
)
from willmore_nlp.flow import FlowError
from willmore_nlp.mesh.core import Mesh
from willmore_nlp.registry import build

OUT = Path(__file__).resolve().parent
CACHE = OUT / "studies" / "wulff"
T_END = 67.0
"""Final time of every run (75 steps of tau = h at subdivisions 2, 150 at 3, 300 at 4)."""
W_WULFF = gamma1_wulff_energy()
"""w_gamma of every Wulff shape of gamma1 (42.96; :func:`willmore_nlp.anisotropy.gamma1_wulff_energy`)."""


def run(subdivisions: int, control: bool) -> dict[str, Any]:
    """Flow ``anisotropic_sphere`` at ``subdivisions`` to :data:`T_END` and measure the final state."""
    pb, _ = build("anisotropic_sphere", subdivisions=subdivisions)
    flow = pb.make_flow(**({} if control else {"mesh_control": "off"}))
    steps = round(T_END / pb.tau)
    t0 = time.time()
    res, error = [], ""
    try:
        for _ in range(steps):
            res.append(flow.step())
    except FlowError as exc:  # recorded in the table
        error = str(exc).split(";")[0]
    an = get_anisotropy("gamma1", 3)
    X, F = np.array(flow.X), np.array(flow.mesh.simplices)
    r = gamma1_wulff_gauge(X)
    Y = X - X.mean(axis=0)
    ext = Y.max(axis=0) - Y.min(axis=0)
    wg = [s.willmore_gamma for s in res]
    return {"subdivisions": subdivisions, "control": control, "N": pb.mesh.n_vertices, "h": pb.mesh.h,
            "steps": len(res), "t": flow.t, "error": error, "retries": sum(s.retries for s in res),
            "x2/x1": ext[1] / ext[0], "x2/x3": ext[1] / ext[2], "spread": r.max() / r.min() - 1,
            "w_gamma": anisotropic_willmore_energy(Mesh(X, F), an),
            "w_projected": anisotropic_willmore_energy(Mesh(gamma1_wulff_nodes(X), F), an),
            "rest": abs(wg[-1] - wg[-2]) / abs(wg[-1]) if len(wg) > 1 else float("nan"),
            "stepped_angle": min((s.stats.get("min_angle_before_remesh", np.nan) for s in res
                                  if np.isfinite(s.stats.get("min_angle_before_remesh", np.nan))), default=np.nan),
            "angle": min(s.quality["min_angle"] for s in res) if res else float("nan"),
            "iterations": float(np.mean([s.iterations for s in res])) if res else float("nan"),
            "wall": time.time() - t0}


def cached(subdivisions: int, control: bool) -> dict[str, Any]:
    """:func:`run`, read from :data:`CACHE` when it was run before."""
    path = CACHE / f"s{subdivisions}{'' if control else '_off'}.pkl"
    if path.exists():
        with path.open("rb") as fh:
            return pickle.load(fh)
    out = run(subdivisions, control)
    CACHE.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        pickle.dump(out, fh)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subdivisions", default="2,3,4")
    ap.add_argument("--control-off", default="2,3", help="subdivisions also run with mesh_control = off")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    cases = [(int(s), True) for s in a.subdivisions.split(",") if s] + \
            [(int(s), False) for s in a.control_off.split(",") if s]
    with ProcessPoolExecutor(a.jobs) as pool:
        rows = list(pool.map(cached, *zip(*cases, strict=True)))
    lines = ["# Closed anisotropic surfaces at rest against the Wulff shape", "",
             f"`OMP_NUM_THREADS=1 nice python reports/wulff_study.py` on {platform.machine()}, "
             f"{time.strftime('%Y-%m-%d')}; the script's docstring defines the columns. Closed form: w_gamma = "
             f"{W_WULFF:.4f} on every Wulff shape of gamma1.", "",
             "| N | mesh control | steps, t | retries | x2/x1 | x2/x3 | Wulff spread | w_gamma | "
             "w_gamma / closed form - 1 | w_gamma / mesh-matched - 1 | rest (last step) | "
             "smallest angle stepped / after control | iterations per step | wall [s] | note |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['N']} | {'default' if r['control'] else 'off'} | {r['steps']}, {r['t']:.1f} | "
                     f"{r['retries']} | {r['x2/x1']:.4f} | {r['x2/x3']:.4f} | {r['spread']:.2e} | "
                     f"{r['w_gamma']:.4f} | {r['w_gamma'] / W_WULFF - 1:+.2e} | "
                     f"{r['w_gamma'] / r['w_projected'] - 1:+.2e} | {r['rest']:.1e} | "
                     f"{r['stepped_angle']:.1f} / {r['angle']:.1f} | {r['iterations']:.1f} | {r['wall']:.0f} | "
                     f"{r['error']} |")
    ref = [r for r in rows if r["control"] and not r["error"]]
    if len(ref) >= 3:
        h = [r["h"] for r in ref]
        errors = {"Wulff spread": [r["spread"] for r in ref], "|x2/x1 - 2|": [abs(r["x2/x1"] - 2) for r in ref],
                  "|w_gamma / closed form - 1|": [abs(r["w_gamma"] / W_WULFF - 1) for r in ref]}

        def pairs(e: list[float]) -> str:
            return ", ".join(f"{np.log(e[i] / e[i + 1]) / np.log(h[i] / h[i + 1]):.2f}" for i in range(len(e) - 1))

        lines += ["", "Orders over the refinements with the defaults (least-squares slope against h; in brackets "
                  "those of successive refinements): " + "; ".join(
                      f"{k} {fit_order(h, e):.2f} ({pairs(e)})" for k, e in errors.items()) + "."]
    (OUT / "wulff_study.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
